"""Counter-based random numbers: SplitMix64 outputs addressed by element index.

``mix64(key + g * GOLDEN)`` is output ``g`` of SplitMix64 seeded with ``key`` (Steele et
al. 2014; passes BigCrush). Each element draws from its own index, so any split of the
work over threads gives the same numbers.
"""
from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import intrinsic

U64 = np.uint64
I64 = np.int64
GOLDEN = U64(0x9E3779B97F4A7C15)
_M1 = U64(0xBF58476D1CE4E5B9)
_M2 = U64(0x94D049BB133111EB)
_S11, _S27, _S30, _S31 = U64(11), U64(27), U64(30), U64(31)
LOW63 = U64(0x7FFFFFFFFFFFFFFF)
_INV53 = 1.0 / 9007199254740992.0  # 2**-53


@njit(inline="always")
def mix64(z):
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(inline="always")
def draw(key, g):
    """64 random bits for element ``g`` of the stream ``key``."""
    return mix64(key + U64(g) * GOLDEN)


@njit(inline="always")
def unit(z):
    """Uniform in the open interval (0, 1) from the top 53 bits of ``z``."""
    return (float(I64(z >> _S11)) + 0.5) * _INV53


@intrinsic
def leading_zeros(typingctx, x):
    """Count of leading zero bits of a uint64 (LLVM ctlz)."""
    sig = types.uint64(types.uint64)

    def codegen(context, builder, signature, args):
        from llvmlite import ir

        return builder.ctlz(args[0], ir.Constant(ir.IntType(1), 0))

    return sig, codegen

