"""Distributional tests of the noise components: bounds come from the sample size."""
import math

import numpy as np
import pytest
import torch
from scipy import stats

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.distributions import tukey_lambda_icdf, tukey_lambda_variance

SPAN = NoiseProfile.load("SonyA7S2").span_dn
pytestmark = pytest.mark.usefixtures("samplers")


def synth_dn(model, clean_dn, batch=16, size=64, seed=0, **fixed):
    """Noisy frames in DN at ratio 1 and fixed parameters, on a flat clean level."""
    aug = RawNoiseAugment("SonyA7S2", model=model, ratio=1.0, fixed=fixed, generator=torch.Generator().manual_seed(seed))
    x = torch.full((batch, 4, size, size), clean_dn / SPAN, dtype=torch.float64)
    return (aug(x) * SPAN).numpy()


@pytest.mark.parametrize("lam", [-0.3, -0.1, 0.0, 0.14, 0.5])
def test_tukey_lambda_icdf_matches_scipy_ks(lam):
    gen = torch.Generator().manual_seed(1)
    u = torch.rand(200_000, generator=gen)
    x = tukey_lambda_icdf(u, torch.tensor(lam)).numpy()
    assert np.isfinite(x).all()
    # KS p-value: a correct sampler fails this at rate 1e-3.
    assert stats.kstest(x, stats.tukeylambda(lam).cdf).pvalue > 1e-3


@pytest.mark.parametrize("lam", [-0.3, 0.0, 0.14])
def test_read_noise_module_matches_scipy_scaled(lam):
    sigma = 2.5
    noise = synth_dn("G*", 0.0, batch=8, size=96, sigma_tl=sigma, **{"lambda": lam}).ravel()
    assert stats.kstest(noise, stats.tukeylambda(lam, scale=sigma).cdf).pvalue > 1e-3


def test_tukey_lambda_icdf_finite_at_the_ends_and_continuous_at_zero():
    u = torch.tensor([0.0, 1e-30, 0.5, 1.0 - 2**-24, 1.0])
    for lam in (-1.0, -0.5, -1e-9, 0.0, 1e-9, 0.5, 1.0):
        q = tukey_lambda_icdf(u, torch.tensor(lam))
        assert torch.isfinite(q).all(), (lam, q)
    near = tukey_lambda_icdf(u, torch.tensor(1e-5))
    at = tukey_lambda_icdf(u, torch.tensor(0.0))
    assert torch.allclose(near, at, rtol=1e-3, atol=1e-4)


@pytest.mark.parametrize("lam", [-0.3, -0.1, 0.0, 0.14, 0.5])
def test_tukey_lambda_variance_matches_scipy(lam):
    assert math.isclose(tukey_lambda_variance(lam), stats.tukeylambda(lam).var(), rel_tol=1e-6)


def test_poisson_shot_noise_is_poisson_in_electrons():
    k, electrons = 0.8, 3.7
    out = synth_dn("P*", electrons * k, batch=4, size=128, k=k).ravel() / k
    counts = np.rint(out)
    assert np.abs(out - counts).max() < 1e-6  # whole electrons
    n = counts.size
    # mean and variance within 5 standard errors (Poisson: var = lambda, mu4 = lambda(1 + 3 lambda))
    assert abs(counts.mean() - electrons) < 5 * math.sqrt(electrons / n)
    se_var = math.sqrt((electrons * (1 + 3 * electrons) - electrons**2) / n)
    assert abs(counts.var(ddof=1) - electrons) < 5 * se_var
    # chi-square goodness of fit against scipy's pmf
    kmax = 12
    observed = np.array([(counts == i).sum() for i in range(kmax)] + [(counts >= kmax).sum()])
    pmf = stats.poisson(electrons).pmf(np.arange(kmax))
    expected = n * np.append(pmf, 1 - pmf.sum())
    assert stats.chisquare(observed, expected).pvalue > 1e-3


