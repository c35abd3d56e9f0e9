"""Spatial patterns keep their measured scale: on a crop smaller than the measured frame,
FPN shading is a window of the frame's shading and LowFreq keeps its cell size."""
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects.dark_shading import upsample_grid
from rawaug.engine import backend

GRID = np.random.default_rng(0).normal(0.0, 3.0, (8, 8))


def shading_profile(frame=(256, 192)):
    params = {"seed": 5, "k": [1.0], "sigma_dn": [0.0], "shading_dn": [GRID.tolist()]}
    if frame:
        params.update(frame_h=frame[0], frame_w=frame[1])
    return NoiseProfile.load("SonyA7S2").with_effect("FPN", params)


def shading_only(profile, x, name):
    aug = RawNoiseAugment(profile, model="G", ratio=1.0, fixed={"k": 1.0, "sigma_g": 0.0}, rank_seeding=False,
                          generator=torch.Generator().manual_seed(3))
    previous = backend.set_backend(name)
    try:
        out = aug(x)
    finally:
        backend.set_backend(previous)
    return out.double().numpy() * profile.span_dn, aug.sample_parameters(aug._params)


@pytest.mark.parametrize("name", ["numba", "triton"])
def test_fpn_shading_on_a_crop_is_a_window_of_the_measured_frame(name):
    pytest.importorskip("triton")
    profile = shading_profile()
    full = upsample_grid(GRID, 256, 192)
    out, params = shading_only(profile, torch.zeros(6, 4, 48, 40), name)
    oy, ox = params["fpn_oy"].numpy().astype(int), params["fpn_ox"].numpy().astype(int)
    assert len(set(zip(oy, ox))) == 6 and oy.max() <= 256 - 48 and ox.max() <= 192 - 40  # a window per sample
    for b in range(6):
        window = full[oy[b] : oy[b] + 48, ox[b] : ox[b] + 40]
        for c in range(4):
            np.testing.assert_allclose(out[b, c], window, atol=2e-3)  # float32 output of ~10 DN
    # the window keeps the shading's measured scale: its spread is far below the whole grid's
    assert np.mean([out[b, 0].std() for b in range(6)]) < 0.7 * full.std()


def test_fpn_shading_on_the_measured_frame_or_without_its_size_is_stretched_over_the_input():
    x = torch.zeros(2, 4, 64, 48)
    stretched = upsample_grid(GRID, 64, 48)
    for profile in (shading_profile(frame=(64, 48)), shading_profile(frame=None), shading_profile(frame=(32, 32))):
        out, params = shading_only(profile, x, "numba")
        assert float(params["fpn_oy"].abs().max()) == 0.0
        np.testing.assert_allclose(out[:, 0], np.broadcast_to(stretched, (2, 64, 48)), atol=2e-3)


def test_lowfreq_keeps_its_cell_size_on_inputs_of_any_size():
    base = NoiseProfile.load("SonyA7S2")
    profile = base.with_effect("LowFreq", {"grid": [6, 10], "k": [1.0], "sigma_dn": [2.0], "frame_h": 360, "frame_w": 960})
    aug = RawNoiseAugment(profile, model="G", ratio=1.0, fixed={"k": 1.0})
    for shape, grid in [((360, 960), (6, 10)), ((64, 64), (1, 1)), ((120, 480), (2, 5)), ((720, 1920), (12, 20))]:
        p = aug.sample_parameters(aug.draw_parameters(2, "cpu", seed=1, shape=shape))
        assert (p["lowfreq_gh"][0].item(), p["lowfreq_gw"][0].item()) == grid
    # without a frame size the grid spans whatever it synthesizes (profiles of earlier versions)
    old = base.with_effect("LowFreq", {"grid": [6, 10], "k": [1.0], "sigma_dn": [2.0]})
    p = RawNoiseAugment(old, model="G").sample_parameters(RawNoiseAugment(old, model="G").draw_parameters(1, "cpu", seed=1, shape=(64, 64)))
    assert (p["lowfreq_gh"][0].item(), p["lowfreq_gw"][0].item()) == (6, 10)


def test_frame_size_is_validated():
    with pytest.raises(ValueError, match="frame_h must be a whole number"):
        shading_profile(frame=(0, 10))
    with pytest.raises(ValueError, match="frame_w must be a whole number"):
        NoiseProfile.load("SonyA7S2").with_effect("LowFreq", {"grid": [2, 2], "k": [1.0], "sigma_dn": [1.0], "frame_h": 10,
                                                               "frame_w": 2.5})
