"""DarkDrift: the dark signal of each frame scaled by a factor of its own (a sensor whose
temperature changes over a series), through the real stage and its estimator."""
import functools

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import dark_drift

SHAPE = (16, 16)  # packed pixels per channel: the factor is per frame
RATE = 200.0  # e-/s: 200 e- in 1 s, its shot noise 14 e- per pixel, 0.45 e- in a frame mean of 1024 pixels
DARK = {"seed": 19, "k": [1.0], "rate_e_per_s": [RATE], "dsnu": [0.1]}


@functools.lru_cache(maxsize=None)
def drift_profile(sigma, rho):
    profile = NoiseProfile.load("SonyA7S2").with_effect("Dark", DARK)
    return profile.with_effect("DarkDrift", {"sigma": sigma, "rho": rho}) if sigma else profile


def stack(n, sigma=0.3, rho=0.8, seed=0, sequence=1, exposure_s=1.0):
    """(n, 4, h, w) dark frames in DN (K 1): read noise 1 DN, the dark signal with its shot noise."""
    profile = drift_profile(sigma, rho)
    aug = RawNoiseAugment(profile, model="G+P", ratio=1.0,
                          fixed={"k": 1.0, "sigma_g": 1.0, "sequence": sequence, "exposure_s": exposure_s, "sensor": 0},
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.zeros(n, 4, *SHAPE)).numpy().astype(np.float64) * profile.span_dn


def log_factors(frames, exposure_s=1.0):
    return np.log(frames.mean(axis=(1, 2, 3)) / (RATE * exposure_s))


def test_independent_shots_have_a_log_normal_factor_of_mean_one():
    # 4000 shots, sigma 0.3: sd of the log factor within 4 x 0.3 / sqrt(2 x 4000) (plus the frame
    # mean's shot noise, 0.002 in log), the factor's mean within 4 x 0.31 / sqrt(4000)
    x = log_factors(stack(4000, sigma=0.3, rho=0.0, seed=1, sequence=0))
    assert abs(x.std(ddof=1) - 0.3) < 4 * 0.3 / np.sqrt(2 * 4000) + 0.002
    assert abs(np.exp(x).mean() - 1.0) < 4 * 0.31 / np.sqrt(4000)
    assert abs(np.corrcoef(x[:-1], x[1:])[0, 1]) < 4 / np.sqrt(4000)


def test_a_sequence_walks_with_its_lag1_correlation():
    # AR(1) with rho 0.9 over 4000 frames: lag-1 correlation within 5 x sqrt((1 - rho^2) / n) = 0.035
    x = log_factors(stack(4000, sigma=0.3, rho=0.9, seed=2))
    assert abs(np.corrcoef(x[:-1], x[1:])[0, 1] - 0.9) < 5 * np.sqrt((1 - 0.81) / 4000)


def test_it_scales_the_dark_signal_only():
    # bias frames (no exposure: no dark signal) are the same with and without the drift, bit for bit;
    # darks are not
    assert np.array_equal(stack(6, seed=3, exposure_s=0.0), stack(6, sigma=0.0, seed=3, exposure_s=0.0))
    assert not np.allclose(stack(6, seed=3), stack(6, sigma=0.0, seed=3))


def records(sigma, rho, seed, n_stacks=4, n=8):
    base = [stack(n, sigma=0.0, seed=90_000 + i) for i in range(4)]
    return [dark_drift.estimate(stack(n, sigma=sigma, rho=rho, seed=1000 * seed + j), base, 1.0, kind="dark",
                                black_dn=[0.0] * 4) for j in range(n_stacks)]


@pytest.mark.parametrize("rho, n", [(0.0, 8), (0.7, 8), (0.8, 16)])
def test_estimate_measures_a_planted_drift_back_over_seeds(rho, n):
    # 20 cameras, each 4 dark stacks of n frames, sigma 0.2: the medians of sigma and rho.
    # Measured: sigma 0.20 / 0.19 / 0.18, rho 0.02 / 0.65 / 0.75 (rho 0 is biased up: it is
    # kept >= 0; a short walk's down)
    got = [dark_drift.combine(records(0.2, rho, s, n=n)) for s in range(20)]
    assert abs(np.median([g["sigma"] for g in got]) / 0.2 - 1.0) < 0.25
    assert abs(np.median([g["rho"] for g in got]) - rho) < 0.15


def test_without_a_drift_the_estimate_is_near_nothing():
    # 20 cameras without it: the excess spread is the frame means' noise, 0.45 e- in 200 (0.002)
    got = [dark_drift.combine(records(0.0, 0.0, 100 + s)) for s in range(20)]
    assert np.median([g["sigma"] for g in got]) < 0.01


def test_bias_flats_one_frame_and_no_black_cannot_show_it():
    frames = stack(4)
    for kind, f, black in (("bias", frames, [0.0] * 4), ("flat", frames, [0.0] * 4), ("dark", frames[:1], [0.0] * 4),
                           ("dark", frames, None)):
        with pytest.raises(ValueError, match="dark stacks"):
            dark_drift.estimate(f, [f], 1.0, kind=kind, black_dn=black)
    with pytest.raises(ValueError, match="dark signal above"):
        dark_drift.estimate(frames, [frames], 1.0, kind="dark", black_dn=[1e6] * 4)


@pytest.mark.parametrize("params, match", [
    ({"sigma": 0.1, "rho": 1.0}, r"rho \(correlation of consecutive frames\) must be in \[0, 1\)"),
    ({"sigma": -0.1, "rho": 0.5}, r"sigma \(std of the log dark factor per frame\)"),
    ({"sigma": 0.1}, "rho"),
    ("0.1", "must be a mapping"),
])
def test_bad_entries_are_refused(params, match):
    with pytest.raises(ValueError, match=match):
        NoiseProfile.load("SonyA7S2").with_effect("DarkDrift", params)
