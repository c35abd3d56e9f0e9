"""FrameRow: the row noise of each frame at one of two levels (interference that comes and goes
between frames), its statistic and its estimator."""
import math

import numpy as np
import pytest

from rawaug import NoiseProfile
from rawaug.effects import frame_row_noise
from rawaug.statistics import frame_row_spread
from test_effects_loop import K, synth

ROW = {"model": "G+R", "sigma_r": 1.0, "sigma_g": 2.0}  # one camera's row noise, not drawn per frame
PLANTED = {"k": [K], "share": [0.25], "weak": [1.0], "strong": [10.0]}  # a quarter of the frames with 10 x sigma_r^2


def test_a_share_of_the_frames_has_the_stronger_row_noise():
    # 400 frames of 128 sensor rows: each frame's row-noise variance (sampling sd ~ 0.2 of it in
    # log) is 10 or 1 x sigma_r^2; the share above their geometric middle is 0.25 within 5
    # binomial sd, each group's mean within 5 of its standard errors
    n = 400
    levels = frame_row_noise.frame_row_levels(synth({"FrameRow": PLANTED}, batch=n, size=64, **ROW))
    high = levels > math.sqrt(10.0)
    assert abs(high.mean() - 0.25) < 5 * math.sqrt(0.25 * 0.75 / n), high.mean()
    for group, level in ((levels[high], 10.0), (levels[~high], 1.0)):
        assert abs(group.mean() / level - 1.0) < 5 * group.std(ddof=1) / group.mean() / math.sqrt(len(group)), group.mean()
    steady = frame_row_noise.frame_row_levels(synth({}, batch=n, size=64, seed=1, **ROW))
    assert abs(steady.mean() - 1.0) < 5 * steady.std(ddof=1) / math.sqrt(n)  # sigma_r^2 at one level


def test_estimate_finds_the_two_levels_and_little_for_one_level():
    # 20 stacks of 16 frames: share and levels within 5 standard errors of their means over the
    # stacks of the planted 0.25, 1 and 10 (logs for the levels); on steady row noise the stacks
    # find two levels only where sampling beat the syntheses' spread, and then close ones
    base = [synth({}, batch=16, size=64, seed=s, **ROW) for s in range(1, 9)]
    est = [frame_row_noise.estimate(synth({"FrameRow": PLANTED}, batch=16, size=64, seed=s, **ROW), base, K, kind="bias")
           for s in range(20, 40)]
    share = np.array([e["share"][0] for e in est])
    assert abs(share.mean() - 0.25) < 5 * share.std(ddof=1) / math.sqrt(len(est)) + 1e-9, share
    for key, level in (("weak", 1.0), ("strong", 10.0)):
        got = np.log([e[key][0] for e in est])
        assert abs(got.mean() - math.log(level)) < 5 * got.std(ddof=1) / math.sqrt(len(est)), (key, np.exp(got))
    steady = [frame_row_noise.estimate(synth({}, batch=16, size=64, seed=s, **ROW), base, K, kind="bias") for s in range(40, 60)]
    ratios = np.array([e["strong"][0] / e["weak"][0] for e in steady])
    assert np.sum(ratios > 1.0) <= 14 and ratios.max() < 3.0, ratios  # measured: 6 of 20, the largest 1.99
    combined = frame_row_noise.combine(est[:2] + steady[:2])
    assert combined["share"][0] == pytest.approx(np.mean([e["share"][0] for e in est[:2] + steady[:2]]))
    # the statistic: the planted stacks' spread far above the steady ones'
    assert (np.median([frame_row_spread(synth({"FrameRow": PLANTED}, batch=16, size=64, seed=s, **ROW)) for s in range(60, 66)])
            > 2 * max(frame_row_spread(b) for b in base))
    with pytest.raises(ValueError, match="bias and dark stacks of >= 3 frames"):
        frame_row_noise.estimate(base[0], base, K, kind="flat")


@pytest.mark.parametrize("params, words", [
    ({"k": [1.0], "share": [1.5], "weak": [1.0], "strong": [2.0]}, r"share \(of the frames with the stronger row noise\) must be in \[0, 1\], got 1.5"),
    ({"k": [1.0], "share": [0.5], "weak": [2.0], "strong": [1.0]}, r"must satisfy 0 <= weak <= strong <= 10000, got 2.0 and 1.0"),
    ({"k": [1.0], "share": [0.5], "weak": [1.0]}, "needs 'strong' with one value per k"),
])
def test_bad_entries_are_refused_by_name(params, words):
    with pytest.raises(ValueError, match=words):
        NoiseProfile.load("SonyA7S2").with_effect("FrameRow", params)
