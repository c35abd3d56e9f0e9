"""Compile the fused Triton kernel to cubins without a GPU (run by test_triton_compiles.py
in a process of its own: under TRITON_INTERPRET=1 ``triton.jit`` makes interpreted
functions, which cannot be compiled). Prints one JSON line: {branch@arch: cubin bytes or error}."""
import json
import os
import sys

os.environ.pop("TRITON_INTERPRET", None)

import torch  # noqa: E402
import triton  # noqa: E402
from triton.backends.compiler import GPUTarget  # noqa: E402
from triton.compiler import ASTSource  # noqa: E402

from rawaug import RawNoiseAugment  # noqa: E402
from rawaug.engine import backend  # noqa: E402
from rawaug.engine import layout as L  # noqa: E402
from rawaug.gpu import fused  # noqa: E402

from rawaug.effects import EFFECTS  # noqa: E402

ALL = (max(cls.flag for cls in EFFECTS.values()) << 1) - 1  # every stage flag up to the highest registered
# every stage; then the switches' other branches: P (not P*), G* and G (not the measured read table)
BRANCHES = {"all": ALL, "P,G*": ALL & ~(L.SHOT_POISSON | L.READ_TABLE), "G": ALL & ~(L.SHOT_POISSON | L.READ_TABLE | L.READ_TUKEY)}
# every stage in one of two kernels: alternate flags (Triton's coalescing pass grows faster than the kernel:
# every stage at once takes ~50 s to compile, the two halves ~12 s together)
_BITS = [1 << i for i in range(ALL.bit_length()) if ALL >> i & 1]
BRANCHES.update({"even": sum(_BITS[0::2]), "odd": sum(_BITS[1::2])})
TYPES = {torch.float32: "fp32", torch.float64: "fp64", torch.int64: "i64", torch.int32: "i32"}


def launch_arguments():
    """The kernel's arguments in a real call on CPU tensors (nothing is launched)."""
    seen = {}

    def capture(clean, out, values, keys, span, flags, fine, coarse, grids, normal, code_lut, read_lut, block=1024):
        seen["args"] = [clean, out, values, keys, float(span), clean.shape[2], clean.shape[3], *fine, *coarse, grids,
                        grids.shape[1], grids.shape[2], normal, code_lut, code_lut.shape[1], read_lut, read_lut.shape[1]]
        seen["P"] = values.shape[1]
        return out

    fused.launch = capture
    os.environ["TRITON_INTERPRET"] = "1"  # the backend's guard for CPU tensors; the kernel is already a JITFunction
    backend.set_backend("triton")
    RawNoiseAugment("SonyA7S2")(torch.rand(1, 4, 8, 8))
    return seen["args"], seen["P"]


def main(targets):
    args, n_params = launch_arguments()
    names = fused.fused_kernel.arg_names
    sig = {n: "*" + TYPES[a.dtype] if isinstance(a, torch.Tensor) else "fp32" if isinstance(a, float) else "i32"
           for n, a in zip(names, args)}
    result = {}
    for target in targets:
        branch, arch = target.split("@")
        low, high = L.flag_words(BRANCHES[branch])
        consts = {"FLAGS": low, "FLAGS_HIGH": high, "P": n_params, "BLOCK": 128}  # the GPU default
        src = ASTSource(fused.fused_kernel, {**sig, **{n: "constexpr" for n in consts}},
                        constexprs={(names.index(k),): v for k, v in consts.items()})
        try:
            kernel = triton.compile(src, target=GPUTarget("cuda", int(arch), 32))
            result[target] = len(kernel.asm["cubin"]) if "fused_kernel" in kernel.asm["ptx"] else "no fused_kernel in the PTX"
        except Exception as e:  # reported, asserted by the test
            result[target] = f"{type(e).__name__}: {e}"[-2000:]
    print(json.dumps(result))


if __name__ == "__main__":
    main(sys.argv[1:])
