"""DarkNoise: white temporal noise whose variance grows with the exposure time, through the
real stage and its estimator."""
import functools

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import dark_noise

SHAPE = (32, 32)  # packed pixels per channel
RATE = 0.5  # DN^2 per second at K 1


@functools.lru_cache(maxsize=None)
def noise_profile(rate):
    profile = NoiseProfile.load("SonyA7S2")
    return profile.with_effect("DarkNoise", {"k": [1.0], "rate_dn2_per_s": [rate]}) if rate else profile


def stack(n, rate=RATE, seed=0, exposure_s=4.0, model="G*"):
    """(n, 4, h, w) frames in DN at K 1: the read noise (Tukey lambda 0.05 of scale 1.5 DN, or
    Gaussian of 1 DN) plus DarkNoise."""
    profile = noise_profile(rate)
    aug = RawNoiseAugment(profile, model=model + ("+DarkNoise" if rate else ""), ratio=1.0,
                          fixed={"k": 1.0, "sigma_tl": 1.5, "lambda": 0.05, "sigma_g": 1.0,
                                 "exposure_s": exposure_s, "sensor": 0},
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.zeros(n, 4, *SHAPE)).numpy().astype(np.float64) * profile.span_dn


@pytest.mark.parametrize("exposure_s", [1.0, 4.0, 16.0])
def test_its_variance_grows_linearly_with_the_exposure(exposure_s):
    # Gaussian read noise of 1 DN plus the stage: 64 frames x 4096 pixels; the variance of a
    # variance estimate of 262144 Gaussian values is 2 v^2 / n: 5 standard errors
    got = stack(64, seed=1, exposure_s=exposure_s, model="G").var()
    base = stack(64, rate=0.0, seed=1, exposure_s=exposure_s, model="G").var()
    total = base + RATE * exposure_s  # the same read noise draws: only the stage's own noise differs
    assert abs(got - total) < 5 * RATE * exposure_s * np.sqrt(2 / (64 * 4 * 32 * 32)) + 5 * np.sqrt(4 * base * RATE * exposure_s / (64 * 4 * 32 * 32))


def test_without_an_exposure_it_adds_nothing():
    # a bias frame (exposure 0) is the same with and without it, bit for bit; a dark is not
    assert np.array_equal(stack(4, seed=2, exposure_s=0.0), stack(4, rate=0.0, seed=2, exposure_s=0.0))
    assert not np.allclose(stack(4, seed=2), stack(4, rate=0.0, seed=2))


def estimates(rate, seeds, n=6, offsets=0.0):
    base = [stack(n, rate=0.0, seed=90_000 + i) for i in range(4)]
    out = []
    for s in seeds:
        frames = stack(n, rate=rate, seed=1000 + s)
        frames = frames + offsets * np.random.default_rng(s).standard_normal((n, 1, 1, 1))  # a black level per frame
        out.append(dark_noise.estimate(frames, base, 1.0, kind="dark", exposure_s=4.0)["rate_dn2_per_s"][0])
    return np.array(out)


def test_estimate_measures_a_planted_rate_back_over_seeds():
    # 20 dark stacks of 6 frames of 4 x 32 x 32 under the Tukey-lambda read noise (2 DN^2 of
    # variance at 4 s over the base 2.3 DN^2): the medians of the per-pixel variances are ~1 %
    # apart from stack to stack, 0.01 DN^2/s. Measured: median 0.50, spread 0.025 DN^2/s (0.53
    # when the median of variances was taken for a Gaussian's, before the noise was solved for).
    got = estimates(RATE, range(20))
    assert abs(np.median(got) / RATE - 1.0) < 0.1
    assert got.std() < 0.1 * RATE


def test_a_black_level_that_moves_from_frame_to_frame_is_not_it():
    # offsets of 2 DN rms per frame, 4 times the planted noise: the estimate does not move
    # (each frame's channel means are taken out)
    assert abs(np.median(estimates(RATE, range(10), offsets=2.0)) - np.median(estimates(RATE, range(10)))) < 0.02


def test_without_it_the_estimate_is_near_nothing():
    # 20 stacks without it: excess variances of a few 0.01 DN^2, over 4 s
    assert np.median(estimates(0.0, range(20))) < 0.02


def test_bias_flats_one_frame_and_no_exposure_cannot_show_it():
    frames = stack(4)
    for kind, f, t in (("bias", frames, 4.0), ("flat", frames, 4.0), ("dark", frames[:1], 4.0), ("dark", frames, None)):
        with pytest.raises(ValueError, match="dark stacks"):
            dark_noise.estimate(f, [f], 1.0, kind=kind, exposure_s=t)


@pytest.mark.parametrize("params, match", [
    ({"k": [1.0], "rate_dn2_per_s": [-0.1]}, "rate_dn2_per_s"),
    ({"k": [1.0]}, "rate_dn2_per_s"),
    ({"k": [1.0, 2.0], "rate_dn2_per_s": [0.1]}, "rate_dn2_per_s"),
])
def test_bad_entries_are_refused(params, match):
    with pytest.raises(ValueError, match=match):
        NoiseProfile.load("SonyA7S2").with_effect("DarkNoise", params)
