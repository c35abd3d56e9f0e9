"""The noise kernels, tested through the engine: distribution against scipy, exactness of
the tables, independence of the counter-based streams, thread-count invariance, and the
numba and Triton kernels drawing the same noise from the same seed."""
import math

import numpy as np
import pytest
import torch
from numba import njit
from scipy import stats

from rawaug.cpu.counter import draw
from rawaug.cpu.poisson import COARSE_MAX, GRID_STEP, TABLE_MAX, stream_keys, tables
from rawaug.cpu.quantile_table import symmetric, tukey_lambda_table
from rawaug.distributions import tukey_lambda_upper_quantile
from rawaug.engine import backend
from rawaug.engine import layout as L
from rawaug.rng import bits_at, host_normal, host_unit, numpy_bits, stream_key, torch_bits, torch_normal, torch_unit

P_MIN = 1e-3  # a correct sampler fails each goodness-of-fit test at this rate


def run_stages(flags, dn, columns=None, seed=1, which="numba", grids=None, read_lut=None):
    """The fused kernel on DN values (span 1, ratio 1: the kernel's DN in and out)."""
    dn = torch.as_tensor(dn, dtype=torch.float64)
    if dn.ndim == 2:
        dn = dn.reshape(dn.shape[0], 4, 1, -1)
    b = dn.shape[0]
    values = torch.zeros(b, L.N_COLUMNS, dtype=torch.float64)
    values[:, L.COLUMN["k"]] = 1.0
    values[:, L.COLUMN["ratio"]] = 1.0
    for name, value in (columns or {}).items():
        values[:, L.COLUMN[name]] = torch.as_tensor(value, dtype=torch.float64)
    keys = [stream_key(seed, name) for name in L.STREAMS]
    keys[L.STREAM["shot_rest"]], keys[L.STREAM["shot_coarse"]] = stream_keys(keys[L.STREAM["shot"]])[1:]
    grids = torch.zeros(1, 1, 1, dtype=torch.float64) if grids is None else grids
    previous = backend.set_backend(which)
    try:
        read_lut = torch.zeros(1, 2, dtype=torch.float64) if read_lut is None else read_lut
        return backend.run(dn.contiguous(), values, torch.tensor(keys), 1.0, flags, grids, torch.zeros(1, 3, 1, dtype=torch.float64),
                           read_lut)
    finally:
        backend.set_backend(previous)


