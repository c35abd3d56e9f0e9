"""The one-pass code histogram behind missing_codes, code_dnl and clip_low: NumPy's counts
of the rounded values (halves to even), its lowest code, and whether the values were whole."""
import numpy as np
import pytest

from rawaug.code_histogram import code_histogram
from rawaug.statistics import clip_low, code_counts, missing_codes


@pytest.mark.parametrize("kind", ["whole", "halves", "continuous", "float32", "int", "one_value"])
def test_counts_are_numpys_bincount_of_the_rounded_values(kind):
    rng = np.random.default_rng(3)
    v = {"whole": np.rint(rng.normal(-20, 5, 10000)),
         "halves": rng.integers(-8, 8, 10000) + 0.5,  # np.rint rounds each to the even neighbour
         "continuous": rng.normal(100, 30, 10000),
         "float32": np.rint(rng.normal(0, 3, 10000)).astype(np.float32),
         "int": rng.integers(-5, 300, 10000),
         "one_value": np.full(100, 4.0)}[kind]
    lowest, counts, whole = code_histogram(v)
    r = np.rint(v).astype(np.int64)
    assert lowest == r.min()
    assert np.array_equal(counts, np.bincount(r - r.min()))
    assert whole == bool(np.all(v == np.rint(v)))


def test_statistics_read_the_histogram_as_before():
    rng = np.random.default_rng(4)
    frames = np.rint(rng.normal(0, 4, (4, 4, 16, 16)))
    frames[frames % 3 == 0] += 1  # a comb: every third code missing
    r = np.rint(frames).astype(np.int64).ravel()
    counts = np.bincount(r - r.min())
    assert clip_low(frames) == float((np.rint(frames) <= np.rint(frames).min()).mean())
    codes, got = code_counts(frames)
    assert np.array_equal(got, counts) and codes[0] == r.min()
    assert code_counts(frames + 0.25) is None  # not whole codes
    assert 0.2 < missing_codes(frames) < 0.5


def test_non_finite_values_are_refused():
    with pytest.raises(ValueError, match="finite"):
        code_histogram(np.array([1.0, np.nan]))
