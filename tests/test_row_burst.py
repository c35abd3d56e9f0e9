"""RowBurst: sensor rows read with extra white noise, new rows in every frame, through the real
stage and its estimator."""
import math

import numpy as np

from rawaug import NoiseProfile
from rawaug.effects import row_burst
from rawaug.statistics import burst_rows

from base_camera import bias_stack

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
BURSTS = {"density": 0.01, "k": [K], "sigma_dn": [3.0]}


def stack(effects, seed, n=8, size=96, sensor=0):
    """(n, 4, size, size) bias frames (DN) at gain K with ``effects`` (token: entry)."""
    return bias_stack(BASE, effects, K, seed, n=n, size=size, sensor=sensor)


def test_burst_rows_are_whole_sensor_rows_of_one_frame_at_the_density():
    """Over 64 frames of 192 sensor rows, the rows whose variance (both channels, about the frame's
    row) exceeds the others' by 3 DN^2 x 0.5 number within 5 binomial sd of 1 %, both packed
    channels of a sensor row together; their extra variance is 9 DN^2 within 5 sd of a mean
    over that many rows of 192 values."""
    f = stack({"RowBurst": BURSTS}, 1, n=64)
    base = stack({}, 1, n=64)
    extra = np.empty((64, 192))
    for row_set, chans in ((0, [0, 1]), (1, [2, 3])):
        v = f[:, chans].var(axis=(1, 3), ddof=1) - base[:, chans].var(axis=(1, 3), ddof=1)  # the same noise but the bursts
        extra[:, row_set::2] = v
    hit = extra > 4.5
    n = hit.size
    assert abs(hit.sum() - 0.01 * n) < 5 * math.sqrt(0.01 * 0.99 * n), hit.sum()
    # a burst row's extra variance: 9 DN^2 plus the cross term, sd ~ sqrt(2 x 9^2 / 192 + 4 x 9 x 4 / 192)
    assert abs(extra[hit].mean() - 9.0) < 5 * math.sqrt((2 * 81 + 144) / 192 / hit.sum()), extra[hit].mean()
    assert np.all(np.abs(extra[~hit]) < 4.5)


def test_estimate_finds_the_bursts_and_none_without():
    """Ten sessions of 8 bias frames of 256 sensor rows (read noise ~3.4 DN), bursts of 6 DN in 1 %
    of the rows (a burst row's robust variance ~3.4x its row's, the threshold 2.3x): the share
    within 5 binomial sd of 1 % and the extra noise within 15 % of 6 DN in each; ten sessions
    without bursts: none (Poisson test at 1e-3 per stack), and no burst row in 5 more."""
    bursts = {**BURSTS, "sigma_dn": [6.0]}
    base = [stack({}, s, size=128, sensor=1) for s in range(100, 104)]
    rows = 8 * 256
    for session in range(10):
        est = row_burst.estimate(stack({"RowBurst": bursts}, 10 + session, size=128), base, K, kind="bias")
        assert abs(est["density"] - 0.01) < 5 * math.sqrt(0.01 / rows), est
        assert abs(est["sigma_dn"][0] - 6.0) < 0.15 * 6.0, est
    none = [row_burst.estimate(stack({}, 30 + s, size=128), base, K, kind="bias") for s in range(10)]
    assert all(row_burst.empty(row_burst.combine([e])) for e in none), none
    assert max(burst_rows(stack({}, 50 + s, size=128)) for s in range(5)) == 0.0


def test_the_share_is_the_stacks_that_see_bursts():
    """A gain whose read noise hides the bursts finds none: its stack does not lower the share."""
    seen = {"density": 0.01, "k": [1.0], "sigma_dn": [3.0], "rows": [2048]}
    hidden = {"density": 0.0, "k": [3.0], "sigma_dn": [0.0], "rows": [2048]}
    out = row_burst.combine([seen, hidden, {**seen, "density": 0.02, "rows": [1024]}])
    assert out["density"] == (0.01 * 2048 + 0.02 * 1024) / 3072 and out["k"] == [1.0] and out["sigma_dn"] == [3.0], out
    assert row_burst.empty(row_burst.combine([hidden]))