def test_gaussian_shot_noise_mean_and_variance():
    k, level = 1.5, 30.0
    out = synth_dn("P", level, batch=4, size=128, k=k).ravel()
    n = out.size
    var = k * level
    assert abs(out.mean() - level) < 5 * math.sqrt(var / n)
    assert abs(out.var(ddof=1) - var) < 5 * math.sqrt(2 * var**2 / n)


def per_image(stat, frames):
    values = np.array([stat(f) for f in frames])
    return values.mean(), values.std(ddof=1) / math.sqrt(len(values))


def test_full_model_pixel_and_row_mean_variance_match_analytic():
    k, level, sigma_tl, lam, sigma_r, q = 1.2, 20.0, 1.7, 0.05, 0.6, 1.0
    frames = synth_dn("G*+P*+R+U", level, batch=24, size=64, k=k, sigma_tl=sigma_tl, sigma_r=sigma_r, step_dn=q, **{"lambda": lam})
    read_var = sigma_tl**2 * tukey_lambda_variance(lam)
    pixel_var = k * level + read_var + sigma_r**2 + q**2 / 12
    mean, se = per_image(lambda f: f.var(), frames)
    assert abs(mean - pixel_var) < 4 * se, (mean, pixel_var, se)
    # sensor-row means: channels (0, 1) and (2, 3) share rows; 2W pixels per sensor row
    width = frames.shape[-1]
    row_var = sigma_r**2 + (k * level + read_var + q**2 / 12) / (2 * width)

    def row_mean_var(f):
        rows = np.concatenate([f[(0, 1), :, :].mean(axis=(0, 2)), f[(2, 3), :, :].mean(axis=(0, 2))])
        return rows.var()

    mean, se = per_image(row_mean_var, frames)
    assert abs(mean - row_var) < 4 * se, (mean, row_var, se)


def test_row_noise_is_shared_by_the_two_channels_of_a_sensor_row():
    frames = synth_dn("R", 0.0, batch=2, size=32, sigma_r=3.0)
    assert np.allclose(frames[:, 0], frames[:, 1]) and np.allclose(frames[:, 2], frames[:, 3])
    assert np.allclose(frames[:, 0], frames[:, 0, :, :1])  # constant along the row
    assert not np.allclose(frames[:, 0], frames[:, 2])  # the other sensor row differs


def test_quantization_noise_is_uniform_over_one_step():
    q = 2.0
    noise = synth_dn("U", 0.0, batch=2, size=128, step_dn=q).ravel()
    assert noise.min() >= -q / 2 and noise.max() <= q / 2
    assert stats.kstest(noise, stats.uniform(-q / 2, q).cdf).pvalue > 1e-3


def test_color_bias_adds_the_record_nearest_the_drawn_k():
    profile = NoiseProfile.load("SonyA7S2")
    k = profile.color_bias.k[4]  # records 4 and 5 are the two frames of one ISO step
    assert profile.color_bias.k[5] == k
    out = synth_dn("C", 0.0, batch=64, size=2, k=k).mean(axis=(2, 3))
    pair = np.array(profile.color_bias.values[4:6])
    distance = np.abs(out[:, None, :] - pair[None]).max(axis=2)
    assert (distance.min(axis=1) < 1e-4).all()  # every sample got one of the two records
    picked_first = (distance.argmin(axis=1) == 0).sum()
    assert 0 < picked_first < 64  # both frames are used (binomial(64, 1/2): P(fail) ~ 1e-19)


def test_colour_bias_is_added_on_request_not_by_default():
    # +C pays for a denoiser of one gain and costs over gains whose bias jumps (README)
    profile = NoiseProfile.load("SonyA7S2")
    assert profile.richest_model == "G*+P*+R+U"
    bias = [2.5, -2.0, 3.0, 2.0]  # each > 5 standard errors from 0: a model without C fails
    x = torch.full((8, 4, 64, 64), 20.0 / SPAN)  # 20 DN
    for model, expected in (("G*+P*+R+U+C", bias), (None, [0.0] * 4)):
        aug = RawNoiseAugment(profile, model=model, ratio=1.0, fixed={"k": 1.0, "color_bias_dn": bias},
                              generator=torch.Generator().manual_seed(5))
        noise = (aug(x) * SPAN).numpy() - 20.0
        means = noise.mean(axis=(0, 2, 3))
        se = noise.std(axis=(0, 2, 3)) / np.sqrt(noise[:, 0].size / 64)  # generous: rows and draws correlate
        assert (np.abs(means - expected) < 5 * se).all(), (model, means, se)


