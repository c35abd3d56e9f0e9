"""RowTail: heavy-tailed row noise, through the real stage, ``row_tail_mass``, its estimator and
its profile entry."""
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import row_tail
from scipy import stats

from rawaug.statistics import ROW_TAIL_Z, row_tail_mass, temporal_row_means

BASE = NoiseProfile.load("SonyA7S2")


def bias(h, k, seed, n=8, sigma_r=1.0, size=(96, 128)):
    """(n, 4, h, w) bias frames in DN at gain ``k``: the base camera's read noise, row noise of
    ``sigma_r`` DN with Tukey h ``h`` (0: Gaussian)."""
    profile = BASE.with_effect("RowTail", {"k": [k], "h": [h]}) if h else BASE
    fixed = {"k": k, "sigma_tl": BASE.tukey_scale.median(k), "lambda": 0.05, "sigma_g": BASE.gaussian_scale.median(k), "sigma_r": sigma_r, "sensor": 0}
    aug = RawNoiseAugment(profile, model="G+P+R" + ("+RowTail" if h else ""), ratio=1.0, fixed=fixed,
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.zeros((n, 4, *size))).numpy().astype(np.float64) * BASE.span_dn


def test_the_transform_has_the_kurtosis_it_is_solved_with():
    z = np.random.default_rng(0).standard_normal(1_000_000)
    for h in (0.02, 0.05, 0.1):
        x = z * np.exp(0.5 * h * z * z) * (1.0 - 2.0 * h) ** 0.75
        # the sample's excess kurtosis within 5 standard errors (its sd from the eighth moment)
        m4 = np.mean(x**4)
        se = np.sqrt((np.mean(x**8) - m4**2) / z.size)
        assert abs(m4 - 3.0 - row_tail.excess_kurtosis(h)) < 5 * se
        assert abs(x.var() - 1.0) < 5 * np.sqrt((m4 - 1.0) / z.size)  # sigma_r stays the rows' std


def test_the_stage_keeps_the_row_variance_and_gives_the_rows_their_kurtosis():
    h = 0.1
    heavy = np.concatenate([temporal_row_means(bias(h, 1.0, seed)) for seed in range(6)], axis=None)
    gauss = np.concatenate([temporal_row_means(bias(0.0, 1.0, seed)) for seed in range(6)], axis=None)
    n = heavy.size
    se = np.sqrt((np.mean(heavy**4) - heavy.var() ** 2) / n + (np.mean(gauss**4) - gauss.var() ** 2) / n)
    assert abs(heavy.var() - gauss.var()) < 5 * se  # sigma_r stays the rows' std
    kurt = np.mean(heavy**4) / heavy.var() ** 2
    assert kurt > 3.0 + 0.5 * row_tail.excess_kurtosis(h)  # heavy (the pixel noise's share dilutes it a little)


def test_bias_frames_without_row_noise_are_unchanged_bit_for_bit():
    profile = BASE.with_effect("RowTail", {"k": [1.0], "h": [0.1]})
    fixed = {"k": 1.0, "sigma_tl": 1.0, "lambda": 0.05, "sigma_g": 1.0, "sigma_r": 1.0, "sensor": 0}
    out = []
    for p, model in ((profile, "G+P+RowTail"), (BASE, "G+P")):  # no R: the transform has no row draw to act on
        aug = RawNoiseAugment(p, model=model, ratio=1.0, fixed=fixed, generator=torch.Generator().manual_seed(4), rank_seeding=False)
        with torch.no_grad():
            out.append(aug(torch.zeros((2, 4, 32, 32))).numpy())
    assert np.array_equal(*out)


def test_the_estimate_finds_the_planted_tail_and_none_where_rows_are_gaussian():
    """5 sessions at each of K 0.375 and 3 (8 bias frames of 384 sensor rows, against 3
    syntheses): the mean of the 10 estimates of h 0.1 within 5 standard errors (their own
    spread) of 0.1; Gaussian rows give a mean h within 5 standard errors of 0."""
    got = {0.1: [], 0.0: []}
    for k in (0.375, 3.0):
        for session in range(5):
            synth = [bias(0.0, k, 100 * session + 10 + j, size=(192, 128)) for j in range(3)]
            for truth, seed in ((0.1, 100 * session), (0.0, 100 * session + 1)):
                got[truth].append(row_tail.estimate(bias(truth, k, seed, size=(192, 128)), synth, k, kind="bias")["h"][0])
    for truth, values in got.items():
        values = np.asarray(values)
        assert abs(values.mean() - truth) <= 5 * values.std(ddof=1) / np.sqrt(values.size) + 1e-9, (truth, values)
    assert np.mean(got[0.1]) > 0.05


def test_row_tail_mass_counts_bursts_of_every_row_and_not_a_few_rows_of_their_own():
    """Gaussian rows (5 stacks of 8 frames, 192 sensor rows): the share beyond 4 robust sigmas
    within 5 binomial standard errors of the normal's 6.3e-5; h 0.1: above 1e-3; a Gaussian
    stack with 2 % of its rows switching 6 DN between frames (telegraph rows) within the same
    bound: those rows are left out."""
    p = 2 * stats.norm.sf(ROW_TAIL_Z)
    n = 8 * 192
    bound = 5 * np.sqrt(p * (1 - p) / (5 * n)) + 1.0 / (5 * n)
    gaussian = np.mean([row_tail_mass(bias(0.0, 1.0, seed)) for seed in range(5)])
    assert abs(gaussian - p) < bound, gaussian
    assert np.mean([row_tail_mass(bias(0.1, 1.0, seed)) for seed in range(5)]) > 1e-3
    rng = np.random.default_rng(3)
    telegraph = []
    for seed in range(5):
        f = bias(0.0, 1.0, seed)
        rows = rng.random(96) < 0.02
        f[:, :, rows] += np.where(rng.random((8, 1, int(rows.sum()), 1)) < 0.5, 6.0, 0.0)
        telegraph.append(row_tail_mass(f))
    assert abs(np.mean(telegraph) - p) < bound, telegraph


def test_the_estimator_takes_bias_and_dark_stacks_only():
    with pytest.raises(ValueError, match="bias or dark stacks"):
        row_tail.estimate(np.zeros((4, 4, 16, 16)), [], 1.0, kind="flat")


@pytest.mark.parametrize("params, match", [
    ({"k": [1.0], "h": [-0.1]}, "h must be >= 0"),
    ({"k": [1.0], "h": [0.3]}, "h must be <= 0.2"),
])
def test_bad_parameters_name_the_value(params, match):
    with pytest.raises(ValueError, match=match):
        BASE.with_effect("RowTail", params)
