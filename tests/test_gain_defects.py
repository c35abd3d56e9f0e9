"""PixelGain: gain defect pixels (dim and bright outliers of a flat), through the real stage,
its estimator and its profile entry."""
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import gain_defects

from base_camera import base_fixed

BASE = NoiseProfile.load("SonyA7S2")
DIM = {"seed": 5, "density": 0.003, "median": 0.5, "log_std": 0.0, "negative": 1.0}
MIXED = {"seed": 7, "density": 0.01, "median": 0.2, "log_std": 0.3, "negative": 0.7}


def flats(level_dn, params, k, seed, n=2, size=96):
    """(n, 4, size, size) flats in DN at gain ``k``: Poisson shot noise, the base camera's read and
    row noise, gain defect pixels ``params`` (None: none)."""
    profile = BASE.with_effect("PixelGain", params) if params else BASE
    fixed = base_fixed(BASE, k)
    aug = RawNoiseAugment(profile, model="G+P+R" + ("+PixelGain" if params else ""), ratio=1.0, fixed=fixed,
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.full((n, 4, size, size), level_dn / BASE.span_dn)).numpy().astype(np.float64) * BASE.span_dn


def test_the_stage_draws_the_defects_at_their_density_sizes_and_signs():
    level, n = 4000.0, 2
    with_defects, without = flats(level, MIXED, 1.0, seed=1, n=n, size=160), flats(level, None, 1.0, seed=1, n=n, size=160)
    changed = (with_defects != without).all(axis=0)  # a defect changes its pixel in every frame; the others are untouched
    assert np.array_equal((with_defects != without).any(axis=0), changed)
    m = changed.size
    frac = changed.mean()
    assert abs(frac - MIXED["density"]) < 5 * np.sqrt(MIXED["density"] * (1 - MIXED["density"]) / m)
    # the same shot and read draws: (with - without) / signal is d, the signal's shot noise aside
    d = ((with_defects - without)[:, changed] / level).mean(axis=0)
    count = d.size
    assert abs((d < 0).mean() - MIXED["negative"]) < 5 * np.sqrt(MIXED["negative"] * (1 - MIXED["negative"]) / count)
    logs = np.log(np.abs(d))
    assert abs(logs.mean() - np.log(MIXED["median"])) < 5 * MIXED["log_std"] / np.sqrt(count) + 0.01
    assert abs(logs.std() - MIXED["log_std"]) < 5 * MIXED["log_std"] / np.sqrt(2 * count) + 0.01


def test_bias_frames_are_unchanged_bit_for_bit():
    assert np.array_equal(flats(0.0, MIXED, 1.0, seed=3, n=3), flats(0.0, None, 1.0, seed=3, n=3))


@pytest.mark.parametrize("k", [0.375, 3.0])
def test_the_estimate_finds_the_planted_defects_and_none_where_there_are_none(k):
    """Over 5 sessions (sensors) at each gain, from a flat pair at 3000 DN: the density of 50 %
    dim pixels within 5 binomial standard errors, their median within 2 %, all dim; none
    planted gives none."""
    m = 4 * 96 * 96
    for session in range(5):
        synth = [flats(3000.0, None, k, seed=100 * session + 10 + j) for j in range(4)]
        got = gain_defects.estimate(flats(3000.0, {**DIM, "seed": session}, k, seed=100 * session), synth, k, kind="flat")
        assert abs(got["density"] - DIM["density"]) < 5 * np.sqrt(DIM["density"] / m), (k, session, got)
        assert got["median"] == pytest.approx(DIM["median"], abs=0.02) and got["negative"] == 1.0, (k, session, got)
        none = gain_defects.estimate(flats(3000.0, None, k, seed=100 * session + 1), synth, k, kind="flat")
        assert none["density"] == 0.0 and gain_defects.empty(none), (k, session, none)


def test_combine_keeps_the_stack_that_resolved_the_most():
    records = [{**DIM, "density": 0.001}, {**DIM, "density": 0.0029}, {**DIM, "density": 0.0}]
    assert gain_defects.combine(records)["density"] == 0.0029


def test_the_estimator_takes_flats_only():
    with pytest.raises(ValueError, match="flat stacks"):
        gain_defects.estimate(np.ones((2, 4, 16, 16)), [], 1.0, kind="bias")


@pytest.mark.parametrize("change, match", [
    ({"density": 0.2}, "density"),
    ({"median": 1.5}, "median"),
    ({"log_std": -0.1}, "log_std"),
    ({"negative": 2.0}, "negative"),
])
def test_bad_parameters_name_the_value(change, match):
    with pytest.raises(ValueError, match=match):
        BASE.with_effect("PixelGain", {**DIM, **change})
