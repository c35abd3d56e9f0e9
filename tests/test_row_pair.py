"""RowPair: the two sensor rows of a Bayer row pair share a row offset, new in every frame,
through the real stage and its estimator."""
import math

from rawaug import NoiseProfile
from rawaug.effects import row_pair
from rawaug.statistics import row_pair_corr, row_pair_covariances

from base_camera import bias_stack

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
PAIRS = {"k": [K], "sigma_dn": [1.0]}


def stack(effects, seed, n=8, size=96, sensor=0):
    """(n, 4, size, size) bias frames (DN) at gain K with ``effects`` (token: entry)."""
    return bias_stack(BASE, effects, K, seed, n=n, size=size, sensor=sensor)


def test_the_two_rows_of_a_pair_move_together():
    """64 frames of 96 row pairs at 1.0 DN: the covariance of a pair's rows less that of rows of
    adjacent pairs within 5 sd of 1 DN^2 x 63/64 (the stack's mean took 1/64), and
    row_pair_corr over 0.3; without pairs under 0.05 in size."""
    within, across, var = row_pair_covariances(stack({"RowPair": PAIRS}, 1, n=64))
    want = 63 / 64
    assert abs(within - across - want) < 5 * var * math.sqrt(2.0 / (64 * 96)), (within, across, var)
    assert row_pair_corr(stack({"RowPair": PAIRS}, 2)) > 0.3
    assert abs(row_pair_corr(stack({}, 2))) < 0.05


def test_estimate_finds_the_pairs_and_none_without():
    """Ten sessions of 8 bias frames (128 row pairs) at 0.8 DN: found within 30 % in each (5 sd of
    an rms over 8 x 128 pairs and the row noise about them); twenty sessions without pairs and
    ten with twice the model's row noise (each row its own): none (the difference of
    covariances under 5 standard errors)."""
    pairs = {"k": [K], "sigma_dn": [0.8]}
    base = [stack({}, s, size=128, sensor=1) for s in range(100, 104)]
    for session in range(10):
        est = row_pair.estimate(stack({"RowPair": pairs}, 10 + session, size=128), base, K, kind="bias")
        assert abs(est["sigma_dn"][0] - 0.8) < 0.3 * 0.8, est
    loud = BASE.with_effect("RowCh", {"k": [K], "sigma_dn": [1.0]})  # more row noise, every channel's row its own
    none = [row_pair.estimate(stack({}, 30 + s, size=128), base, K, kind="bias") for s in range(20)]
    none += [row_pair.estimate(bias_stack(loud, {}, K, 60 + s, size=128), base, K, kind="bias") for s in range(10)]
    assert all(row_pair.empty(row_pair.combine([e])) for e in none), none
