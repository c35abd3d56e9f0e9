"""RowTap: each column tap's part of a sensor row has a row offset of its own, new in every
frame, through the real stage and its estimator."""
import numpy as np

from rawaug import NoiseProfile
from rawaug.effects import row_tap
from rawaug.statistics import row_tap_ratio, sensor_row_means

from base_camera import bias_stack

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
H, W = 96, 128  # packed: 192 sensor rows, 256 sensor columns


def taps(sigma=1.0, edges=(100,)):
    return {"col_edges": list(edges), "frame_h": H, "frame_w": W, "k": [K], "sigma_dn": [sigma]}


def stack(effects, seed, n=8, sensor=0):
    """(n, 4, H, W) bias frames (DN) at gain K with ``effects`` (token: entry), model G+R."""
    return bias_stack(BASE, effects, K, seed, n=n, size=(H, W), sensor=sensor)


def test_each_tap_has_its_own_row_offsets(samplers):
    """32 frames, taps at sensor column 100 and 180, 1.5 DN: the difference of two taps' sensor-row
    means has variance 2 x 1.5^2 plus their white noise; within 5 sd (of a variance over 32 x 192
    rows); between the halves of one tap only the white noise."""
    f = stack({"RowTap": taps(1.5, (100, 180))}, 1, n=32)
    means = []
    for lo, hi in ((0, 100), (100, 180), (180, 256), (0, 50), (50, 100)):
        part = np.zeros_like(f)
        cols = np.zeros(2 * W, dtype=bool)
        cols[lo:hi] = True
        # the packed channels' sensor columns: R and G2 on even ones, G1 and B on odd ones
        for c, parity in ((0, 0), (1, 1), (2, 1), (3, 0)):
            part[:, c] = np.where(cols[parity::2][None, None, :], f[:, c], np.nan)
        means.append(np.stack([np.nanmean(part[:, [0, 1]], axis=(1, 3)), np.nanmean(part[:, [3, 2]], axis=(1, 3))], axis=2)
                     .reshape(f.shape[0], -1))
    pixel = np.var(np.diff(f, axis=3)) / 2  # a pixel's white noise (neighbours in a row share the row's offsets)
    white = pixel * (1 / 100 + 1 / 80)  # the two levels' white noise (a sensor row's pixels in each tap)
    d = means[0] - means[1]
    d -= d.mean(axis=0)
    n = d.size
    assert abs(d.var() - (2 * 1.5**2 + white)) < 5 * (2 * 1.5**2 + white) * np.sqrt(2 / n), d.var()
    same = means[3] - means[4]
    same -= same.mean(axis=0)
    assert abs(same.var() - pixel * (2 / 50)) < 5 * pixel * (2 / 50) * np.sqrt(2 / n)


def test_estimate_finds_the_taps_and_none_without():
    """Ten sessions with one edge at sensor column 100 and 1.0 DN: the edge within 2 columns and
    sigma within 20 % in each (5 sd of a variance over 7 x 191 rows is 0.2 DN^2 on 1 DN^2); twenty
    sessions without taps, ten with 2 DN more row noise shared by whole rows: no edge (chance
    1e-3 per stack)."""
    base = [stack({}, s, sensor=1) for s in range(100, 104)]
    for session in range(10):
        est = row_tap.estimate(stack({"RowTap": taps()}, 10 + session), base, K, kind="bias")
        assert len(est["col_edges"]) == 1 and abs(est["col_edges"][0] - 100) <= 2, est["col_edges"]
        assert abs(est["sigma_dn"][0] - 1.0) < 0.2, est["sigma_dn"]
    for session in range(20):
        est = row_tap.estimate(stack({}, 40 + session), base, K, kind="bias")
        assert row_tap.empty(est), est["col_edges"]
    for session in range(10):  # 2 DN more row noise, shared by whole rows (a row pair's)
        f = stack({"RowPair": {"k": [K], "sigma_dn": [2.0]}}, 70 + session)
        assert row_tap.empty(row_tap.estimate(f, base, K, kind="bias")), session


def test_the_statistic_sees_the_taps():
    """row_tap_ratio: about 1 without taps (under 1.3 in 5 of 5), over 2 with 1 DN taps (5 of 5)."""
    for seed in range(5):
        assert row_tap_ratio(stack({}, 200 + seed)) < 1.3
        assert row_tap_ratio(stack({"RowTap": taps()}, 300 + seed)) > 2.0


def test_whole_rows_still_share_the_row_noise():
    """With taps, the sensor-row means still carry the model's row noise: their variance is at
    least the model's without taps."""
    with_taps = sensor_row_means(stack({"RowTap": taps()}, 5, n=16))
    plain = sensor_row_means(stack({}, 6, n=16))
    assert (with_taps - with_taps.mean(0)).var() > 0.9 * (plain - plain.mean(0)).var()


def test_bad_entries_are_refused():
    import pytest

    with pytest.raises(ValueError, match="strictly increasing"):
        BASE.with_effect("RowTap", taps(1.0, (120, 100)))
    with pytest.raises(ValueError, match="whole sensor columns"):
        BASE.with_effect("RowTap", taps(1.0, (300,)))
    with pytest.raises(ValueError, match="frame_h and frame_w"):
        BASE.with_effect("RowTap", {"col_edges": [10], "k": [K], "sigma_dn": [1.0]})
