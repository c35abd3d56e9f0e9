"""The fused Triton kernel's time against its block size and warp count at (32, 4, 512, 512),
beside a device copy of the same bytes, and whether the noise stays the same (it must: the
counters are per element). Output as in benchmarks/results_h100/blocks.txt.

    python benchmarks/bench_kernel_blocks.py [--profile LOOP_PROFILE.yaml]
"""
import argparse
import sys
import time

import torch

from rawaug import RawNoiseAugment
from rawaug.engine import backend as B
from rawaug.engine.transfer import to_device
from rawaug.gpu import fused

FIXED = {"k": 1.0, "sigma_tl": 2.0, "lambda": 0.05, "sigma_r": 0.5, "ratio": 200.0}
CONFIGS = ((1024, 4), (1024, 8), (512, 4), (512, 8), (256, 4), (256, 8), (128, 4), (256, 2))


def timed(fn, n=20):
    for _ in range(3):
        fn()
    torch.cuda.synchronize()
    start = time.perf_counter()
    for _ in range(n):
        fn()
    torch.cuda.synchronize()
    return (time.perf_counter() - start) / n


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--profile", default=None, help="also a loop profile, with its effects")
    args = parser.parse_args(argv)
    if not torch.cuda.is_available():
        sys.exit("needs a CUDA device")
    dev = torch.device("cuda")
    clean = torch.rand(32, 4, 512, 512, device=dev) * 0.2
    dst = torch.empty_like(clean)
    t_copy = timed(lambda: dst.copy_(clean))
    print(f"copy (32,4,512,512) {t_copy * 1e3:.3f} ms", flush=True)
    profiles = [("G*+P*+R+U", "SonyA7S2")] + ([("loop", args.profile)] if args.profile else [])
    for name, prof in profiles:
        aug = RawNoiseAugment(prof, model="G*+P*+R+U", fixed=FIXED)
        aug(clean[:1])
        values = aug._params["values"][:1].expand(32, -1).contiguous()
        values, keys = to_device((values, aug._stream_keys(int(aug._params["seed"]))), dev)
        grids, code_lut, read_lut = aug._tables_on(dev)
        fine, coarse = B.poisson_tables(str(dev))
        normal = B.normal_table_on(str(dev))
        ref = None
        for block, warps in CONFIGS:
            out = torch.empty_like(clean)
            t = timed(lambda: fused.launch(clean, out, values, keys, float(aug.profile.span_dn), aug._flags, fine, coarse, grids, normal,
                                           code_lut, read_lut, block=block, num_warps=warps))
            same = "ref" if ref is None else ("same noise" if torch.equal(out, ref) else "DIFFERENT")
            ref = out.clone() if ref is None else ref
            print(f"{name:10s} BLOCK {block:5d} warps {warps}: {t * 1e3:.3f} ms = {t_copy / t:.1%} of the bound; {same}", flush=True)


if __name__ == "__main__":
    main()
