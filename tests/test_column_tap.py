"""ColTap: each column tap has temporal column noise of its own level, through the real stage,
its statistic and its estimator."""
import numpy as np
import pytest

from rawaug import NoiseProfile
from rawaug.effects import column_tap
from rawaug.statistics import col_noise_spread, column_temporal_variance

from base_camera import bias_stack

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
H, W = 96, 128  # packed: 192 sensor rows, 256 sensor columns


def taps(sigmas=(1.2, 0.0), edges=(128,)):
    return {"col_edges": list(edges), "frame_h": H, "frame_w": W, "k": [K], "sigma_dn": [list(sigmas)]}


def stack(effects, seed, n=8, sensor=0):
    """(n, 4, H, W) bias frames (DN) at gain K with ``effects`` (token: entry), model G+R."""
    return bias_stack(BASE, effects, K, seed, n=n, size=(H, W), sensor=sensor)


def test_each_tap_has_its_own_column_noise():
    """32 frames, taps cut at sensor columns 80 and 170 with 1.5, 0 and 0.8 DN: each tap's mean
    column temporal variance, less the same without taps, is its std squared within 5 sd (of a
    variance over 31 x the tap's columns)."""
    with_taps = column_temporal_variance(stack({"ColTap": taps((1.5, 0.0, 0.8), (80, 170))}, 1, n=32))
    plain = column_temporal_variance(stack({}, 2, n=32))
    for (lo, hi), s in (((0, 80), 1.5), ((80, 170), 0.0), ((170, 256), 0.8)):
        got = with_taps[lo:hi].mean() - plain[lo:hi].mean()
        sd = with_taps[lo:hi].mean() * np.sqrt(2.0 / (31 * (hi - lo))) + plain[lo:hi].mean() * np.sqrt(2.0 / (31 * (hi - lo)))
        assert abs(got - s**2) < 5 * sd, (lo, hi, got, s**2)


def test_a_smaller_input_is_a_window_of_the_frame():
    """An input half as wide as the frame is a window at a whole-pixel offset drawn per sample:
    in each sample's frame the noisy columns (3 DN; a column mean off by more than 1 DN, 4.5 sd
    of the quiet columns' 0.22) all lie left of the tap's edge in the window, most columns
    there are noisy (74 % expected), and the edge moves from sample to sample."""
    from base_camera import base_fixed
    import torch

    from rawaug import RawNoiseAugment

    prof = BASE.with_effect("ColTap", taps((3.0, 0.0), (128,)))
    aug = RawNoiseAugment(prof, model="G+R", ratio=1.0, fixed=base_fixed(prof, K), generator=torch.Generator().manual_seed(4),
                          rank_seeding=False)
    with torch.no_grad():
        f = aug(torch.zeros(16, 4, H, W // 2, dtype=torch.float64)).numpy() * prof.span_dn
    ends = []
    for frame in f:
        m = np.empty(W)  # sensor-column means of the window's 128 sensor columns
        m[0::2], m[1::2] = frame[[0, 3]].mean(axis=(0, 1)), frame[[1, 2]].mean(axis=(0, 1))
        noisy = np.abs(m - np.median(m[-16:])) > 1.0
        end = int(np.flatnonzero(noisy).max()) + 1 if noisy.any() else 0
        assert end <= 128
        if end >= 16:
            assert noisy[:end].mean() > 0.55, noisy[:end].mean()
        ends.append(end)
    assert len(set(ends)) > 4, ends


def test_estimate_finds_the_taps_and_none_without():
    """Ten sessions with an edge at sensor column 128, 1.2 DN left and none right: the edge
    within 2 columns and each tap's std within 0.2 DN; twenty sessions without taps, ten with
    1.2 DN of column noise in every column: no edge (chance 1e-3 per stack of a cut, then
    two taps that must differ by 5 sd)."""
    base = [stack({}, s, sensor=1) for s in range(100, 104)]
    for session in range(10):
        est = column_tap.estimate(stack({"ColTap": taps()}, 10 + session), base, K, kind="bias")
        assert len(est["col_edges"]) == 1 and abs(est["col_edges"][0] - 128) <= 2, est["col_edges"]
        left, right = est["sigma_dn"][0]
        assert abs(left - 1.2) < 0.2 and right < 0.2, est["sigma_dn"]
    for session in range(20):
        est = column_tap.estimate(stack({}, 40 + session), base, K, kind="bias")
        assert column_tap.empty(est), est["col_edges"]
    col = {"Col": {"seed": 3, "k": [K], "sigma_dn": [1.2], "fixed_dn": [0.0]}}
    for session in range(10):
        assert column_tap.empty(column_tap.estimate(stack(col, 70 + session), base, K, kind="bias")), session


def test_the_statistic_sees_the_taps():
    """col_noise_spread: under 2 without taps (5 of 5: the medians of 8 blocks of 32 columns, 7
    degrees each), over 20 with 1.2 DN in one half (5 of 5)."""
    for seed in range(5):
        assert col_noise_spread(stack({}, 200 + seed)) < 2.0
        assert col_noise_spread(stack({"ColTap": taps()}, 300 + seed)) > 20.0


def test_bad_entries_are_refused():
    with pytest.raises(ValueError, match="strictly increasing"):
        BASE.with_effect("ColTap", taps((1.0, 1.0, 1.0), (120, 100)))
    with pytest.raises(ValueError, match="whole sensor columns"):
        BASE.with_effect("ColTap", taps((1.0, 1.0), (300,)))
    with pytest.raises(ValueError, match="frame_h and frame_w"):
        BASE.with_effect("ColTap", {"col_edges": [10], "k": [K], "sigma_dn": [[1.0, 1.0]]})
    with pytest.raises(ValueError, match="one per tap"):
        BASE.with_effect("ColTap", taps((1.0,), (100,)))
    with pytest.raises(ValueError, match="one per tap"):
        BASE.with_effect("ColTap", taps((1.0, -0.5), (100,)))
