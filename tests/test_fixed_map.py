"""FixedMap, the measured fixed map: a fixed pattern no physical effect explains, reproduced as
measured (its stage on the kernels' grids table, its estimator by split-half cross validation)."""
import numpy as np
import pytest

from rawaug.effects import fixed_map
from rawaug.effects.dark_shading import upsample_grid

from test_effects_loop import BASE, K, synth

SIZE = 96  # packed pixels a side


def rings(h, w, amplitude=0.7, period=48.0, phase=0.0):
    """(4, h, w) a fixed pattern of rings about the frame's centre, r in sensor pixels (DN)."""
    y, x = np.mgrid[0:2 * h, 0:2 * w]
    raw = amplitude * np.cos(2.0 * np.pi * np.hypot(y - h + 0.5, x - w + 0.5) / period + phase)
    return np.stack([raw[0::2, 0::2], raw[0::2, 1::2], raw[1::2, 1::2], raw[1::2, 0::2]])


def test_a_ring_pattern_is_reproduced_as_measured():
    """Rings of 0.7 DN (period 24 packed pixels) over 2 DN of read noise, 8 frames, 5 sessions:
    the map's correlation with the rings above 0.95 and its rms error under 0.15 DN in 5 of 5
    (measured: 0.98, 0.09 DN); the stage adds the map it holds."""
    truth = rings(SIZE, SIZE).mean(axis=0)
    base = [synth({}, batch=8, size=SIZE, sigma_g=2.0, seed=100 + i) for i in range(4)]
    for session in range(5):
        measured = synth({}, batch=8, size=SIZE, sigma_g=2.0, seed=10 + session) + rings(SIZE, SIZE)
        est = fixed_map.combine([fixed_map.estimate(measured, base, K, kind="bias")])
        up = upsample_grid(np.asarray(est["map_dn"][0]), SIZE, SIZE)
        assert np.corrcoef(up.ravel(), truth.ravel())[0, 1] > 0.95, est["map_dn"]
        assert np.sqrt(np.mean((up - (truth - truth.mean())) ** 2)) < 0.15
    params = {key: value for key, value in est.items() if key != "_seen"}
    out = synth({"FixedMap": params}, batch=2, size=SIZE, sigma_g=0.0)
    assert np.allclose(out - synth({}, batch=2, size=SIZE, sigma_g=0.0), up[None, None], atol=1e-3)


def test_no_map_is_measured_where_there_is_none():
    """White frames (2 DN, 8 frames, 20 stacks): no cell predicts one half from the other 2 %
    better than no map in 20 of 20 (measured: the best cell within 0.1 % of no map)."""
    base = [synth({}, batch=8, size=SIZE, sigma_g=2.0, seed=200 + i) for i in range(4)]
    empty = [fixed_map.empty(fixed_map.combine([fixed_map.estimate(synth({}, batch=8, size=SIZE, sigma_g=2.0, seed=300 + s), base, K,
                                                                   kind="bias")])) for s in range(20)]
    assert sum(empty) == 20, empty


def test_a_smaller_input_is_a_window_of_the_measured_frame():
    grid = np.arange(12.0).reshape(3, 4)
    params = {"k": [K], "map_dn": [grid.tolist()], "frame_h": 60, "frame_w": 80}
    out = synth({"FixedMap": params}, batch=6, size=20, sigma_g=0.0) - synth({}, batch=6, size=20, sigma_g=0.0)
    full = upsample_grid(grid, 60, 80)
    for b in range(6):
        window = out[b, 0]
        hits = [(oy, ox) for oy in range(41) for ox in range(61) if np.allclose(full[oy:oy + 20, ox:ox + 20], window, atol=1e-4)]
        assert hits, b  # each sample a window of the frame's map, at an offset of its own


@pytest.mark.parametrize("params, match", [
    ({"k": [K], "map_dn": [[[0.0, 1.0]]]}, "frame_h"),
    ({"k": [K], "map_dn": [np.zeros((80, 80)).tolist()], "frame_h": 96, "frame_w": 96}, "4096 nodes"),
    ({"k": [K, 3.0], "map_dn": [[[0.0]], [[0.0, 1.0]]], "frame_h": 9, "frame_w": 9}, "same shape"),
    ({"k": [K], "map_dn": [[[float("nan")]]], "frame_h": 9, "frame_w": 9}, "finite"),
])
def test_bad_entries_are_refused(params, match):
    with pytest.raises(ValueError, match=match):
        BASE.with_effect("FixedMap", params)
