"""GainGrid: a measured periodic grid of pixel gains (phase-detection pixels), through the real stage."""
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import gain_grid
from rawaug.engine import layout as L
from rawaug.statistics import grid_excess

SHAPE = (96, 128)  # packed pixels per channel
PERIOD = (6, 4)  # every 12th sensor row, every 8th sensor column
LEVEL = 0.2  # of white: ~3000 DN, ~3000 e- at K 1


def planted(masked=0.5):
    """(4, 6, 4) gains of mean 1: one G1 cell of the period at ``masked`` of the others."""
    g = np.ones((4, *PERIOD))
    g[1, 3, 1] = masked
    return g / g.mean(axis=(1, 2), keepdims=True)


def flats(gain=None, n=4, seed=0, conversion=0.0):
    """A flat stack (n, 4, h, w) in DN at K 1, shot noise only, through RawNoiseAugment."""
    profile = NoiseProfile.load("SonyA7S2")
    if gain is not None:
        profile = profile.with_effect("GainGrid", {"period": list(gain.shape[1:]), "gain": gain.tolist(),
                                                   "frame_h": SHAPE[0], "frame_w": SHAPE[1], "conversion": conversion})
    aug = RawNoiseAugment(profile, model="P", ratio=1.0, fixed={"k": 1.0}, generator=torch.Generator().manual_seed(seed))
    with torch.no_grad():
        return aug(torch.full((n, 4, *SHAPE), LEVEL)).numpy().astype(np.float64) * profile.span_dn


