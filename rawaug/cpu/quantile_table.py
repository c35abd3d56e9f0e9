"""Symmetric noise by a tabulated quantile: Tukey lambda (G*) and Gaussian (G, P).

A draw is 64 random bits: the top bit is the sign, the other 63 are the tail probability
``t = r * 2**-64`` in (0, 1/2). The table is indexed by the binary exponent of ``t``
(its leading zeros, 63 rows, down to t = 2**-64) and the first ``MANTISSA_BITS`` bits of
its mantissa, and interpolated linearly in between. Each row spans one octave of ``t``,
so far tails are as finely resolved as the body: the quantile's relative error is below
4e-7 for every lambda in [-1, 1] (``tests/test_cpu_kernels.py``), near float32 resolution,
at about 5 ns per element on one core against 35 ns for the exact formula.
"""
from __future__ import annotations

import functools

import numpy as np
import torch
from numba import njit

from .counter import I64, LOW63, U64, draw, leading_zeros

MANTISSA_BITS = 10
_ROW = (1 << MANTISSA_BITS) + 1
_SIGN = U64(63)
_CELLS = float(1 << MANTISSA_BITS)
_POW2 = np.array([2.0 ** (lz - 63) for lz in range(64)])  # r * 2**(lz-63) is in [1, 2)


def tail_points() -> np.ndarray:
    """The tail probabilities the table holds, (63, 2**M + 1): row ``lz - 1`` is t in [2**-(lz+1), 2**-lz]."""
    lz = np.arange(1, 64, dtype=np.float64)[:, None]
    j = np.arange(_ROW, dtype=np.float64)[None, :]
    return (1.0 + j / _CELLS) * 2.0 ** (-1.0 - lz)


def build_table(upper_quantile) -> np.ndarray:
    """Flat float64 table of ``upper_quantile(t)`` (the quantile at 1 - t, >= 0) over ``tail_points()``."""
    t = torch.from_numpy(tail_points())
    table = upper_quantile(t).to(torch.float64).numpy().ravel().copy()
    if not np.all(np.isfinite(table)):
        raise ValueError("the quantile table holds non-finite values")
    return table


@njit(inline="always")
def symmetric(table, z):
    """A standard draw of the tabulated symmetric distribution from 64 random bits."""
    r = (z & LOW63) | U64(1)
    lz = I64(leading_zeros(r))  # 1..63
    pos = (float(I64(r)) * _POW2[lz] - 1.0) * _CELLS
    j = int(pos)
    idx = (lz - 1) * _ROW + j
    q = table[idx] + (pos - j) * (table[idx + 1] - table[idx])
    return q * (1.0 - 2.0 * float(I64(z >> _SIGN)))  # top bit: the lower tail (no branch)


@functools.lru_cache(maxsize=128)
def tukey_lambda_table(lam: float) -> np.ndarray:
    from ..distributions import tukey_lambda_upper_quantile

    return build_table(lambda t: tukey_lambda_upper_quantile(t, torch.tensor(lam, dtype=torch.float64)))


@functools.lru_cache(maxsize=1)
def normal_table() -> np.ndarray:
    return build_table(lambda t: -torch.special.ndtri(t))
