"""BlackStep: the black level steps at a row drawn anew in every frame, its statistic and its
estimator."""
import math

import numpy as np
import pytest
import torch
from scipy import stats

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import black_step
from rawaug.engine import layout as L
from rawaug.statistics import row_step_scan, row_step_z
from test_effects_loop import K, synth

ROW = {"model": "G+R", "sigma_r": 0.5, "sigma_g": 2.0}
PLANTED = {"k": [K], "share": [1.0], "mean_dn": [1.5], "sd_dn": [0.5]}


def stepped_frames(params, batch, seed=0, size=64):
    """(frames (B, 4, size, size) DN, planted first stepped sensor row (B,), planted size (B,))."""
    prof = NoiseProfile.load("SonyA7S2").with_effect("BlackStep", params)
    aug = RawNoiseAugment(prof, model="G+R", ratio=1.0, fixed={"k": K, "sigma_g": 2.0, "sigma_r": 0.5, "sensor": 0},
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    out = (aug(torch.zeros(batch, 4, size, size, dtype=torch.float64)) * prof.span_dn).numpy()
    v = aug._params["values"]
    return out, np.ceil(v[:, L.COLUMN["bstep_at"]].numpy() * 2 * size), v[:, L.COLUMN["bstep_dn"]].numpy()


def test_each_frame_steps_from_its_drawn_row_by_its_drawn_size():
    frames, at, size = stepped_frames(PLANTED, batch=64)
    rows = frames[:, [0, 1]].mean(axis=(1, 3))  # the even sensor rows (R, G1): (B, 64)
    y = 2 * np.arange(64)
    for b in range(64):  # the planted step in the rows' means, each mean's noise ~0.5 DN of row noise
        below, above = rows[b, y >= at[b]], rows[b, y < at[b]]
        if len(below) >= 4 and len(above) >= 4:
            se = 0.5 * math.sqrt(1 / len(below) + 1 / len(above)) + 2.0 / math.sqrt(64 * 2 * len(below))
            assert abs(below.mean() - above.mean() - size[b]) < 5 * se, b
    # the rows uniform over the frame, the sizes normal of 1.5 +- 0.5 (each within 5 sd)
    assert stats.kstest(at / 128.0, "uniform").pvalue > 1e-3
    assert abs(size.mean() - 1.5) < 5 * 0.5 / 8 and abs(size.std(ddof=1) - 0.5) < 5 * 0.5 / math.sqrt(2 * 63)
    # a share of 0.5: about half the frames without a step (5 binomial sd)
    _, _, half = stepped_frames({**PLANTED, "share": [0.5]}, batch=200, seed=1)
    assert abs(np.mean(half == 0.0) - 0.5) < 5 * math.sqrt(0.25 / 200)


def test_estimate_finds_the_steps_and_none_in_steady_frames():
    # 10 stacks of 8 frames with a step of 1.5 +- 0.5 DN in every frame (row noise 0.5 DN):
    # measured, 0.625 to 1.0 of a stack's frames found (a small step, or one near an end, is
    # not), the pooled mean and spread within 5 of their standard errors; 20 stacks of steady
    # row noise: a frame found in 3 of 20 (one frame each), none of them in more than 1 frame
    base = [synth({}, batch=8, size=64, seed=s, **ROW) for s in range(1, 9)]
    est = [black_step.estimate(stepped_frames(PLANTED, batch=8, seed=s)[0], base, K, kind="bias") for s in range(20, 30)]
    assert all(e["share"][0] >= 0.5 for e in est), [e["share"] for e in est]
    pooled = black_step.combine(est)
    steps = sum(e["steps"] for e in est)
    assert abs(pooled["mean_dn"][0] - 1.5) < 5 * 0.5 / math.sqrt(steps), pooled
    assert abs(pooled["sd_dn"][0] - 0.5) < 5 * 0.5 / math.sqrt(2 * steps) + 0.1, pooled
    steady = [black_step.estimate(synth({}, batch=8, size=64, seed=s, **ROW), base, K, kind="bias") for s in range(40, 60)]
    found = [e["share"][0] for e in steady]
    assert sum(f > 0 for f in found) <= 5 and max(found) <= 0.125, found
    # the statistic: every planted stack above every steady one
    assert min(row_step_z(stepped_frames(PLANTED, batch=8, seed=s)[0]) for s in range(60, 64)) > max(row_step_z(b) for b in base)
    with pytest.raises(ValueError, match="bias or dark stacks of >= 3 frames"):
        black_step.estimate(base[0], base, K, kind="flat")


def test_the_scan_finds_a_step_where_it_is():
    frames, at, _ = stepped_frames({**PLANTED, "sd_dn": [0.0], "mean_dn": [3.0]}, batch=8, seed=5)
    z, found, _, _ = black_step.locate_steps(frames)
    inside = (at > 16) & (at < 112)  # away from the ends the scan leaves out
    assert np.all(np.abs(found[inside] - at[inside]) <= 4), (found, at)


@pytest.mark.parametrize("params, words", [
    ({"k": [1.0], "share": [1.5], "mean_dn": [1.0], "sd_dn": [0.0]}, r"share \(of the frames with a step\) must be in \[0, 1\], got 1.5"),
    ({"k": [1.0], "share": [0.5], "mean_dn": [1.0], "sd_dn": [-1.0]}, "sd_dn must be >= 0, got -1.0"),
    ({"k": [1.0], "share": [0.5], "mean_dn": [1.0]}, "needs 'sd_dn' with one value per k"),
])
def test_bad_entries_are_refused_by_name(params, words):
    with pytest.raises(ValueError, match=words):
        NoiseProfile.load("SonyA7S2").with_effect("BlackStep", params)
