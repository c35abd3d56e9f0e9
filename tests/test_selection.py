"""The histogram selection behind ``statistics.median``: the values a full sort puts at the
two middle ranks, on every kind of row the statistics meet (continuous, heavy-tailed,
whole codes with ties, constant, float32, ranges near float64's limit)."""
import numpy as np
import pytest

from rawaug.selection import middle_pair
from rawaug.statistics import median


def _rows(kind, rng, m, n):
    if kind == "normal":
        return rng.normal(size=(m, n))
    if kind == "cauchy":  # a few values far out: the first bins hold nearly everything
        return rng.standard_cauchy(size=(m, n)) * 1e6
    if kind == "codes":  # whole DN: ties at every rank
        return np.rint(rng.normal(0.0, 2.0, size=(m, n)))
    if kind == "float32":
        return rng.normal(size=(m, n)).astype(np.float32)
    if kind == "half_constant":
        x = rng.normal(size=(m, n))
        x[:, : n // 2 + 1] = 7.0
        return x
    if kind == "huge_range":  # max - min overflows float64
        x = rng.normal(size=(m, n))
        x[:, 0], x[:, 1] = -1.5e308, 1.5e308
        return x
    if kind == "tiny_spread":  # values one ulp apart around a large offset
        return 1e15 + rng.integers(0, 3, size=(m, n)).astype(np.float64) * 0.125
    raise AssertionError(kind)


KINDS = ["normal", "cauchy", "codes", "float32", "half_constant", "huge_range", "tiny_spread"]


@pytest.mark.parametrize("kind", KINDS)
def test_middle_pair_is_the_sorted_rows_ranks(kind):
    rng = np.random.default_rng(KINDS.index(kind))
    for n in (2, 3, 64, 65, 1000, 4097, 70000):
        x = _rows(kind, rng, 3, n)
        s = np.sort(x, axis=1)
        for rank in sorted({0, (n - 1) // 2, n // 2 - 1, n - 2} - {-1}):
            lo, hi = middle_pair(x, rank)
            assert np.array_equal(lo, s[:, rank]) and np.array_equal(hi, s[:, rank + 1]), (kind, n, rank)
            assert lo.dtype == x.dtype


# (not huge_range: two middle values of 1.5e308 overflow the half-sum NumPy avoids)
@pytest.mark.parametrize("kind", [k for k in KINDS if k != "huge_range"])
def test_median_equals_numpy_along_every_axis(kind):
    rng = np.random.default_rng(100 + KINDS.index(kind))
    x = _rows(kind, rng, 6, 301).reshape(2, 3, 301)
    for axis in (None, 0, 1, 2, -1):
        assert np.array_equal(np.asarray(median(x, axis=axis)), np.asarray(np.median(x, axis=axis))), (kind, axis)
        assert np.shape(median(x, axis=axis, keepdims=True)) == np.shape(np.median(x, axis=axis, keepdims=True))


def test_median_of_non_finite_values_is_numpys():
    x = np.arange(200.0)
    x[5] = np.inf
    assert median(x) == np.median(x)
    x[7] = np.nan
    assert np.isnan(median(x))


def test_middle_pair_refuses_a_rank_without_a_value_above_it():
    with pytest.raises(ValueError, match="more than rank"):
        middle_pair(np.zeros((2, 5)), 4)
    with pytest.raises(ValueError, match="2-D"):
        middle_pair(np.zeros(5), 1)
