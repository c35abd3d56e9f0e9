"""The numba CPU kernels, tested directly: distribution against scipy, exactness of the
tables, independence of the counter-based streams, thread-count invariance."""
import math

import numpy as np
import pytest
import torch
from numba import njit
from scipy import stats

from rawaug import RawNoiseAugment, cpu
from rawaug.cpu import parallel
from rawaug.cpu.poisson import COARSE_MAX, GRID_STEP, TABLE_MAX, poisson_dn, tables
from rawaug.cpu.quantile_table import add_scaled, add_signal_scaled, normal_table, symmetric, tukey_lambda_table
from rawaug.cpu.uniform import add_uniform
from rawaug.effects.read_noise import tukey_lambda_upper_quantile

P_MIN = 1e-3  # a correct sampler fails each goodness-of-fit test at this rate


def draw_counts(lam, n=200_000, key=1):
    x = torch.full((2, n // 2), lam, dtype=torch.float64)
    out = poisson_dn(x, torch.empty_like(x), torch.ones(2, dtype=torch.float64), key)
    return out.numpy().ravel()


def chi_square_p(counts, lam):
    """Chi-square p-value of integer counts against Poisson(lam), bins with >= 5 expected."""
    counts = counts.astype(np.int64)
    lo, hi = int(stats.poisson.ppf(1e-4, lam)), int(stats.poisson.isf(1e-4, lam))
    edges = np.arange(lo, hi + 1)
    observed = np.array([(counts < lo).sum()] + [(counts == k).sum() for k in edges] + [(counts > hi).sum()])
    pmf = stats.poisson.pmf(edges, lam)
    expected = counts.size * np.concatenate([[stats.poisson.cdf(lo - 1, lam)], pmf, [stats.poisson.sf(hi, lam)]])
    keep = expected >= 5
    observed = np.append(observed[keep], observed[~keep].sum())
    expected = np.append(expected[keep], expected[~keep].sum())
    if expected[-1] < 5:  # fold a small remainder into the last bin
        observed[-2] += observed[-1]
        expected[-2] += expected[-1]
        observed, expected = observed[:-1], expected[:-1]
    return stats.chisquare(observed, expected).pvalue


# Grid points, just off them, both sides of each switch (fine/coarse tables, PTRS), far above.
@pytest.mark.parametrize("lam", [0.05, 0.3, 1.0, 2.7, 4.25, 9.99, 10.5, 33.3, 63.9, 64.0, 64.1, 250.0, 1000.3,
                                 COARSE_MAX - 0.2, COARSE_MAX, 5000.0, 1e6])
def test_poisson_matches_scipy(lam):
    counts = draw_counts(lam, key=int(lam * 1000))
    assert np.array_equal(counts, np.rint(counts))
    n = counts.size
    assert abs(counts.mean() - lam) < 5 * math.sqrt(lam / n)
    se_var = math.sqrt((lam * (1 + 3 * lam) - lam**2) / n)
    assert abs(counts.var(ddof=1) - lam) < 5 * se_var
    assert chi_square_p(counts, lam) > P_MIN


def test_poisson_of_a_continuous_range_of_lambda_is_poisson_per_pixel():
    # Each pixel its own lambda: the probability integral transform of a discrete
    # variable, randomized within its jump, is U(0, 1) exactly when every draw is right.
    rng = np.random.default_rng(0)
    lam = np.concatenate([rng.uniform(0.0, 80.0, 300_000), rng.uniform(80.0, 5000.0, 100_000)])
    x = torch.from_numpy(lam.reshape(4, -1).copy())
    counts = poisson_dn(x, torch.empty_like(x), torch.ones(4, dtype=torch.float64), 99).numpy().ravel()
    v = rng.random(counts.size)
    pit = stats.poisson.cdf(counts - 1, lam) + v * stats.poisson.pmf(counts, lam)
    assert stats.kstest(pit, "uniform").pvalue > P_MIN


def test_poisson_gain_units_and_non_positive_signal():
    gain = torch.tensor([0.5, 4.0], dtype=torch.float64)
    x = torch.tensor([[-3.0, 0.0, 10.0], [-1.0, 0.0, 1e-9]], dtype=torch.float64)
    out = poisson_dn(x, torch.empty_like(x), gain, 5)
    assert out[:, :2].eq(0).all()  # no electrons below zero signal
    electrons = out / gain[:, None]
    assert torch.equal(electrons, electrons.round())  # whole electrons, times K


@pytest.mark.parametrize("which", [0, 1])
def test_poisson_tables_cover_every_reachable_count(which):
    cdf, cdf_off, guide, guide_off, guide_size, k_min = tables()[which]
    step = GRID_STEP if which == 0 else TABLE_MAX
    ends = list(cdf_off[1:]) + [len(cdf)]
    for j in range(1, len(k_min)):
        lam = j * step
        start, end = cdf_off[j], ends[j]
        assert stats.poisson.cdf(k_min[j] - 1, lam) < 2.0**-54  # below the smallest uniform
        assert stats.poisson.sf(k_min[j] + end - start - 1, lam) < 2.0**-54
        assert cdf[end - 1] == 1.0 and np.all(np.diff(cdf[start:end]) >= 0)
        # a guide cell's entry is its first count (negative: a CDF step lies inside the cell)
        size = int(guide_size[j])
        cells = guide[guide_off[j] : guide_off[j] + size]
        first = np.where(cells >= 0, cells, -cells - 1)
        assert np.array_equal(first, np.searchsorted(cdf[start:end], np.arange(size) / size, side="left"))
        pure = cells >= 0
        assert np.array_equal(first[pure], np.searchsorted(cdf[start:end], np.arange(1, size + 1)[pure] / size, side="left"))


@njit
def _quantiles(table, bits):
    out = np.empty(bits.size)
    for i in range(bits.size):
        out[i] = symmetric(table, bits[i])
    return out


@pytest.mark.parametrize("lam", [-1.0, -0.3, 0.0, 0.14, 0.5, 1.0])
def test_tukey_table_matches_the_exact_quantile(lam):
    rng = np.random.default_rng(3)
    # tails from every octave: r = 2**e + mantissa, e in 0..62, plus uniform draws
    exps = rng.integers(0, 63, 100_000)
    r = (np.uint64(1) << exps.astype(np.uint64)) | (rng.integers(0, 2**62, 100_000, dtype=np.uint64) >> (np.uint64(62) - exps.astype(np.uint64)))
    r = np.concatenate([r, rng.integers(0, 2**63, 100_000, dtype=np.uint64)]) | np.uint64(1)
    sign = rng.integers(0, 2, r.size).astype(np.uint64) << np.uint64(63)
    got = _quantiles(tukey_lambda_table(lam), r | sign)
    tail = torch.from_numpy(r.astype(np.float64) * 2.0**-64)
    exact = tukey_lambda_upper_quantile(tail, torch.tensor(lam, dtype=torch.float64)).numpy()
    exact = np.where(sign > 0, -exact, exact)  # the top bit picks the lower tail
    assert np.all(np.isfinite(got))
    rel = np.abs(got - exact) / np.maximum(np.abs(exact), 1e-12)
    assert rel.max() < 3e-6, rel.max()


@pytest.mark.parametrize("lam", [-0.3, -0.1, 0.0, 0.14, 0.5])
def test_tukey_lambda_kernel_matches_scipy(lam):
    x = torch.zeros(2, 150_000, dtype=torch.float64)
    sigma = torch.tensor([1.0, 3.0], dtype=torch.float64)
    out = add_scaled(x, torch.empty_like(x), sigma, [tukey_lambda_table(lam)] * 2, 17).numpy()
    assert stats.kstest(out[0], stats.tukeylambda(lam).cdf).pvalue > P_MIN
    assert stats.kstest(out[1], stats.tukeylambda(lam, scale=3.0).cdf).pvalue > P_MIN


def test_gaussian_kernels_match_scipy():
    x = torch.zeros(1, 300_000, dtype=torch.float64)
    z = add_scaled(x, torch.empty_like(x), torch.ones(1, dtype=torch.float64), [normal_table()], 21).numpy().ravel()
    assert stats.kstest(z, "norm").pvalue > P_MIN
    level = torch.full((1, 300_000), 40.0, dtype=torch.float64)
    shot = add_signal_scaled(level, torch.empty_like(level), torch.tensor([2.0], dtype=torch.float64), 22).numpy().ravel()
    assert stats.kstest(shot, stats.norm(40.0, math.sqrt(80.0)).cdf).pvalue > P_MIN


def test_uniform_kernel_matches_scipy():
    x = torch.zeros(1, 300_000)
    u = add_uniform(x, torch.empty_like(x), torch.tensor([2.0], dtype=torch.float64), 4).numpy().ravel()
    assert u.min() >= -1.0 and u.max() <= 1.0
    assert stats.kstest(u, stats.uniform(-1.0, 2.0).cdf).pvalue > P_MIN


def test_neighbouring_elements_and_streams_are_uncorrelated():
    n = 400_000
    x = torch.zeros(1, n, dtype=torch.float64)
    one = torch.ones(1, dtype=torch.float64)
    a = add_uniform(x, torch.empty_like(x), one, 1).numpy().ravel()
    b = add_uniform(x, torch.empty_like(x), one, 2).numpy().ravel()
    bound = 5 / math.sqrt(n)  # 5 standard errors of a correlation coefficient
    assert abs(np.corrcoef(a[:-1], a[1:])[0, 1]) < bound
    assert abs(np.corrcoef(a, b)[0, 1]) < bound
    # (the Poisson kernel's parts draw from one key's independent streams: a dependence
    # between them would show in test_poisson_matches_scipy, whose lambdas all use them)


def test_same_key_replays_and_thread_count_does_not_matter():
    x = torch.rand(3, 4, 160, 160, generator=torch.Generator().manual_seed(0)) * 50
    gain = torch.tensor([0.7, 1.0, 2.0], dtype=torch.float64)
    previous = torch.get_num_threads()
    try:
        results = []
        for threads in (1, 2, 3):
            torch.set_num_threads(threads)
            results.append(poisson_dn(x, torch.empty_like(x), gain, 8))
    finally:
        torch.set_num_threads(previous)
    assert torch.equal(results[0], results[1]) and torch.equal(results[0], results[2])
    assert not torch.equal(results[0], poisson_dn(x, torch.empty_like(x), gain, 9))


@pytest.mark.parametrize("batch,n,threads", [(1, 10, 4), (3, 100_000, 2), (8, 65_536, 7), (5, 1_000_003, 3), (0, 10, 2)])
def test_thread_segments_cover_every_element_once(batch, n, threads):
    seen = np.zeros(batch * n, dtype=np.int64)
    for pieces in parallel.segments(batch, n, threads):
        for b, start, stop in pieces:
            assert 0 <= start < stop <= n
            seen[b * n + start : b * n + stop] += 1
    assert (seen == 1).all()


def test_kernels_write_in_place_and_refuse_a_wrong_output():
    x = torch.zeros(2, 1000)
    out = add_uniform(x, x, torch.ones(2, dtype=torch.float64), 3)
    assert out is x and x.abs().sum() > 0
    with pytest.raises(ValueError, match="contiguous"):
        add_uniform(x, torch.empty(2, 999), torch.ones(2, dtype=torch.float64), 3)


def test_switching_the_kernels_off_uses_torch_samplers():
    aug = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U")
    x = torch.rand(2, 4, 32, 32)
    y = aug(x)
    previous = cpu.use_cpu_kernels(False)
    try:
        assert not cpu.handles(x)
        z = aug(x, params=aug._params)  # same parameters, torch's noise
    finally:
        cpu.use_cpu_kernels(previous)
    assert cpu.handles(x) == previous
    assert not torch.equal(y, z)
    assert torch.equal(aug(x, params=aug._params), y)
    assert not cpu.handles(x.requires_grad_())  # gradients flow through torch's path only
