"""Run the closed loop on the measured data and print the before/after tables (markdown).

1. SonyA7S2 per-ISO table (PMN, 28 ISOs): regime change and noise floor of the joint model.
2. IMX686 per-frame bias fits (PMN, ISO 100 and 6400): frame-to-frame black-level error.
3. The real InfiniteISP dark frame (1920x1080, 12 bit, BGGR, ISO unknown): single-frame
   statistics only; base read/row noise measured on the frame itself (stage 1).

Usage: python benchmarks/loop_measured.py [--dark PATH] [--n-synth 8]
"""
from __future__ import annotations

import argparse
import time
from importlib import resources
from pathlib import Path

import numpy as np

from rawaug import NoiseProfile
from rawaug.calibration.joint import read_parameter_table
from rawaug.calibration.stage1 import estimate_read_noise, estimate_row_noise, read_residual
from rawaug.io import read_frame
from rawaug.loop import FrameStack, run_frame_loop
from rawaug.loop.parameters import frame_table_loop, parameter_loop, read_frame_table
from rawaug.loop.report import outcome_summary, residual_table, steps_table

DATA = Path(str(resources.files("rawaug") / "data" / "measured" / "PMN"))
# the real dark frame: whole in shared/ beside the checkout (not copied into the project),
# else the 512x512 crop of it bundled with the tests
ROOT = Path(__file__).resolve().parents[1]
DARK = ROOT.parent / "shared/data/frames/InfiniteISP/BlackImage_1920x1080_12bits_BGGR.raw"
DARK_CROP = ROOT / "tests/data/InfiniteISP_BlackImage_crop512_y0_x1408_12bits_BGGR.raw"
IMX686_K = {100: 0.1366021, 6400: 8.7425333}  # PMN_noise_params_extracted.json, IMX686_specific


def sony():
    print("## SonyA7S2 per-ISO table (PMN, 28 ISOs)\n")
    result = parameter_loop(read_parameter_table(DATA / "PMN_noise_params_extracted.json"))
    print("Error: rms residual of log(sigma) over the 28 ISOs.\n")
    print(steps_table(result["steps"]))


def imx686():
    for iso, k in IMX686_K.items():
        print(f"## IMX686 ISO {iso} per-frame bias fits (PMN)\n")
        out = frame_table_loop(read_frame_table(DATA / f"IMX686_iso{iso}_per_frame_bias_fits.csv"), 3472 // 2, 4624 // 2, k)
        print(steps_table(out["steps"]))
        print("".join(f"{token} found: {params}\n" for token, params in out["effects"].items()))
        print(residual_table(out["before"], "before"))
        print(residual_table(out["after"], "after"))


def _summary(token, params):
    """An effect's profile entry in a line (the FPN grid and the CodeMap table are long)."""
    if token == "FPN":
        return f"white sigma {params['sigma_dn'][0]:.3g} DN, {len(params['shading_dn'][0])}x{len(params['shading_dn'][0][0])} shading grid"
    if token == "CodeMap":
        m = params["map_dn"][0]
        return f"{len(set(m))} codes used for {len(m)} whole DN from {params['lo_dn'][0]:g} DN"
    if token == "ReadDist":
        q = np.asarray(params["quantiles_dn"][0])
        return (f"measured quantiles per channel, {q.shape[-1]} normal scores; 1 / 50 / 99 % of G1: "
                + " / ".join(f"{v:.2f}" for v in np.interp([-2.326, 0.0, 2.326], np.linspace(-6, 6, q.shape[-1]), q[1])) + " DN")
    return str({k: v for k, v in params.items() if k != "seed"})


def dark(path, n_synth):
    path = Path(path)
    width, height = (512, 512) if "crop512" in path.name else (1920, 1080)
    print(f"## InfiniteISP dark frame ({path.name}: {width}x{height}, 12 bit, BGGR, single frame)\n")
    frame = read_frame(path, width=width, height=height, dtype="<u2", cfa="BGGR", black_level=0, white_level=4095)
    packed = frame.packed_dn()[None].astype(np.float64)
    row = estimate_row_noise(packed[0])
    read = estimate_read_noise(read_residual(packed[0], row.row_means))
    data = NoiseProfile.load("SonyA7S2").to_dict()
    data["camera"] = "InfiniteISP dark frame"
    data["sensor"].update(black_level=0, white_level=4095, bit_depth=12, cfa="BGGR")
    base = NoiseProfile.from_dict(data)  # only the levels matter: every base sigma is fixed below
    stack = FrameStack(packed, 1.0, label="dark frame",
                       base={"sigma_tl": read.sigma_tl, "lambda": read.lam, "sigma_g": read.sigma_g, "sigma_r": row.sigma_r})
    print(f"base (stage 1 on the frame): sigma_TL {read.sigma_tl:.3f} DN, lambda {read.lam:.3f}, sigma_r {row.sigma_r:.3f} DN\n")
    result = run_frame_loop([stack], base, n_synth=n_synth, seed=0)
    print(outcome_summary(result) + "\n")
    print(steps_table([s.to_dict() for s in result.steps]))
    print("effects: " + "; ".join(f"{t}: {_summary(t, p)}" for t, p in result.profile.effects.items()) + "\n")
    print(residual_table([r.to_dict() for r in result.initial["dark frame"]], "before"))
    print(residual_table([r.to_dict() for r in result.final["dark frame"]], "after"))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dark", default=DARK)
    ap.add_argument("--n-synth", type=int, default=8)
    args = ap.parse_args()
    t = time.time()
    sony()
    imx686()
    dark_path = Path(args.dark) if Path(args.dark).is_file() else DARK_CROP
    if dark_path != Path(args.dark):
        print(f"(the whole dark frame {args.dark} is not here: its bundled 512x512 crop is used)\n")
    dark(dark_path, args.n_synth)
    print(f"\n(elapsed {time.time() - t:.0f} s)")
