"""RowMap: row noise of its own level per row block, drawn and estimated."""
from __future__ import annotations

import math

import numpy as np

from rawaug.effects import row_map
from rawaug.statistics import row_noise_blocks, row_noise_spread
from test_effects_loop import K, synth

RAMP = [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5]  # extra row noise per row block, DN
ROW = {"sigma_g": 2.0, "model": "G+R", "sigma_r": 0.5}


def test_row_map_draws_its_blocks_row_noise():
    f = synth({"RowMap": {"k": [K], "row_block_dn": [RAMP], "frame_h": 64}}, batch=64, size=64, sigma_g=0.01)
    v = row_noise_blocks(f)  # 64 frames x 16 sensor rows a block: a variance within ~4.5 % (1 sd); each
    # frame's mean taken out moves every block by ~ the mean variance / 128 sensor rows (0.04 DN^2)
    assert np.allclose(v, np.square(RAMP), rtol=4 * math.sqrt(2 / (63 * 16)), atol=0.1), v
    assert row_noise_spread(synth({}, batch=64, size=64, sigma_g=0.01, **{"sigma_r": 0.5, "model": "G+R"})) < 0.2


def test_row_map_is_estimated_and_absent_without_it():
    """6 stacks of 8 frames (16 sensor rows a block): the blocks' extra variance pooled within 4
    sd of the ramp's (each block's variance ~13 % sd a stack); 10 stacks without it: all blocks
    0 in at least 9 (F-test at p 1e-3 per stack)."""
    record = {"k": [K], "row_block_dn": [RAMP], "frame_h": 64}
    base = [synth({}, batch=8, size=64, seed=s, **ROW) for s in range(1, 6)]
    est = [row_map.estimate(synth({"RowMap": record}, batch=8, size=64, seed=20 + s, **ROW), base, K) for s in range(6)]
    out = np.square(row_map.combine(est)["row_block_dn"][0])
    truth = np.square(RAMP)
    total = truth + 0.25 + 4.0 / 128  # each block's row-mean variance: the ramp, the row noise, the read noise / 128 pixels
    assert np.all(np.abs(out - truth) < 4 * total * math.sqrt(2 / (7 * 16 * 6)) + 0.1), (out, truth)
    null = [row_map.estimate(synth({}, batch=8, size=64, seed=40 + s, **ROW), base, K)["row_block_dn"][0] for s in range(10)]
    assert sum(any(v > 0 for v in n) for n in null) <= 1, null
