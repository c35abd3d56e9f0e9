"""Time ``rawaug loop`` on a whole camera session: 6 ISOs x (8 bias + 4 dark + 10 flat)
frames of a simulated camera (the SonyA7S2 ELD model plus column noise), written as 16-bit
``.npy`` frames with a manifest, calibrated and looped end to end through the CLI.

    python benchmarks/bench_loop.py --megapixels 0.25 [--n-synth 12]

The issue's target is 12 MP frames in under 5 minutes on the 2-core machine; the time is
printed with the frame size, never asserted.
"""
from __future__ import annotations

import argparse
import csv
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from rawaug import NoiseProfile, RawNoiseAugment, unpack
from rawaug.cli import main as rawaug_main

ISOS = (400, 800, 1600, 3200, 6400, 12800)


def write_session(folder: Path, megapixels: float) -> Path:
    base = NoiseProfile.load("SonyA7S2")
    camera = base.with_effect("Col", {"seed": 3, "k": [1.0], "sigma_dn": [0.8], "fixed_dn": [1.2]})
    side = int(np.sqrt(megapixels * 1e6 / 4)) // 2 * 2  # packed side: 4 side^2 pixels
    rows = []
    for i, iso in enumerate(ISOS):
        k = 0.0009563 * iso
        frames = ([("bias", 1e-4, 0.0)] * 8 + [("dark", 2.0, 0.0)] * 4
                  + [("flat", 0.01 * 2 ** (j // 2), 0.02 * 2 ** (j // 2)) for j in range(10)])  # one light: a flat series
        # one camera: the ELD model's parameters fixed per ISO (medians of its relations), as a
        # sensor has them; drawn anew for every frame they would vary as no sensor's do
        lam = base.tukey_shape.values[min(range(len(base.tukey_shape.k)), key=lambda j: abs(base.tukey_shape.k[j] - k))]
        per_iso = {"k": k, "sigma_tl": base.tukey_scale.median(k), "lambda": float(lam), "sigma_r": base.row_scale.median(k)}
        for n, (kind, exposure, level) in enumerate(frames):
            fixed = {**per_iso, "exposure_s": exposure, "sensor": 0}  # one sensor: its fixed patterns in every frame
            aug = RawNoiseAugment(camera, model="G*+P*+R", ratio=1.0, fixed=fixed,
                                  generator=torch.Generator().manual_seed(1000 * i + n), rank_seeding=False)
            dn = aug(torch.full((1, 4, side, side), min(level, 0.6))).numpy()[0] * base.span_dn
            codes = np.clip(np.rint(dn + base.black_level), 0, base.white_level).astype(np.uint16)
            name = f"{kind}_{iso}_{n:02d}.npy"
            np.save(folder / name, unpack(codes, "RGGB"))
            rows.append([name, kind, iso, exposure, "RGGB", 512, 16383])
    manifest = folder / "manifest.csv"
    with open(manifest, "w", newline="") as f:
        csv.writer(f).writerows([["path", "kind", "iso", "exposure_s", "cfa", "black_level", "white_level"]] + rows)
    return manifest


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--megapixels", type=float, default=0.25, help="frame size, MP (the target: 12)")
    ap.add_argument("--n-synth", type=int, default=12)
    ap.add_argument("--loop-size", type=int, default=256, help="rawaug loop --loop-size (packed pixels per side diagnosed)")
    ap.add_argument("--keep", default=None, help="folder to keep the loop's report in (default: discarded)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "frames").mkdir()
        start = time.perf_counter()
        manifest = write_session(tmp / "frames", args.megapixels)
        made = time.perf_counter() - start
        start = time.perf_counter()
        report = Path(args.keep) if args.keep else tmp / "report"
        code = rawaug_main(["loop", str(manifest), "--out", str(tmp / "loop.yaml"), "--report", str(report),
                            "--n-synth", str(args.n_synth), "--no-progress", "--loop-size", str(args.loop_size)])
        took = time.perf_counter() - start
        added = NoiseProfile.load(tmp / "loop.yaml").effects if code == 0 else {}
    print(f"{len(ISOS)} ISOs x (8 bias + 4 dark + 10 flat) frames of {args.megapixels:g} MP, n_synth {args.n_synth}, "
          f"loop size {args.loop_size}, "
          f"{torch.get_num_threads()} threads: writing the frames {made:.0f} s; rawaug loop (calibration included) "
          f"{took:.0f} s (exit {code}); added {sorted(added)} (planted: Col). Target: 12 MP in < 300 s.")


if __name__ == "__main__":
    main()
