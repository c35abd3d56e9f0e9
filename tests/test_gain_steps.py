"""A flat's gain steps against the noise its frames actually have: white, coloured over the
lines (row noise of a 1/f spectrum, a flickering light), and one line's own offset."""
import numpy as np
import pytest
from scipy import stats

from rawaug.effects.tap_gain import consensus_edges
from rawaug.statistics import GAIN_P, GAIN_TEMPORAL_P, despiked, gain_edges, gain_steps, temporal_step_excess

WHITE = 1e-3  # log units per line, of each frame's profile and of the fixed pattern


def _ar1(rng, n, length, rho, sd):
    """(n, length) AR(1) profiles of innovations ``sd``: temporal noise coloured over the lines."""
    e = rng.normal(0.0, sd, (n, length))
    x = np.empty_like(e)
    x[:, 0] = e[:, 0] / np.sqrt(1.0 - rho**2)
    for i in range(1, length):
        x[:, i] = rho * x[:, i - 1] + e[:, i]
    return x


def _profiles(seed, n=2, length=384, coloured=0.0, step=0.0, at=200):
    rng = np.random.default_rng(seed)
    p = rng.normal(0.0, WHITE, length) + rng.normal(0.0, WHITE, (n, length))
    if coloured:
        p = p + _ar1(rng, n, length, 0.9, coloured)
    p[:, at:] += step
    return p


@pytest.mark.parametrize("length, n", [(128, 2), (384, 2), (384, 4)])
def test_white_temporal_noise_reads_as_coloured_at_its_nominal_rate(length, n):
    # 300 stacks: rejections binomial(300, p <= GAIN_TEMPORAL_P); 12 or more has probability < 0.1 % at 1 %
    # (measured: 2, 1 and 1 of 300)
    hits = sum(temporal_step_excess(_profiles(s, n, length)) > 0 for s in range(300))
    assert hits <= stats.binom.isf(1e-3, 300, GAIN_TEMPORAL_P), hits


def test_coloured_temporal_noise_does_not_read_as_gain_edges():
    # 100 flat pairs with AR(1) temporal noise (rho 0.9) beside the white: measured, the white-noise test
    # found edges in 21 of them and the test with the frames' excess in none; the excess was significant in 98
    found_white, found, detected = 0, 0, 0
    for s in range(1000, 1100):
        p = _profiles(s, coloured=0.6e-3)
        excess = temporal_step_excess(p)
        detected += excess > 0
        found_white += bool(gain_edges(p.mean(axis=0)))
        found += bool(gain_edges(p.mean(axis=0), excess=excess))
    assert found_white >= 10 and found <= 2 and detected >= 90, (found_white, found, detected)


def test_a_tap_step_is_still_found_under_coloured_noise():
    # a 1 % gain step, the same in every frame (it never enters the frames' spread about their mean)
    hits = [gain_edges(p.mean(axis=0), excess=temporal_step_excess(p))
            for p in (_profiles(s, coloured=0.6e-3, step=0.01) for s in range(2000, 2020))]
    assert sum(h == [200] for h in hits) >= 19, hits


def test_one_lines_offset_is_not_a_step_and_a_step_keeps_its_edge():
    rng = np.random.default_rng(5)
    p = rng.normal(0.0, WHITE, 384)
    spiked = p.copy()
    spiked[201] += 30 * WHITE  # a bright column beside the gap at 200
    assert np.abs(despiked(spiked) - p).max() < 6 * WHITE
    assert gain_edges(spiked) == []
    stepped = p.copy()
    stepped[200:] += 10 * WHITE
    assert np.array_equal(despiked(stepped)[195:206], stepped[195:206])
    assert gain_edges(stepped) == [200]
    assert np.nanargmax(np.abs(gain_steps(stepped))) == 200


def test_the_sensors_edges_are_those_most_flats_show():
    # 256: three flats of the three that found any; 90: one flat's own (noise steps at a gap of its own)
    found = [{"col": [256], "row": []}, {"col": [256], "row": [90]}, {"col": [257], "row": []}, {"col": [], "row": []}]
    assert consensus_edges(found) == {"col": [256], "row": []}
    # an edge in two flats of five that found any is not the sensor's; in three it is
    five = [{"col": [100], "row": []}] * 2 + [{"col": [300], "row": []}] * 3
    assert consensus_edges(five) == {"col": [300], "row": []}
    assert consensus_edges([{"col": [40], "row": []}]) == {"col": [40], "row": []}  # a single flat: its own
    assert consensus_edges([]) == {"col": [], "row": []}


def test_white_profiles_show_no_edge_at_the_nominal_rate_ends_included():
    # 1000 profiles of white noise (GAIN_P = 1e-3 per profile): 5 or more hits has probability
    # < 0.4 %; every gap counted, the ends' shorter windows included
    hits = sum(bool(gain_edges(np.random.default_rng(s).normal(0.0, WHITE, 384))) for s in range(3000, 4000))
    assert hits <= stats.binom.isf(4e-3, 1000, GAIN_P), hits


@pytest.mark.parametrize("at", [6, 378])
def test_a_band_of_edge_lines_with_a_gain_of_its_own_is_found_at_its_edge(at):
    """6 lines at one end of a flat at a gain of 0.95 (edge rows on their own driver), over a light
    falling off as a cubic towards that end: the edge is found at its gap in 20 of 20 profiles
    (before, no step was looked for within 32 lines of an end)."""
    x = np.linspace(-1.0, 1.0, 384)
    hits = []
    for s in range(5000, 5020):
        p = np.random.default_rng(s).normal(0.0, WHITE, 384) - 0.1 * x**2 - 0.02 * x**3
        band = slice(0, at) if at < 192 else slice(at, None)
        p[band] += np.log(0.95)
        hits.append(gain_edges(p))
    assert all(h == [at] for h in hits), hits



def test_no_step_is_measured_across_lines_without_light():
    """8 masked lines at one end (black in a flat, far below half the light): no edge and no
    finite step within reach of them (a masked band is Masked's, not a tap's gain); an edge
    beyond their reach is still found."""
    p = np.random.default_rng(6000).normal(0.0, WHITE, 384)
    p[:8] = np.log(1e-6)
    steps = gain_steps(p)
    assert np.all(np.isnan(steps[:8 + 32])) and gain_edges(p) == []
    p[200:] += 10 * WHITE
    assert gain_edges(p) == [200]
