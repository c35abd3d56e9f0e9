"""BlackRamp: the black level ramps across the frame by a new amount in every frame, through the
real stage and its estimator."""
import math


from rawaug import NoiseProfile
from rawaug.effects import black_ramp
from rawaug.statistics import col_ramp_std, frame_slopes, row_ramp_std

from base_camera import bias_stack

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
RAMP = {"k": [K], "row_dn": [0.01], "col_dn": [0.0]}


def stack(effects, seed, n=8, size=96, sensor=0):
    """(n, 4, size, size) bias frames (DN) at gain K with ``effects`` (token: entry)."""
    return bias_stack(BASE, effects, K, seed, n=n, size=size, sensor=sensor)


def test_each_frame_ramps_down_the_rows_by_its_own_slope():
    """64 frames of 192 sensor rows at 0.01 DN per row: the frames' fitted slopes have a std
    within 5 sd (of a std over 64 draws) of 0.01 DN per row, the columns' a std under 0.002
    (the row and pixel noise's alone), and the statistics read 1.9 DN over the frame's height."""
    f = stack({"BlackRamp": RAMP}, 1, n=64)
    sd = frame_slopes(f).std(ddof=1)
    assert abs(sd - 0.01) < 5 * 0.01 / math.sqrt(2 * 63), sd
    assert frame_slopes(f, columns=True).std(ddof=1) < 0.002
    assert abs(row_ramp_std(f) - 0.01 * 192) < 5 * 0.01 * 192 / math.sqrt(2 * 63) and col_ramp_std(f) < 0.4


def test_estimate_finds_the_ramps_and_none_without():
    """Ten sessions of 8 bias frames (256 sensor lines) ramping 0.01 DN per row and 0.005 per
    column: both found in 10 of 10, each within a factor 2 (a std over 8 frames: 27 % rms);
    twenty sessions without: none on either axis (an F test at 1e-3 per axis and stack)."""
    ramp = {"k": [K], "row_dn": [0.01], "col_dn": [0.005]}
    base = [stack({}, s, size=128, sensor=1) for s in range(100, 104)]
    for session in range(10):
        est = black_ramp.estimate(stack({"BlackRamp": ramp}, 10 + session, size=128), base, K, kind="bias")
        assert 0.005 < est["row_dn"][0] < 0.02 and 0.0025 < est["col_dn"][0] < 0.01, est
    none = [black_ramp.estimate(stack({}, 30 + s, size=128), base, K, kind="bias") for s in range(20)]
    assert all(black_ramp.empty(black_ramp.combine([e])) for e in none), none


def test_the_stacks_of_a_gain_are_pooled():
    """A bias stack of 8 frames and a dark stack of 4 at one gain give one record, their slope
    variances pooled by degrees of freedom (7 and 3); a gain whose pooled ratio fails the F test
    gets 0."""
    seen = {"k": [1.0], "rows": [[4e-4, 1e-6, 7, 28]], "cols": [[1e-6, 1e-6, 7, 28]]}
    dark = {"k": [1.0], "rows": [[1e-4, 1e-6, 3, 12]], "cols": [[1e-6, 1e-6, 3, 12]]}
    other = {"k": [3.0], "rows": [[1.1e-6, 1e-6, 7, 28]], "cols": [[1e-6, 1e-6, 7, 28]]}
    out = black_ramp.combine([seen, dark, other])
    assert out["k"] == [1.0, 3.0] and out["col_dn"] == [0.0, 0.0] and out["row_dn"][1] == 0.0
    assert math.isclose(out["row_dn"][0], math.sqrt((7 * 4e-4 + 3 * 1e-4) / 10 - 1e-6)), out
