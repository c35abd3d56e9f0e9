"""ColBurst: sensor columns read with extra white noise, new columns in every frame, through the
real stage and its estimator."""
import math

import numpy as np

from rawaug import NoiseProfile
from rawaug.effects import column_burst, row_burst
from rawaug.statistics import burst_cols, burst_rows

from base_camera import bias_stack

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
BURSTS = {"density": 0.01, "k": [K], "sigma_dn": [3.0]}


def stack(effects, seed, n=8, size=96, sensor=0):
    """(n, 4, size, size) bias frames (DN) at gain K with ``effects`` (token: entry)."""
    return bias_stack(BASE, effects, K, seed, n=n, size=size, sensor=sensor)


def test_burst_columns_are_whole_sensor_columns_of_one_frame_at_the_density():
    """Over 64 frames of 192 sensor columns, the columns whose variance (both channels) exceeds the
    same frame's without bursts by 3 DN^2 x 0.5 number within 5 binomial sd of 1 %; their extra
    variance is 9 DN^2 within 5 sd of a mean over that many columns of 192 values; the rows see
    no bursts."""
    f = stack({"ColBurst": BURSTS}, 1, n=64)
    base = stack({}, 1, n=64)
    extra = np.empty((64, 192))
    for col_set, chans in ((0, [0, 3]), (1, [1, 2])):
        extra[:, col_set::2] = f[:, chans].var(axis=(1, 2), ddof=1) - base[:, chans].var(axis=(1, 2), ddof=1)
    hit = extra > 4.5
    n = hit.size
    assert abs(hit.sum() - 0.01 * n) < 5 * math.sqrt(0.01 * 0.99 * n), hit.sum()
    assert abs(extra[hit].mean() - 9.0) < 5 * math.sqrt((2 * 81 + 144) / 192 / hit.sum()), extra[hit].mean()
    assert np.all(np.abs(extra[~hit]) < 4.5)
    # a 3 DN burst over ~3.4 DN of read noise sits near burst_cols' threshold: about 0.4 % found (49 columns)
    assert burst_rows(f) == 0.0 and burst_cols(f) > 0.001


def test_estimate_finds_the_bursts_and_none_without():
    """Ten sessions of 8 bias frames of 256 sensor columns, bursts of 6 DN in 1 % of the columns:
    the share within 5 binomial sd of 1 % and the extra noise within 15 % of 6 DN in each; ten
    sessions without bursts: none (Poisson test at 1e-3 per stack), and no burst column in 5
    more; RowBurst finds none in the bursts' stacks."""
    bursts = {**BURSTS, "sigma_dn": [6.0]}
    base = [stack({}, s, size=128, sensor=1) for s in range(100, 104)]
    cols = 8 * 256
    for session in range(10):
        f = stack({"ColBurst": bursts}, 10 + session, size=128)
        est = column_burst.estimate(f, base, K, kind="bias")
        assert abs(est["density"] - 0.01) < 5 * math.sqrt(0.01 / cols), est
        assert abs(est["sigma_dn"][0] - 6.0) < 0.15 * 6.0, est
        assert row_burst.estimate(f, base, K, kind="bias")["density"] == 0.0
    none = [column_burst.estimate(stack({}, 30 + s, size=128), base, K, kind="bias") for s in range(10)]
    assert all(column_burst.empty(column_burst.combine([e])) for e in none), none
    assert max(burst_cols(stack({}, 50 + s, size=128)) for s in range(5)) == 0.0
