"""Masked: optically black lines at the frame's edges (no light in flats), through the real stage."""
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import masked_lines
from rawaug.loop.illumination import illumination_shape
from rawaug.statistics import masked_lines as masked_share

SHAPE = (48, 64)  # packed pixels per channel: 96 x 128 sensor lines
LEVEL = 0.1  # of white: ~1500 DN
MASK = {"top": 8, "bottom": 0, "left": 3, "right": 2, "frame_h": SHAPE[0], "frame_w": SHAPE[1]}


def flats(mask=None, n=2, seed=0, shape=SHAPE, light=None):
    """A flat stack (n, 4, h, w) in DN at K 1 with read and shot noise, through RawNoiseAugment."""
    profile = NoiseProfile.load("SonyA7S2")
    if mask is not None:
        profile = profile.with_effect("Masked", mask)
    aug = RawNoiseAugment(profile, model="G+P", ratio=1.0, fixed={"k": 1.0, "sigma_g": 2.0},
                          generator=torch.Generator().manual_seed(seed))
    x = torch.full((n, 4, *shape), LEVEL, dtype=torch.float64) * (1.0 if light is None else torch.as_tensor(light))
    with torch.no_grad():
        return aug(x).numpy() * profile.span_dn


def sensor_rows(f):
    m = f.mean(axis=0)
    out = np.empty(2 * m.shape[1])
    out[0::2], out[1::2] = m[[0, 1]].mean(axis=(0, 2)), m[[2, 3]].mean(axis=(0, 2))
    return out


def sensor_cols(f):
    m = f.mean(axis=0)
    out = np.empty(2 * m.shape[2])
    out[0::2], out[1::2] = m[[0, 3]].mean(axis=(0, 1)), m[[1, 2]].mean(axis=(0, 1))
    return out


def test_the_masked_lines_get_no_light_on_the_measured_frame_only():
    f = flats(MASK)
    rows, cols = sensor_rows(f), sensor_cols(f)
    level = np.median(rows)
    # a masked line's mean: read noise only, 2 DN over >= 96 x 2 pixels, against ~1500 DN of light
    assert np.all(np.abs(rows[:8]) < 5 * 2.0 / np.sqrt(2 * 128 * 2)) and np.all(rows[8:] > 0.9 * level)
    assert np.all(np.abs(cols[:3]) < 5 * 2.0 / np.sqrt(2 * 96 * 2)) and np.all(np.abs(cols[-2:]) < 5 * 2.0 / np.sqrt(2 * 96 * 2))
    assert np.all(cols[3:-2] > 0.9 * level)
    crop = flats(MASK, shape=(40, 40))  # a crop: its edges are not the sensor's
    assert masked_share(crop) == 0.0 and sensor_rows(crop).min() > 0.9 * level


def test_estimate_measures_the_lines_back_and_none_under_uneven_light():
    # 5 sessions with the mask: every edge exact; 10 without: none, also under a light 30 %
    # darker in the corners (a cos^4 vignetting a wide lens gives)
    for s in range(5):
        est = masked_lines.estimate(flats(MASK, seed=s), [], 1.0, kind="flat")
        assert est == MASK, est
    yy, xx = np.meshgrid(np.linspace(-1, 1, SHAPE[0]), np.linspace(-1, 1, SHAPE[1]), indexing="ij")
    vignette = np.cos(np.arctan(0.55 * np.hypot(yy, xx))) ** 4  # 0.7 in the corners
    for s in range(10):
        f = flats(seed=10 + s, light=vignette)
        assert masked_lines.empty(masked_lines.combine([masked_lines.estimate(f, [], 1.0, kind="flat")]))
        assert masked_share(f) == 0.0
    with pytest.raises(ValueError, match="flat stacks"):
        masked_lines.estimate(flats(), [], 1.0, kind="bias")


def test_the_light_shape_is_fitted_without_the_masked_lines():
    # the same light with and without the shield: the shapes agree off the masked lines within
    # 0.5 % (the fit of a uniform light is 1 within its noise; with the dark lines in it, the
    # polynomial bent by ~10 % near the top)
    masked, bare = flats(MASK, n=4, seed=3), flats(n=4, seed=3)
    a, b = illumination_shape(masked.mean(axis=0)), illumination_shape(bare.mean(axis=0))
    inside = (slice(None), slice(4, None), slice(2, -1))
    assert np.abs(a[inside] / a[inside].mean() - b[inside] / b[inside].mean()).max() < 0.005


@pytest.mark.parametrize("params, words", [
    ({**MASK, "top": -1}, "top must be a whole number of sensor lines >= 0, got -1"),
    ({**MASK, "frame_h": 0}, "frame_h must be a whole number of packed pixels >= 1, got 0"),
    ({**MASK, "top": 60, "bottom": 40}, "exceed the frame's sensor lines (96 x 128)"),
    ({k: v for k, v in MASK.items() if k != "left"}, "needs exactly the keys"),
])
def test_bad_entries_are_named(params, words):
    with pytest.raises(ValueError) as err:
        NoiseProfile.load("SonyA7S2").with_effect("Masked", params)
    assert words in str(err.value)
