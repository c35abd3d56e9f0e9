"""RowSpikes: sensor rows offset far in one frame, new rows in every frame, through the real stage,
its statistic and its estimator."""
import math

import numpy as np

from rawaug import NoiseProfile
from rawaug.effects import row_spikes
from rawaug.statistics import row_spike_fraction, sensor_row_means

from base_camera import bias_stack

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
SPIKES = {"density": 0.004, "log_std": 0.3, "negative": 0.5, "k": [K], "median_dn": [25.0]}


def stack(effects, seed, n=8, size=96, sensor=0):
    """(n, 4, size, size) bias frames (DN) at gain K with ``effects`` (token: entry)."""
    return bias_stack(BASE, effects, K, seed, n=n, size=size, sensor=sensor)


def test_row_spikes_offset_whole_sensor_rows_of_one_frame_at_the_density():
    """Over 64 frames of 192 sensor rows, the rows whose mean moved by more than 8 DN (the same
    frames without the stage: row noise ~1 DN) number within 5 binomial sd of 0.4 %; both
    packed channels of the sensor row move alike; the offsets' log is normal about log 25 with
    sd 0.3 and half of them are negative, within 5 sd each."""
    f, base = stack({"RowSpikes": SPIKES}, 1, n=64), stack({}, 1, n=64)
    moved = sensor_row_means(f) - sensor_row_means(base)  # (64, 192): the offsets alone
    hit = np.abs(moved) > 8.0
    n, m = hit.size, int(hit.sum())
    assert abs(m - 0.004 * n) < 5 * math.sqrt(0.004 * n), m
    for row_set, chans in ((0, [0, 1]), (1, [2, 3])):
        d = f[:, chans].mean(axis=3) - base[:, chans].mean(axis=3)  # (64, 2, 96) per packed channel
        assert np.allclose(d[:, 0], d[:, 1]), row_set
    logs = np.log(np.abs(moved[hit]))
    assert abs(logs.mean() - math.log(25.0)) < 5 * 0.3 / math.sqrt(m) and abs(logs.std() - 0.3) < 5 * 0.3 / math.sqrt(2 * m)
    assert abs(np.mean(moved[hit] < 0) - 0.5) < 5 * 0.5 / math.sqrt(m)
    assert np.all(np.abs(moved[~hit]) < 1e-9)


def test_estimate_finds_the_spikes_and_none_without():
    """Ten sessions of 8 bias frames of 256 sensor rows (row noise ~1 DN): the density within 5
    binomial sd of 0.4 %, the log median within 5 sd (0.3 / sqrt(events)) of log 25 DN; ten sessions without: none
    (Poisson test at 1e-3 per stack), and the statistic 0 in 20 stacks of the model alone (an
    event is 8 robust sigma: ~1e-15 per row for Gaussian rows)."""
    base = [stack({}, s, size=128, sensor=1) for s in range(100, 104)]
    rows = 8 * 256
    for session in range(10):
        est = row_spikes.estimate(stack({"RowSpikes": SPIKES}, 10 + session, size=128), base, K, kind="bias")
        assert abs(est["density"] - 0.004) < 5 * math.sqrt(0.004 / rows), est
        assert abs(math.log(est["median_dn"][0] / 25.0)) < 5 * 0.3 / math.sqrt(est["events"][0]), est
    none = [row_spikes.estimate(stack({}, 30 + s, size=128), base, K, kind="bias") for s in range(10)]
    assert all(row_spikes.empty(row_spikes.combine([e])) for e in none), none
    assert max(row_spike_fraction(stack({}, 50 + s, size=128)) for s in range(20)) == 0.0


def test_a_row_that_jumps_in_several_frames_is_not_a_spike():
    """A row offset in two frames of eight is a telegraph's, not a glitch: the statistic leaves it out."""
    f = stack({}, 3, size=64)
    f[2, 0:2, 10, :] += 30.0  # sensor row 20 in frame 2 only: an event
    f[4, 2:4, 30, :] += 30.0  # sensor row 61 in frames 4 and 6: not one
    f[6, 2:4, 30, :] += 30.0
    assert row_spike_fraction(f) == 1.0 / (8 * 128)
