"""The measured read-noise distribution (ReadDist): estimated quantiles, dequantized codes,
its profile entry, and what the kernel draws from it."""
import numpy as np
import pytest
import torch
from scipy import stats

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import read_distribution as rd

P_MIN = 1e-3


def test_estimated_table_is_the_residual_quantile_function():
    # a skewed read noise (gamma, shape 3) with row offsets: the table holds the law, centred
    rng = np.random.default_rng(0)
    law = stats.gamma(3.0, scale=1.5)
    frames = 10.0 + law.rvs(size=(4, 4, 128, 128), random_state=rng) + 0.7 * rng.standard_normal((4, 1, 128, 1))
    rec = rd.estimate(frames, None, 2.0)
    assert rec["k"] == [2.0]
    q = np.asarray(rec["quantiles_dn"][0])
    assert q.shape == (4, rd.N_GRID)
    z = rd.grid()[np.abs(rd.grid()) <= 3.0]  # 0.13 % .. 99.87 %
    p = stats.norm.cdf(z)
    truth = law.ppf(p) - law.mean()
    # bound: 5 standard errors of a sample quantile of 65,536 values, sqrt(p (1 - p) / n) / f(q),
    # plus 0.25 DN: removing each row's mean (the row noise's part) also removes that row's
    # read-noise mean, sigma / sqrt(128) = 0.23 DN, which smooths the law's sharp lower end
    bound = 5 * np.sqrt(p * (1 - p) / frames[:, 0].size) / law.pdf(law.ppf(p)) + 0.25
    i = np.flatnonzero(np.abs(rd.grid()) <= 3.0)
    for c in range(4):
        assert np.all(np.abs(q[c, i] - truth) < bound), np.max(np.abs(q[c, i] - truth) - bound)
    np.testing.assert_allclose(rd.table_mean(q), 0.0, atol=1e-9)


def test_dequantized_codes_stay_in_their_cells():
    rng = np.random.default_rng(1)
    codes = rng.choice([0.0, 4.0, 5.0, 8.0], p=[0.3, 0.5, 0.15, 0.05], size=200_000)
    v = rd.dequantized(codes, seed=2)
    cells = {0.0: (-0.5, 2.0), 4.0: (2.0, 4.5), 5.0: (4.5, 6.5), 8.0: (6.5, 8.5)}
    for code, (lo, hi) in cells.items():
        x = v[codes == code]
        assert x.min() >= lo and x.max() <= hi
        assert stats.kstest(x, stats.uniform(lo, hi - lo).cdf).pvalue > P_MIN
    unit = rd.dequantized(rng.integers(0, 20, size=10_000).astype(float), seed=3)  # every code written: one DN
    assert np.all(np.abs(unit - np.rint(unit)) <= 0.5)


def test_profile_entry_round_trips_and_bad_tables_are_named(tmp_path):
    q = np.sort(np.random.default_rng(3).normal(size=(1, 4, rd.N_GRID)), axis=-1)
    prof = NoiseProfile.load("SonyA7S2").with_effect("ReadDist", {"k": [1.0], "quantiles_dn": q.tolist()})
    prof.save(tmp_path / "p.yaml")
    np.testing.assert_array_equal(np.asarray(NoiseProfile.load(tmp_path / "p.yaml").effects["ReadDist"]["quantiles_dn"]), q)
    base = NoiseProfile.load("SonyA7S2")
    for bad in (q[..., ::-1], q[:, :3], np.full_like(q, np.nan)):
        with pytest.raises(ValueError, match="quantiles_dn"):
            base.with_effect("ReadDist", {"k": [1.0], "quantiles_dn": bad.tolist()})


def test_the_stage_draws_the_table_at_its_gain_and_scales_it_with_the_read_noise_relation():
    law = stats.laplace(scale=2.0)
    q = law.ppf(stats.norm.cdf(rd.grid()))
    q[0], q[-1] = law.ppf(1e-12), law.ppf(1 - 1e-12)
    prof = NoiseProfile.load("SonyA7S2").with_effect("ReadDist", {"k": [1.0], "quantiles_dn": [[q.tolist()] * 4]})
    x = torch.zeros(4, 4, 128, 128)
    at_record = RawNoiseAugment(prof, model="G*", ratio=1.0, fixed={"k": 1.0})(x).numpy().ravel() * prof.span_dn
    assert stats.kstest(at_record, law.cdf).pvalue > P_MIN
    k2 = 4.0
    ratio = prof.tukey_scale.median(k2) / prof.tukey_scale.median(1.0)
    scaled = RawNoiseAugment(prof, model="G*", ratio=1.0, fixed={"k": k2})(x).numpy().ravel() * prof.span_dn
    assert stats.kstest(scaled / ratio, law.cdf).pvalue > P_MIN


def test_a_one_sided_tail_is_measured_with_its_single_frame_events():
    # read noise of 1.5 DN plus, in 3 % of the readings, an exponential of mean 4 DN (a trap that
    # only adds): the events far out in one frame are the tail's, so the table keeps them and a
    # synthesis from it makes as many single-frame events (spike_fraction, ~70 per stack here)
    # as the measured stack: within 5 Poisson sd of the count, 4 syntheses against one stack
    from rawaug.statistics import spike_fraction

    rng = np.random.default_rng(3)
    shape = (8, 4, 64, 64)
    frames = np.rint(1.5 * rng.standard_normal(shape) + (rng.random(shape) < 0.03) * rng.exponential(4.0, shape)) + 100.0
    rec = rd.estimate(frames, None, 1.0)
    q = np.asarray(rec["quantiles_dn"][0])
    assert np.all(q[:, -20] > 3.0 * -q[:, 19])  # the upper tail far longer than the lower
    profile = NoiseProfile.load("SonyA7S2").with_effect("ReadDist", {"k": [1.0], "quantiles_dn": rec["quantiles_dn"]})
    measured = spike_fraction(frames - 100.0) * frames.size
    synth = []
    for seed in range(4):
        aug = RawNoiseAugment(profile, model="G*", ratio=1.0, fixed={"k": 1.0, "sensor": 0}, rank_seeding=False,
                              generator=torch.Generator().manual_seed(seed))
        out = np.rint(aug(torch.zeros(shape, dtype=torch.float64)).numpy() * profile.span_dn)
        synth.append(spike_fraction(out) * out.size)
    assert measured > 30
    assert abs(np.mean(synth) - measured) < 5 * np.sqrt(measured * (1 + 1 / 4)), (measured, synth)