def test_a_planted_grid_is_measured_back():
    truth = planted()
    measured = flats(truth, seed=1)
    est = gain_grid.estimate(measured, [flats(seed=10 + i) for i in range(4)], 1.0, kind="flat")
    assert est["period"] == list(PERIOD)
    # each cell is the mean of n * (h / 6) * (w / 4) pixels of relative shot noise 1 / sqrt(electrons)
    level_e = LEVEL * NoiseProfile.load("SonyA7S2").span_dn
    se = 1.0 / np.sqrt(level_e * measured.shape[0] * (SHAPE[0] // PERIOD[0]) * (SHAPE[1] // PERIOD[1]))
    assert np.abs(np.asarray(est["gain"]) - truth).max() < 6 * se + 1e-5


def test_grid_excess_tells_a_grid_from_none_over_seeds():
    # 20 stacks each: without a grid, and with one G1 cell in 24 at 90 % (a weak phase-detection pixel).
    # Measured: without, 0.0010-0.0031 (the largest of 255 folds' chance excess); with, 0.38-0.40.
    none = [grid_excess(flats(seed=100 + s, n=2)) for s in range(20)]
    weak = [grid_excess(flats(planted(0.9), seed=200 + s, n=2)) for s in range(20)]
    assert max(none) < 0.01 < min(weak)


def test_the_phase_is_the_measured_one_on_its_frame_and_drawn_on_crops():
    profile = NoiseProfile.load("SonyA7S2").with_effect(
        "GainGrid", {"period": list(PERIOD), "gain": planted().tolist(), "frame_h": SHAPE[0], "frame_w": SHAPE[1]})
    aug = RawNoiseAugment(profile, model="P", ratio=1.0, fixed={"k": 1.0})
    oy, ox = L.COLUMN["ggrid_oy"], L.COLUMN["ggrid_ox"]
    whole = aug.draw_parameters(64, "cpu", shape=SHAPE)["values"]
    assert torch.all(whole[:, oy] == 0) and torch.all(whole[:, ox] == 0)
    crop = aug.draw_parameters(64, "cpu", shape=(40, 40))["values"]
    # every phase among 64 uniform draws: a phase is missed with probability <= 6 (5/6)^64 < 1e-4
    assert sorted(set(crop[:, oy].tolist())) == list(map(float, range(PERIOD[0])))
    assert sorted(set(crop[:, ox].tolist())) == list(map(float, range(PERIOD[1])))


def test_the_stage_multiplies_the_photo_signal_at_its_cells():
    # shot noise after the gain: the masked cell's mean is half the others', at its place
    out = flats(planted(), n=8, seed=3)
    cells = out.mean(axis=0)[1].reshape(SHAPE[0] // 6, 6, SHAPE[1] // 4, 4).mean(axis=(0, 2))
    others = np.delete(cells.ravel(), 3 * 4 + 1)
    assert abs(cells[3, 1] / others.mean() - 0.5) < 0.005  # the cell's relative noise: ~1e-3
    assert np.ptp(others) / others.mean() < 0.005


ROW_PAIRS = np.array([[[0.8], [1.2]]] * 4)  # every other packed row (Bayer row pair) at 1.5 x the gain: (4, 2, 1)


def _phase_moments(out):
    """(2,) mean and (2,) temporal variance of the even and the odd packed rows, all channels."""
    mean, var = out.mean(axis=0), out.var(axis=0, ddof=1)
    return np.array([mean[:, 0::2].mean(), mean[:, 1::2].mean()]), np.array([var[:, 0::2].mean(), var[:, 1::2].mean()])


@pytest.mark.parametrize("conversion", [0.0, 1.0])
def test_a_conversion_gain_scales_the_shot_noise_with_the_square_of_the_gain(conversion):
    # shot noise only: before the Poisson draw a gain g scales the variance by g, after it by g^2
    n = 8
    mean, var = _phase_moments(flats(ROW_PAIRS, n=n, seed=4, conversion=conversion))
    assert abs(mean[1] / mean[0] - 1.5) < 0.005  # each mean over 8 x 4 x 48 x 128 pixels: ~1e-3 relative
    # each variance is the mean of 4 x 48 x 128 pixels' variances of 7 degrees of freedom
    se = np.sqrt(2.0 / ((n - 1) * 4 * 48 * 128)) * np.sqrt(2.0)
    assert abs(var[1] / var[0] / 1.5 ** (1 + conversion) - 1.0) < 5 * se, var[1] / var[0]


@pytest.mark.parametrize("truth", [0.0, 0.5, 1.0])
def test_the_conversion_share_is_measured_back(truth):
    # the slope of the cells' log shot variance on their log mean, less 1, within 5 of its
    # standard errors (clipped to [0, 1] at the ends)
    est = gain_grid.estimate(flats(ROW_PAIRS, n=4, seed=20, conversion=truth), [flats(n=4, seed=30 + i) for i in range(4)],
                             1.0, kind="flat")
    assert est["period"] == [2, 1]
    assert abs(est["conversion"] - truth) < 5 / np.sqrt(est["conversion_weight"]) + 1e-3, est
    assert 5 / np.sqrt(est["conversion_weight"]) < 0.1  # the test can tell 0 from 1
    combined = gain_grid.combine([est, {**est, "conversion": 1.0 - est["conversion"], "conversion_weight": est["conversion_weight"]}])
    assert abs(combined["conversion"] - 0.5) < 1e-3  # two stacks of one precision: their mean


@pytest.mark.parametrize("params, words", [
    ({"period": [2, 1], "gain": [[[1.0], [1.0]]] * 4, "conversion": 1.5}, "conversion (the share of the log gain applied after shot noise) must be a number in [0, 1], got 1.5"),
    ({"period": [0, 4], "gain": []}, "period must be [py, px]"),
    ({"period": [6, 4], "gain": [[[1.0] * 4] * 6] * 3}, "gain must be 4 channels x 6 x 4"),
    ({"period": [2, 2], "gain": [[[1.0, -0.5], [1.0, 1.0]]] * 4}, "gains >= 0"),
    ({"period": [2, 2], "gain": [[[1.0] * 2] * 2] * 4, "phase": 1}, "unknown keys ['phase']"),
])
def test_bad_entries_are_named(params, words):
    with pytest.raises(ValueError) as err:
        NoiseProfile.load("SonyA7S2").with_effect("GainGrid", params)
    assert words in str(err.value)


def test_it_is_measured_on_flats_only():
    with pytest.raises(ValueError, match="flat stacks"):
        gain_grid.estimate(flats(n=2), [flats(n=2, seed=5)], 1.0, kind="bias")
