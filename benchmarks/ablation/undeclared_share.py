"""How much of TestCam's noise its undeclared effects carry at each test setting of the ablation.

    python benchmarks/ablation/undeclared_share.py

A flat field at the mean level of the ablation's test tiles (and at 2 % of white) is captured
by TestCam (``testcam.capture``: its true model, rounded codes) and by the same camera
without ``Col`` and ``FPN`` (the ELD model it is built on); the share is the part of the
short exposure's noise variance (DN^2, over pixels and channels, 2 frames of 256 x 256) that
only the undeclared effects add.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import scenes  # noqa: E402
import testcam  # noqa: E402
from run import RATIOS, TEST_ISOS  # noqa: E402

from rawaug import NoiseProfile  # noqa: E402


def main() -> int:
    tiles = [t for _, t in scenes.test_tiles(128, 9)]  # the CPU scale's test tiles
    level = float(np.mean([t.mean() for t in tiles]))
    true, eld = testcam.true_profile(), NoiseProfile.load("SonyA7S2")
    print(f"mean level of the test tiles: {level:.3f} of white")
    for i, ratio in enumerate(RATIOS):
        iso = TEST_ISOS[i % len(TEST_ISOS)]  # as testcam.write_sid_layout assigns them
        cells = []
        for lv in (level, 0.02):
            flat = np.full((2, 4, 256, 256), lv, np.float32)
            v_true = float(testcam.capture(true, flat, iso, ratio, 1).var(axis=(1, 2, 3)).mean())
            v_eld = float(testcam.capture(eld, flat, iso, ratio, 1).var(axis=(1, 2, 3)).mean())
            cells.append(f"at {lv:.3f}: {v_true:6.1f} DN^2, undeclared {(v_true - v_eld) / v_true:5.1%}")
        print(f"x{ratio} (ISO {iso}): " + "; ".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
