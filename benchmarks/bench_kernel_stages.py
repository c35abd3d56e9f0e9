"""Where the fused kernel's time goes on CUDA: each stage alone, and the exact Poisson stage
against the number of electrons, at (8, 4, 512, 512), beside a device copy of the same
bytes (the bandwidth bound), in one process. Output as in benchmarks/results_h100/stages.txt.

    python benchmarks/bench_kernel_stages.py
"""
import sys
import time

import torch

from rawaug import RawNoiseAugment
from rawaug.engine import layout as L
from rawaug.engine.backend import synthesize_op
from rawaug.engine.transfer import to_device

FIXED = {"k": 1.0, "sigma_tl": 2.0, "lambda": 0.05, "sigma_r": 0.5, "ratio": 200.0}


def timed(fn, n=30):
    fn()
    torch.cuda.synchronize()
    start = time.perf_counter()
    for _ in range(n):
        fn()
    torch.cuda.synchronize()
    return (time.perf_counter() - start) / n


def main():
    if not torch.cuda.is_available():
        sys.exit("needs a CUDA device")
    dev = torch.device("cuda")
    clean = torch.rand(8, 4, 512, 512, device=dev) * 0.2
    dst = torch.empty_like(clean)
    t_copy = timed(lambda: dst.copy_(clean))
    print(f"copy {t_copy * 1e3:.3f} ms", flush=True)
    aug = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", fixed=FIXED)
    aug(clean)
    values, keys = to_device((aug._params["values"], aug._stream_keys(int(aug._params["seed"]))), dev)
    tables = aug._tables_on(dev)
    span = float(aug.profile.span_dn)
    for name, flags in [("none", 0), ("P*", L.SHOT_POISSON), ("P", L.SHOT_GAUSS), ("G*", L.READ_TUKEY), ("G", L.READ_GAUSS),
                        ("R", L.ROW), ("U", L.QUANT), ("C", L.BIAS), ("G*+P*+R+U", aug._flags)]:
        t = timed(lambda: synthesize_op(clean, values, keys, span, flags, *tables))
        print(f"{name:12s} {t * 1e3:.3f} ms  {t_copy / t:.1%} of the bound", flush=True)
    for level in (0.002, 0.02, 0.2, 1.0):
        c = torch.rand(8, 4, 512, 512, device=dev) * level
        t = timed(lambda: synthesize_op(c, values, keys, span, L.SHOT_POISSON, *tables))
        print(f"P* at clean U(0, {level}) (0-{level * span / 200:.0f} e-): {t * 1e3:.3f} ms", flush=True)


if __name__ == "__main__":
    main()
