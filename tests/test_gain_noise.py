"""GainNoise: temporal gain noise of each pixel (a photon transfer curve that bends upward),
through the real stage, its estimator and its profile entry."""
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import gain_noise

from base_camera import base_fixed

BASE = NoiseProfile.load("SonyA7S2")


def flats(level_dn, sigma_rel, k, seed, n=2, size=96):
    """(n, 4, size, size) flats in DN at gain ``k``: Poisson shot noise, the base camera's read and
    row noise, pixel gain noise of ``sigma_rel``."""
    profile = BASE.with_effect("GainNoise", {"k": [k], "sigma_rel": [sigma_rel]}) if sigma_rel else BASE
    fixed = base_fixed(BASE, k)
    aug = RawNoiseAugment(profile, model="G+P+R" + ("+GainNoise" if sigma_rel else ""), ratio=1.0, fixed=fixed,
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.full((n, 4, size, size), level_dn / BASE.span_dn)).numpy().astype(np.float64) * BASE.span_dn


@pytest.mark.parametrize("k", [0.375, 3.0])
@pytest.mark.parametrize("level_dn", [500.0, 5000.0])
def test_the_stage_adds_the_square_of_its_level_to_the_temporal_variance_and_keeps_the_mean(level_dn, k):
    g, n = 0.01, 8
    with_noise, without = flats(level_dn, g, k, seed=1, n=n), flats(level_dn, 0.0, k, seed=1, n=n)
    # the same shot and read draws: the difference is the stage's alone, s g z
    diff = with_noise - without
    m = diff.size
    assert abs(diff.mean()) < 5 * g * level_dn / np.sqrt(m)
    rel = diff.var() / (g * level_dn) ** 2  # shot noise moves s by sqrt(K s), well under s: ~1
    assert abs(rel - 1.0) < 5 * np.sqrt(2.0 / m) + k / level_dn


def test_bias_frames_are_unchanged_bit_for_bit():
    assert np.array_equal(flats(0.0, 0.02, 1.0, seed=3, n=3), flats(0.0, 0.0, 1.0, seed=3, n=3))


MEDIAN_REL_SD = 2.33  # sd of a chi-square(1) sample median over that median, times sqrt(pixels)


@pytest.mark.parametrize("k", [0.375, 3.0])
def test_the_estimate_finds_the_planted_noise_and_none_where_there_is_none(k):
    """Over 5 sessions at each gain (flat pairs at five levels, pooled by ``combine``), the
    estimated g^2 lies within 5 standard errors of the planted (0.5 %, and none). A stack's
    standard error: its white variance's (a median of chi-square(1) pixel variances, the
    measured stack's and the mean of two syntheses') over its level squared."""
    levels = (300.0, 800.0, 1600.0, 3200.0, 6300.0)
    for truth in (0.005, 0.0):
        for session in range(5):
            records, precision = [], 0.0
            for i, level in enumerate(levels):
                measured = flats(level, truth, k, seed=1000 * session + i)
                synth = [flats(level, 0.0, k, seed=1000 * session + 100 + 10 * i + j) for j in range(4)]
                records.append(gain_noise.estimate(measured, synth, k, kind="flat", seed=session))
                rel_sd = MEDIAN_REL_SD / np.sqrt(measured[0].size) * np.sqrt(1.0 + 1.0 / gain_noise.SOLVE_STACKS)
                precision += (level**2 / (rel_sd * measured.var(axis=0, ddof=1).mean())) ** 2
            got = gain_noise.combine(records)["sigma_rel"][0]
            assert abs(got**2 - truth**2) < 5.0 / np.sqrt(precision), (k, truth, session, got)


def test_combine_weighs_each_stack_by_its_precision():
    records = [{"k": [1.0], "sigma_rel": [0.01], "weight": [1.0]}, {"k": [1.0], "sigma_rel": [0.03], "weight": [0.0]},
               {"k": [2.0], "sigma_rel": [0.02], "weight": [3.0]}, {"k": [2.0], "sigma_rel": [0.0], "weight": [1.0]}]
    out = gain_noise.combine(records)
    assert out["k"] == [1.0, 2.0]
    assert out["sigma_rel"] == pytest.approx([0.01, np.sqrt(0.75 * 0.02**2)])


def test_the_estimator_takes_flats_only():
    with pytest.raises(ValueError, match="flat stacks"):
        gain_noise.estimate(np.zeros((4, 4, 8, 8)), [np.zeros((4, 4, 8, 8))], 1.0, kind="dark")


@pytest.mark.parametrize("params, match", [
    ({"k": [1.0], "sigma_rel": [-0.01]}, "sigma_rel must be >= 0"),
    ({"k": [1.0], "sigma_rel": [0.5]}, "sigma_rel must be <= 0.2"),
    ({"k": [1.0, 2.0], "sigma_rel": [0.01]}, "one value per k"),
])
def test_bad_parameters_name_the_value(params, match):
    with pytest.raises(ValueError, match=match):
        BASE.with_effect("GainNoise", params)