def draw_counts(lam, n=200_000, key=1):
    return run_stages(L.SHOT_POISSON, torch.full((2, n // 2), float(lam)), seed=key).numpy().ravel()


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
    counts = run_stages(L.SHOT_POISSON, lam.reshape(4, -1), seed=99).numpy().ravel()
    v = rng.random(counts.size)
    pit = stats.poisson.cdf(counts - 1, lam) + v * stats.poisson.pmf(counts, lam)
    assert stats.kstest(pit, "uniform").pvalue > P_MIN


def test_poisson_gain_units_and_non_positive_signal():
    gain = torch.tensor([0.5, 4.0], dtype=torch.float64)
    x = torch.tensor([[-3.0, 0.0, 10.0, 7.0], [-1.0, 0.0, 1e-9, 30.0]], dtype=torch.float64)
    out = run_stages(L.SHOT_POISSON, x, {"k": gain}).reshape(2, 4)
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
    out = run_stages(L.READ_TUKEY, torch.zeros(2, 150_000), {"sigma_tl": [1.0, 3.0], "lambda": lam}, seed=17).reshape(2, -1)
    assert stats.kstest(out[0].numpy(), stats.tukeylambda(lam).cdf).pvalue > P_MIN
    assert stats.kstest(out[1].numpy(), stats.tukeylambda(lam, scale=3.0).cdf).pvalue > P_MIN


def test_gaussian_stages_match_scipy():
    z = run_stages(L.READ_GAUSS, torch.zeros(1, 300_000), {"sigma_g": 1.0}, seed=21).numpy().ravel()
    assert stats.kstest(z, "norm").pvalue > P_MIN
    shot = run_stages(L.SHOT_GAUSS, torch.full((1, 300_000), 40.0), {"k": 2.0}, seed=22).numpy().ravel()
    assert stats.kstest(shot, stats.norm(40.0, math.sqrt(80.0)).cdf).pvalue > P_MIN


@pytest.mark.parametrize("which", ["numba", "triton"])
def test_measured_read_table_stage_draws_its_distribution(which):
    # a skewed law (gamma, shape 2) as a quantile table on the normal-score grid: record 1,
    # channel c scaled by c + 1, the per-sample scale 2 on top
    from rawaug.effects.read_distribution import grid

    law = stats.gamma(2.0, loc=-2.0)
    q = law.ppf(stats.norm.cdf(grid()))
    q[0], q[-1] = law.ppf(1e-12), law.ppf(1 - 1e-12)
    lut = torch.from_numpy(np.stack([np.zeros_like(q)] * 4 + [q * (c + 1) for c in range(4)]))  # (2 records x 4, n)
    n = 20_000 if which == "triton" else 200_000
    out = run_stages(L.READ_TABLE, torch.zeros(1, 4, 1, n), {"readq_record": 1.0, "readq_scale": 2.0}, seed=9, which=which,
                     read_lut=lut).numpy()
    for c in range(4):
        assert stats.kstest(out[0, c].ravel() / (2.0 * (c + 1)), law.cdf).pvalue > P_MIN


@pytest.mark.parametrize("which", ["numba", "triton"])
def test_defect_line_stage_draws_its_lines(which):
    # one packed frame of 4 x n x n: 2n sensor rows and 2n sensor columns
    n = 2000 if which == "numba" else 400
    cols = {"lines_row_density": 0.01, "lines_col_density": 0.03, "lines_median": 50.0, "lines_log_std": 0.4,
            "lines_negative": 0.25}
    out = run_stages(L.LINES, torch.zeros(1, 4, n, n), cols, seed=3, which=which).numpy()[0]
    rows = np.median(out, axis=2)  # (4, n): the row offsets (a few defective columns cannot move a median)
    columns = np.median(out, axis=1)  # (4, n)
    # the two packed channels of a sensor line carry its offset: row sets (0, 0, 1, 1), column sets (0, 1, 1, 0)
    assert np.array_equal(rows[0], rows[1]) and np.array_equal(rows[2], rows[3])
    assert np.array_equal(columns[0], columns[3]) and np.array_equal(columns[1], columns[2])
    for offsets, density in ((np.concatenate([rows[0], rows[2]]), 0.01), (np.concatenate([columns[0], columns[1]]), 0.03)):
        bad = offsets != 0
        mean, sd = 2 * n * density, math.sqrt(2 * n * density * (1 - density))
        assert abs(bad.sum() - mean) < 5 * sd, (bad.sum(), mean)  # binomial count
        amp = offsets[bad]
        assert stats.kstest(np.log(np.abs(amp)), stats.norm(math.log(50.0), 0.4).cdf).pvalue > P_MIN
        assert stats.binomtest(int((amp < 0).sum()), amp.size, 0.25).pvalue > P_MIN
    # a row's and a column's offsets add where they cross
    i, j = np.flatnonzero(rows[0])[0], np.flatnonzero(columns[0])[0]
    assert out[0, i, j] == pytest.approx(rows[0, i] + columns[0, j])


def test_uniform_stage_matches_scipy():
    u = run_stages(L.QUANT, torch.zeros(1, 300_000), {"step_dn": 2.0}, seed=4).numpy().ravel()
    assert u.min() >= -1.0 and u.max() <= 1.0
    assert stats.kstest(u, stats.uniform(-1.0, 2.0).cdf).pvalue > P_MIN


def test_neighbouring_elements_and_streams_are_uncorrelated():
    n = 400_000
    a = run_stages(L.QUANT, torch.zeros(1, n), {"step_dn": 1.0}, seed=1).numpy().ravel()
    b = run_stages(L.QUANT, torch.zeros(1, n), {"step_dn": 1.0}, seed=2).numpy().ravel()
    g = run_stages(L.READ_GAUSS, torch.zeros(1, n), {"sigma_g": 1.0}, seed=1).numpy().ravel()
    bound = 5 / math.sqrt(n)  # 5 standard errors of a correlation coefficient
    assert abs(np.corrcoef(a[:-1], a[1:])[0, 1]) < bound
    assert abs(np.corrcoef(a, b)[0, 1]) < bound
    assert abs(np.corrcoef(a, g)[0, 1]) < bound  # two stages of one call: different streams


def test_same_seed_replays_and_thread_count_does_not_matter():
    x = torch.rand(3, 4, 160, 160, generator=torch.Generator().manual_seed(0)) * 50
    cols = {"k": [0.7, 1.0, 2.0], "sigma_tl": 1.5, "lambda": 0.1, "sigma_r": 0.4, "step_dn": 1.0}
    flags = L.SHOT_POISSON | L.READ_TUKEY | L.ROW | L.QUANT
    previous = torch.get_num_threads()
    try:
        results = []
        for threads in (1, 2, 3):
            torch.set_num_threads(threads)
            results.append(run_stages(flags, x, cols, seed=8))
    finally:
        torch.set_num_threads(previous)
    assert torch.equal(results[0], results[1]) and torch.equal(results[0], results[2])
    assert not torch.equal(results[0], run_stages(flags, x, cols, seed=9))


def test_counter_hash_is_the_same_on_host_torch_and_numba():
    key = stream_key(5, "x")
    counters = [0, 1, 2**40 + 3]
    host = [bits_at(key, c) for c in counters]
    assert [v & (2**64 - 1) for v in torch_bits(key, torch.tensor(counters)).tolist()] == host
    assert [int(_draw(np.uint64(key), c)) for c in counters] == host
    assert [int(v) for v in numpy_bits(key, np.array(counters))] == host


def test_host_draws_equal_the_torch_draws():
    # the per-call parameter draws run in numpy on the host; the torch functions are their reference
    rng = np.random.default_rng(0)
    for _ in range(200):
        key, n = int(rng.integers(0, 2**63 - 1)), int(rng.integers(1, 70))
        assert torch.equal(host_unit(key, n), torch_unit(key, torch.arange(n)))
        assert torch.equal(host_normal(key, n), torch_normal(key, torch.arange(n)))


@njit
def _draw(key, g):
    return draw(key, g)


def test_run_ranges_cover_every_row_once():
    from rawaug.cpu.parallel import run_ranges

    for rows, threads in [(1, 4), (7, 2), (1000, 3), (5, 8)]:
        seen = np.zeros(rows, dtype=np.int64)

        def mark(r0, r1):
            seen[r0:r1] += 1
            return r1 - r0

        assert run_ranges(mark, rows, 1 << 17, threads) == rows
        assert (seen == 1).all()


@pytest.mark.parametrize("which", ["numba", "triton"])
def test_amp_glow_stage_adds_poisson_electrons_on_its_grid(which):
    # a 2 x 3 grid (e-/s) stored as record 1 of a padded 3 x 4 table, 2 s: every pixel is
    # Poisson(2 * upsampled grid) electrons (K = 1: DN = electrons)
    b, h, w = (64, 12, 18) if which == "numba" else (16, 12, 18)
    grid = torch.tensor([[5.0, 10.0, 20.0], [8.0, 15.0, 30.0]], dtype=torch.float64)
    table = torch.zeros(2, 3, 4, dtype=torch.float64)
    table[0] = -100.0  # another effect's record: never read
    table[1, :2, :3] = grid
    cols = {"glow_s": 2.0, "glow_record": 1.0, "glow_gh": 2.0, "glow_gw": 3.0}
    out = run_stages(L.GLOW | L.SHOT_POISSON, torch.zeros(b, 4, h, w), cols, seed=5, which=which, grids=table).numpy()
    from rawaug.effects.dark_shading import upsample_grid

    lam = 2.0 * upsample_grid(grid.numpy(), h, w)  # (h, w)
    assert np.array_equal(out, np.rint(out))  # whole electrons
    n = b * 4
    z = (out.mean(axis=(0, 1)) - lam) / np.sqrt(lam / n)
    assert np.abs(z).max() < 5, np.abs(z).max()  # 216 pixels: a correct stage fails this with p ~ 1e-4
    dispersion = ((out - lam) ** 2 / lam).mean()  # E = 1, var of one term (2 + 1 / lam)
    assert abs(dispersion - 1) < 5 * math.sqrt((2 + 1 / lam.min()) / out.size), dispersion


@pytest.mark.parametrize("which", ["numba", "triton"])
def test_gain_non_linearity_compresses_each_count(which):
    # after exact Poisson shot noise (K = 1: DN = electrons): s -> s (1 - c s), the same counts
    # as without the stage, so the output is a function of the count; mean x - c (x^2 + x);
    # each channel its own c (one expands)
    b = 16 if which == "numba" else 4
    c = np.array([2e-5, 1e-5, -1e-5, 3e-5])
    lam = torch.tensor([2.0, 300.0, 5000.0, 12000.0], dtype=torch.float64).view(1, 4, 1, 1).expand(b, 4, 32, 32)
    plain = run_stages(L.SHOT_POISSON, lam, seed=4, which=which).numpy()
    out = run_stages(L.SHOT_POISSON | L.NONLIN, lam, {f"nl_c{i}": c[i] for i in range(4)}, seed=4, which=which).numpy()
    c = c[:, None, None]
    assert np.allclose(out, plain * (1 - c * plain), rtol=1e-12, atol=0)
    x, c = lam[0, :, 0, 0].numpy(), c.ravel()
    var = (1 - 2 * c * x) ** 2 * x + 2 * c**2 * x**2  # Var[s - c s^2] for Poisson s, to second order in c
    z = (out.mean(axis=(0, 2, 3)) - (x - c * (x * x + x))) / np.sqrt(var / (b * 32 * 32))
    assert np.abs(z).max() < 5, z  # 4 channels: a correct stage fails this with p ~ 2e-6