def test_parameter_sampling_follows_the_joint_model():
    profile = NoiseProfile.load("NikonD850")
    aug = RawNoiseAugment(profile, model="G*+P*+R", generator=torch.Generator().manual_seed(3))
    n = 4000
    params = aug.sample_parameters(aug.draw_parameters(n, "cpu", seed=11))
    log_k = params["k"].log().numpy()
    lo, hi = math.log(profile.k_min), math.log(profile.k_max)
    assert stats.kstest(log_k, stats.uniform(lo, hi - lo).cdf).pvalue > 1e-3
    rel = profile.tukey_scale
    z = (params["sigma_tl"].log().numpy() - (rel.slope * log_k + rel.intercept)) / rel.residual_std
    assert stats.kstest(z, "norm").pvalue > 1e-3
    rel = profile.row_scale
    z = (params["sigma_r"].log().numpy() - (rel.slope * log_k + rel.intercept)) / rel.residual_std
    assert stats.kstest(z, "norm").pvalue > 1e-3
    ratio = params["ratio"].numpy()
    assert stats.kstest(ratio, stats.uniform(100, 200).cdf).pvalue > 1e-3
    # lambda: the recorded value nearest the drawn K
    ks = np.array(profile.tukey_shape.k)
    dist = np.abs(np.log(ks)[None, :] - log_k[:, None])
    tied = dist <= dist.min(axis=1, keepdims=True) + 1e-9
    lam = params["lambda"].numpy()
    allowed = np.where(tied, np.array(profile.tukey_shape.values)[None, :], np.nan)
    assert np.all(np.any(np.isclose(allowed, lam[:, None]), axis=1))


def test_low_light_ratio_scales_the_noise_back():
    # G only: output noise std in normalized units = sigma_G * ratio / span
    aug = RawNoiseAugment("SonyA7S2", model="G", ratio=200.0, fixed={"sigma_g": 2.0}, generator=torch.Generator().manual_seed(0))
    x = torch.full((4, 4, 64, 64), 0.3)
    noise = (aug(x) - x).numpy().ravel()
    expected = 2.0 * 200.0 / SPAN
    assert abs(noise.std() / expected - 1) < 5 * math.sqrt(1 / (2 * noise.size))


def test_median_and_code_percentiles_equal_numpy():
    # the sort-based median and the percentiles from code counts are speed-ups: the same values
    from rawaug.statistics import code_percentiles, median

    rng = np.random.default_rng(8)
    for shape, axis in (((7,), None), ((6, 9), 1), ((6, 9), 0), ((3, 4, 10), 2), ((3, 4, 5), None), ((5, 2, 3), 0)):
        x = np.rint(rng.normal(0, 2, shape)) * rng.integers(1, 4)  # whole codes: many ties
        for keepdims in (False, True):
            want = np.median(x, axis=axis, keepdims=keepdims)
            got = median(x, axis=axis, keepdims=keepdims)
            assert np.shape(got) == np.shape(want) and np.array_equal(got, want), (shape, axis, keepdims)
    x = np.array([[1.0, np.nan, 3.0], [4.0, 5.0, 6.0]])
    assert np.array_equal(median(x, axis=1), np.median(x, axis=1), equal_nan=True)
    for n in (1, 2, 17, 999):
        v = np.rint(rng.normal(0, 5, n)) - 3
        counts = np.bincount((v - v.min()).astype(int))
        np.testing.assert_allclose(code_percentiles(counts, (0.5, 37.0, 99.5)) + v.min(), np.percentile(v, [0.5, 37.0, 99.5]),
                                   rtol=0, atol=1e-9)
