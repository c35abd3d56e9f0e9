"""Trap: charge trapping (a toe at low light), through the real stage, its estimator and the
flat series the loop synthesizes flats from."""
import functools
import math

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import charge_trap
from rawaug.loop.diagnose import FlatSeries

SHAPE = (64, 64)  # packed pixels per channel
DOSES = np.array([0.02, 0.05, 0.1, 0.2, 0.4])  # a flat series: exposure times, s
RATE = 4000.0  # DN per second of every channel at K 1: 80 to 1600 DN


@functools.lru_cache(maxsize=None)
def trap_profile(trap_e, k):
    profile = NoiseProfile.load("SonyA7S2")
    return profile.with_effect("Trap", {"k": [k], "trap_e": [trap_e]}) if trap_e else profile


def flats(level_dn, trap_e, k, seed=0, n=2, model="G+P"):
    """(n, 4, h, w) flats in DN at gain ``k``: Poisson shot noise, Gaussian read noise of 1 DN, traps."""
    profile = trap_profile(trap_e, k)
    aug = RawNoiseAugment(profile, model=model + ("+Trap" if trap_e else ""), ratio=1.0,
                          fixed={"k": k, "sigma_g": 1.0, "sensor": 0}, generator=torch.Generator().manual_seed(seed),
                          rank_seeding=False)
    with torch.no_grad():
        return aug(torch.full((n, 4, *SHAPE), level_dn / profile.span_dn)).numpy().astype(np.float64) * profile.span_dn


@pytest.mark.parametrize("k", [0.75, 3.0])
@pytest.mark.parametrize("level_dn", [30.0, 100.0, 1000.0])
def test_the_stage_mean_is_the_poisson_expectation(level_dn, k):
    got = flats(level_dn, 15.0, k, seed=1, n=4)
    # the mean of 65536 values, each of variance <= k level + 1: 5 standard errors
    tol = 5.0 * math.sqrt((k * level_dn + 1.0) / got.size)
    assert abs(got.mean() - charge_trap.mean_response(level_dn, 15.0, k)) < tol
    assert charge_trap.mean_response(level_dn, 15.0, k) < level_dn - 0.5 * k  # the traps took a share


def test_bias_frames_are_unchanged_bit_for_bit():
    assert np.array_equal(flats(0.0, 15.0, 1.0, seed=2), flats(0.0, 0.0, 1.0, seed=2, model="G+P"))


@pytest.mark.parametrize("k", [0.75, 3.0])
def test_estimate_round_trip_and_none_on_a_linear_camera(k):
    # channel means of 2 x 4096 pixels: a standard error of sqrt(k x) / 90 DN, <= 0.3 e- at every
    # level here; q from 20 means (5 levels x 4 channels) is held to 1.5 e- (about 5 of its errors)
    for seed in range(5):
        for trap_e in (15.0, 0.0):
            signal = np.stack([flats(RATE * d, trap_e, k, seed=10 * seed + i).mean(axis=(0, 2, 3)) for i, d in enumerate(DOSES)])
            series = FlatSeries(DOSES, signal, np.zeros(4))
            got = charge_trap.estimate(None, [], k, series=series)["trap_e"][0]
            assert abs(got - trap_e) < 1.5, (seed, trap_e, got)


def test_the_series_synthesizes_flats_at_the_rate_the_toe_implies():
    k, trap_e = 3.0, 15.0
    truth = np.array([RATE, 1.02 * RATE, 0.97 * RATE, RATE])
    signal = np.stack([charge_trap.mean_response(truth * d, trap_e, k) for d in DOSES])
    series = FlatSeries(DOSES, signal, np.zeros(4))
    assert np.allclose(series.clean_level(trap_profile(trap_e, k), k, 0.1), truth * 0.1, rtol=1e-6)
    assert not np.allclose(series.clean_level(trap_profile(0.0, k), k, 0.1), truth * 0.1, rtol=1e-2)  # a line through zero misses


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="trap_e"):
        NoiseProfile.load("SonyA7S2").with_effect("Trap", {"k": [1.0], "trap_e": [-1.0]})
    with pytest.raises(ValueError, match="flat series"):
        charge_trap.estimate(None, [], 1.0, series=None)
