"""Benchmark: stage-1 calibration of 10 bias frames and 10 flat pairs of 24 MP (6000x4000).

Frames are synthesized by rawaug at known parameters (uint16 raw codes, written as .npy to a
temporary folder, not timed); the timed part reads them back and runs ``calibrate_iso``.
Then the PPCC read-noise fit is compared at several subsample sizes, up to all pixels of one
bias frame: time and error of lambda and sigma_TL against the truth.

    python benchmarks/bench_calibrate.py [--width 6000 --height 4000 --n 10]
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from rawaug.calibration import calibrate_iso, estimate_read_noise
from rawaug.calibration.stage1 import estimate_row_noise, read_residual
from rawaug.calibration.synthetic import synthesize_packed
from rawaug.profile import NoiseProfile

TRUTH = dict(k=1.6, sigma_tl=4.0, lam=-0.05, sigma_r=0.8)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=6000)
    ap.add_argument("--height", type=int, default=4000)
    ap.add_argument("--n", type=int, default=10, help="bias frames and flat pairs")
    ap.add_argument("--full", action="store_true", default=True, help="also fit PPCC on all pixels of one frame")
    args = ap.parse_args(argv)
    prof = NoiseProfile.load("SonyA7S2")
    shape = (args.height // 2, args.width // 2)
    black = np.float32(prof.black_level)
    print(f"{args.n} bias frames + {args.n} flat pairs of {args.width}x{args.height} "
          f"({args.width * args.height / 1e6:.0f} MP); truth {TRUTH}; os.cpu_count() = {os.cpu_count()}")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        bias_paths, pair_paths = [], []
        levels = np.geomspace(0.02, 0.4, args.n)
        for i in range(args.n):
            p = Path(tmp) / f"bias{i}.npy"
            np.save(p, synthesize_packed(prof, 0.0, shape=shape, seed=i, **TRUTH))
            bias_paths.append(p)
            pair = []
            for j in range(2):
                q = Path(tmp) / f"flat{i}_{j}.npy"
                np.save(q, synthesize_packed(prof, float(levels[i]), shape=shape, seed=1000 + 2 * i + j, **TRUTH))
                pair.append(q)
            pair_paths.append(tuple(pair))
        print(f"synthesis (not timed): {time.perf_counter() - t0:.1f} s")

        def loader(path):
            return lambda: np.load(path).astype(np.float32) - black

        t0 = time.perf_counter()
        p = calibrate_iso([loader(b) for b in bias_paths], [(loader(a), loader(b)) for a, b in pair_paths], 1600,
                          max_samples=200_000, saturation_dn=prof.span_dn, black_clip_dn=-prof.black_level)
        elapsed = time.perf_counter() - t0
        print(f"\ncalibrate_iso (read + stage 1, PPCC on 200k values): {elapsed:.1f} s  (target < 60 s)")
        for name, true, got in (("K", TRUTH["k"], p.k), ("sigma_TL", TRUTH["sigma_tl"], p.sigma_tl),
                                ("sigma_r", TRUTH["sigma_r"], p.sigma_r), ("lambda", TRUTH["lam"], p.lam)):
            print(f"  {name:9s} true {true:8.4f}  estimated {got:8.4f}")

        bias = np.load(bias_paths[0]).astype(np.float32) - black
        residual = read_residual(bias, estimate_row_noise(bias).row_means).astype(np.float32)
        del bias
        sizes = [20_000, 200_000, 2_000_000] + ([None] if args.full else [])
        print(f"\nPPCC read-noise fit on one bias frame ({residual.size / 1e6:.0f} M values):")
        print(f"  {'samples':>10s} {'time s':>8s} {'lambda':>8s} {'|err|':>7s} {'sigma_TL':>9s} {'rel err':>8s}")
        for n in sizes:
            t0 = time.perf_counter()
            r = estimate_read_noise(residual, max_samples=n)
            dt = time.perf_counter() - t0
            print(f"  {r.n_samples:>10d} {dt:8.2f} {r.lam:8.4f} {abs(r.lam - TRUTH['lam']):7.4f} {r.sigma_tl:9.4f} "
                  f"{abs(r.sigma_tl / TRUTH['sigma_tl'] - 1):8.4f}")
    print("\nNote: the CPU is shared with other jobs; times are upper bounds of a quiet machine.")


if __name__ == "__main__":
    main()
