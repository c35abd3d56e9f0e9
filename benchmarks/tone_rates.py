"""False tones and amplitude of the column and diagonal banding estimators, over many stacks.

Stacks of 8 packed frames of 64 x 64 of one camera (read noise 2 DN, row noise 0.5 DN, K 1)
without a tone: how many get one from ``column_banding.estimate`` / ``diagonal_banding.estimate``
(designed: family-wise 1e-3 per stack); and a 1.2 DN tone in 20 stacks of 6 frames: its
estimated amplitude, mean +- sd.

    python benchmarks/tone_rates.py [--stacks N]
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import column_banding, diagonal_banding

BASE = NoiseProfile.load("SonyA7S2")
CAMERA = {"k": 1.0, "sigma_g": 2.0, "sigma_r": 0.5, "sensor": 0}
PLANTED = {"ColBand": {"k": [1.0], "freq_per_col": [[0.093]], "amplitude_dn": [[1.2]]},
           "DiagBand": {"k": [1.0], "freq_per_col": [[0.11]], "freq_per_row": [[0.23]], "amplitude_dn": [[1.2]]}}
MODULES = {"ColBand": column_banding, "DiagBand": diagonal_banding}


def stack(seed: int, frames: int, effects=None) -> np.ndarray:
    """(frames, 4, 64, 64) DN of the camera, plus ``effects``."""
    prof = BASE
    for token, params in (effects or {}).items():
        prof = prof.with_effect(token, params)
    aug = RawNoiseAugment(prof, model="G+R", ratio=1.0, fixed=CAMERA, generator=torch.Generator().manual_seed(seed),
                          rank_seeding=False)
    return (aug(torch.zeros(frames, 4, 64, 64, dtype=torch.float64)) * prof.span_dn).numpy()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stacks", type=int, default=300, help="stacks without a tone")
    args = parser.parse_args(argv)
    base = [stack(s, 8) for s in range(1, 6)]  # the model's syntheses
    for token, module in MODULES.items():
        found = sum(bool(module.estimate(stack(1000 + s, 8), base, 1.0)["amplitude_dn"][0]) for s in range(args.stacks))
        amps = [module.estimate(stack(2000 + s, 6, {token: PLANTED[token]}), base, 1.0)["amplitude_dn"][0] for s in range(20)]
        a = np.array([v[0] if v else 0.0 for v in amps])
        print(f"{token}: {found} of {args.stacks} stacks without a tone got one; 1.2 DN planted: "
              f"{a.mean():.3f} +- {a.std(ddof=1):.3f} DN over 20 stacks", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
