"""FixedField: the measured fixed field (a blotchy fixed pattern at its measured scale), through
the real stage, its estimator and its profile entry."""
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import fixed_field

from base_camera import base_fixed

BASE = NoiseProfile.load("SonyA7S2")
SHAPE = (96, 128)


def field(cell, sigma=1.0, k=1.0):
    h, w = SHAPE
    return {"seed": 3, "grid": [h // cell, w // cell], "k": [k], "sigma_dn": [sigma], "frame_h": h, "frame_w": w}


def bias(params, seed, n=4, k=1.0, sensor=0, shape=SHAPE):
    """(n, 4, h, w) bias frames in DN: the base camera's read noise, a fixed field ``params``."""
    profile = BASE.with_effect("FixedField", params) if params else BASE
    fixed = base_fixed(BASE, k, sensor)
    aug = RawNoiseAugment(profile, model="G+P+R" + ("+FixedField" if params else ""), ratio=1.0, fixed=fixed,
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.zeros((n, 4, *shape))).numpy().astype(np.float64) * BASE.span_dn


def test_the_field_is_fixed_shared_by_the_channels_and_a_sensor_s_own():
    a, b = bias(field(4), seed=1), bias(field(4), seed=2)
    base_a, base_b = bias(None, seed=1), bias(None, seed=2)
    pattern = a - base_a  # the same draws otherwise: the field alone
    assert np.allclose(pattern, b - base_b, atol=1e-4)  # the same in every frame and call (float32 sums)
    assert np.allclose(pattern, pattern[:1, :1], atol=1e-4)  # one field at each packed position, in every channel
    other = bias(field(4), seed=1, sensor=1) - base_a
    assert abs(np.corrcoef(pattern[0, 0].ravel(), other[0, 0].ravel())[0, 1]) < 5 / np.sqrt(pattern[0, 0].size / 16)


def test_the_field_s_spectrum_is_the_unit_field_s_times_its_variance():
    """The stage's field (8 sensors) against the estimator's unit field of the same cell, ring
    by ring: within 5 standard errors (a ring's mean power of n exponential bins has the sd
    power / sqrt(n), for the stage's fields and the unit field's simulated ones)."""
    cell, sigma, sensors = 4, 1.5, 8
    fields = np.stack([fixed_field._field(bias(field(cell, sigma), seed=3, n=1, sensor=s) - bias(None, seed=3, n=1, sensor=s))
                       for s in range(sensors)])
    got, bins = fixed_field.ring_power(fields, counts=True)
    want = sigma**2 * fixed_field._unit_power(*SHAPE, cell)
    n_unit = int(max(2, min(16, 2**22 // (SHAPE[0] * SHAPE[1]))))  # the unit field's simulated fields
    se = want * np.sqrt(1.0 / (sensors * bins) + 1.0 / (n_unit * bins))
    strong = want > 0.01 * want.max()
    assert strong.sum() >= 8
    assert np.all(np.abs(got - want)[strong] < 5 * se[strong]), np.round((got - want) / se, 1)


@pytest.mark.parametrize("cell", [2, 8])
def test_the_estimate_finds_the_cell_and_the_sigma_and_little_where_there_is_none(cell):
    """5 sensors per cell size (4 bias frames each, against 3 syntheses): the planted cell, and
    sigma 1 DN within 15 %; a camera without the field gets under 5 % of its variance."""
    for session in range(5):
        synth = [bias(None, seed=100 * session + 10 + j) for j in range(3)]
        got = fixed_field.estimate(bias(field(cell), seed=100 * session, sensor=session), synth, 1.0, kind="bias")
        assert got["grid"] == field(cell)["grid"] and got["sigma_dn"][0] == pytest.approx(1.0, rel=0.15), (cell, session, got)
        none = fixed_field.estimate(bias(None, seed=100 * session + 1), synth, 1.0, kind="bias")
        assert none["sigma_dn"][0] ** 2 < 0.05, (session, none)


def test_combine_keeps_the_grid_most_stacks_chose():
    rec = lambda grid, k, s: {"seed": 3, "grid": grid, "k": [k], "sigma_dn": [s], "frame_h": 96, "frame_w": 128}  # noqa: E731
    out = fixed_field.combine([rec([48, 64], 1.0, 1.0), rec([48, 64], 1.0, 1.2), rec([24, 32], 3.0, 5.0), rec([48, 64], 3.0, 2.0)])
    assert out["grid"] == [48, 64] and out["k"] == [1.0, 3.0] and out["sigma_dn"] == pytest.approx([1.1, 2.0])


def test_an_input_of_another_size_keeps_the_measured_cell():
    big = bias(field(4), seed=5, n=1, shape=(192, 256)) - bias(None, seed=5, n=1, shape=(192, 256))
    grid_power = fixed_field._unit_power(192, 256, 4)
    got = fixed_field.ring_power(fixed_field._field(big))
    assert np.argmax(got) == np.argmax(grid_power)


@pytest.mark.parametrize("params, match", [
    ({"seed": 1, "grid": [0, 4], "k": [1.0], "sigma_dn": [1.0]}, "grid"),
    ({"seed": 1, "grid": [4, 4], "k": [1.0], "sigma_dn": [-1.0]}, "sigma_dn must be >= 0"),
])
def test_bad_parameters_name_the_value(params, match):
    with pytest.raises(ValueError, match=match):
        BASE.with_effect("FixedField", params)


def test_the_estimator_takes_bias_and_dark_stacks_only():
    with pytest.raises(ValueError, match="bias or dark stacks"):
        fixed_field.estimate(np.zeros((2, 4, 16, 16)), [], 1.0, kind="flat")
