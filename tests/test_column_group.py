"""ColGroup: groups of adjacent sensor columns sharing an offset, new in every frame, through the
real stage and its estimator."""
import math

import numpy as np

from rawaug import NoiseProfile
from rawaug.effects import column_group
from rawaug.statistics import col_neighbour_corr, temporal_col_deviations

from base_camera import bias_stack

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
GROUPS = {"width": 16, "start": 0, "k": [K], "sigma_dn": [1.5]}


def stack(effects, seed, n=8, size=96, sensor=0):
    """(n, 4, size, size) bias frames (DN) at gain K with ``effects`` (token: entry)."""
    return bias_stack(BASE, effects, K, seed, n=n, size=size, sensor=sensor)


def test_sixteen_adjacent_sensor_columns_move_together_and_groups_apart():
    """64 frames of 192 sensor columns (12 groups of 16): the temporal parts of two columns of one
    group differ by the columns' own noise only (their difference's variance that of the stack
    without groups, within 15 %), while columns of neighbouring groups differ by 2 x 1.5^2
    DN^2 more (within 5 sd over 64 x 11 pairs)."""
    d = temporal_col_deviations(stack({"ColGroup": GROUPS}, 1, n=64))
    base = temporal_col_deviations(stack({}, 1, n=64))
    same = np.var(d[:, 5::16] - d[:, 6::16])
    own = np.var(base[:, 5::16] - base[:, 6::16])
    assert abs(same / own - 1.0) < 0.15, (same, own)
    apart = np.var(d[:, 15:-1:16] - d[:, 16::16])
    want = 2 * 1.5**2 + own
    assert abs(apart - want) < 5 * want * math.sqrt(2.0 / (64 * 11)), (apart, want)


def test_estimate_finds_the_groups_and_none_without():
    """Ten sessions of 8 bias frames of 256 sensor columns with groups of 16 from column 5 at 1.2
    DN: width 16 and start 5 in each and the offset within 30 % of 1.2 DN (5 sd of an rms over
    8 x 16 groups); ten sessions without groups and ten with
    independent column noise (Col, 1 DN): no groups (lag-1 excess under 5 se)."""
    groups = {**GROUPS, "start": 5, "sigma_dn": [1.2]}
    base = [stack({}, s, size=128, sensor=1) for s in range(100, 104)]
    for session in range(10):
        est = column_group.estimate(stack({"ColGroup": groups}, 10 + session, size=128), base, K, kind="bias")
        assert est["width"] == 16 and est["start"] == 5 and abs(est["sigma_dn"][0] - 1.2) < 0.3 * 1.2, est
    col = {"seed": 3, "k": [K], "sigma_dn": [1.0], "fixed_dn": [0.5]}
    none = [column_group.estimate(stack({}, 30 + s, size=128), base, K, kind="bias") for s in range(10)]
    none += [column_group.estimate(stack({"Col": col}, 60 + s, size=128), base, K, kind="bias") for s in range(10)]
    assert all(column_group.empty(column_group.combine([e])) for e in none), none


def test_the_neighbour_correlation_sees_groups_only():
    """col_neighbour_corr: over 0.5 with groups of 16 at 1.5 DN, within 0.1 of 0 without."""
    assert col_neighbour_corr(stack({"ColGroup": GROUPS}, 3)) > 0.5
    assert abs(col_neighbour_corr(stack({}, 3))) < 0.1


def test_narrow_groups_are_found_under_strong_read_noise():
    """Pairs of sensor columns (width 2) sharing 1.0 DN at K 3 (read noise about 3 times K 1's):
    width 2 and start 0 in 10 of 10 sessions, the offset within 30 % (a fit with a parameter per
    group and frame, BIC, chose the widest groups here: 128 pairs x 8 frames of parameters cost
    more than they gained)."""
    k = 3.0
    pairs = {"width": 2, "start": 0, "k": [k], "sigma_dn": [1.0]}
    base = [bias_stack(BASE, {}, k, s, size=128, sensor=1) for s in range(100, 104)]
    for session in range(10):
        est = column_group.estimate(bias_stack(BASE, {"ColGroup": pairs}, k, 10 + session, size=128), base, k, kind="bias")
        assert est["width"] == 2 and est["start"] == 0 and abs(est["sigma_dn"][0] - 1.0) < 0.3, est
