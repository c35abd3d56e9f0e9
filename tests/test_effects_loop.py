"""The loop's effects: synthesis statistics (bounds from the sample size), estimation
round trips and parameter validation."""
import math
from types import SimpleNamespace

import numpy as np
from scipy import stats
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment, statistics
from rawaug.effects import (tap_gain, amp_glow, banding, black_clip, column_banding, column_gain, row_gain, column_noise, column_telegraph, row_telegraph, dark_columns, dark_rows, dark_hot_pixels, dark_telegraph, dark_offset, frame_gain, frame_noise, impulses, noisy_pixels, noisy_columns, diagonal_banding, crosstalk, read_map, row_channel, tap_black, row_pattern, shared_pixel, telegraph, dead_pixels, row_drift, column_drift, dark_shading, defect_lines, frame_black_level,
                            gain_nonlinearity, hot_pixels, low_frequency, prnu)
from rawaug.engine.layout import COLUMN_SET, ROW_SET, XTALK_LAGS
from rawaug.statistics import (channel_linearity, defect_lines as defect_line_fraction, repaired, sensor_col_means, sensor_row_means, stuck_fraction, stuck_pixels, tail_mass, temporal_mosaic,
                               without_stuck)

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0


def synth(effects, batch=8, size=64, level_dn=0.0, model="G", seed=0, sigma_g=1.0, exposure_s=0.0, **fixed):
    """A stack of ``batch`` frames of one camera (sensor instance 0: one set of fixed patterns), DN;
    ``fixed``: more fixed parameters (e.g. ``sigma_r``: one camera's, not drawn per frame)."""
    prof = BASE
    for token, params in effects.items():
        prof = prof.with_effect(token, params)
    aug = RawNoiseAugment(prof, model=model, ratio=1.0, fixed={"k": K, "sigma_g": sigma_g, "exposure_s": exposure_s, "sensor": 0, **fixed},
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    x = torch.full((batch, 4, size, size), level_dn / prof.span_dn, dtype=torch.float64)
    return (aug(x) * prof.span_dn).numpy()


def test_column_noise_variance_and_sharing():
    f = synth({"Col": {"seed": 1, "k": [K], "sigma_dn": [2.0], "fixed_dn": [0.0]}}, batch=16, size=64)
    cols = f.mean(axis=2)  # (B, 4, w)
    # R and G2 (0, 3) share sensor columns: their column offsets are identical up to read noise / sqrt(h)
    assert np.corrcoef(cols[:, 0].ravel(), cols[:, 3].ravel())[0, 1] > 0.9
    assert abs(np.corrcoef(cols[:, 0].ravel(), cols[:, 1].ravel())[0, 1]) < 5 / math.sqrt(cols[:, 0].size)
    var = cols.var(axis=2, ddof=1).mean() - 1.0 / 64  # minus read noise / h
    n = 16 * 4 * 64
    assert abs(var - 4.0) < 5 * 4.0 * math.sqrt(2 / n) * 2  # chi-square spread, channels pairwise shared


def test_column_noise_wanders_over_a_sequence_and_rho_is_estimated():
    # a sequence of 32 frames (the loop's synthesis of a stack): the column offsets' lag-1
    # correlation is rho 0.8 and their variance sigma^2, within 5 sd (2 x 64 x 31 pairs, an
    # AR(1)'s correlation sd ~ sqrt((1 - rho^2) / pairs)); independent shots (no sequence): 0
    col = {"seed": 3, "k": [K], "sigma_dn": [2.0], "fixed_dn": [0.0], "rho": [0.8]}
    for sequence, rho in ((1, 0.8), (0, 0.0)):
        f = synth({"Col": col}, batch=32, size=64, sigma_g=0.1, sequence=sequence)
        c = f[:, [0, 3]].mean(axis=2)  # (32, 2, 64): R and G2 share sensor columns
        c = c - c.mean(axis=2, keepdims=True)
        lag1 = float(np.sum(c[1:] * c[:-1]) / np.sum(c[:-1] ** 2))
        assert abs(lag1 - rho) < 5 * math.sqrt((1 - rho**2) / (2 * 64 * 31)) + 0.05, (sequence, lag1)  # + the mean's bias
        assert abs(float(np.mean(c**2)) / 4.0 - 1.0) < 0.35, float(np.mean(c**2))  # 64 columns x ~4 independent stretches
    # estimated from stacks of 8 frames of 256 sensor columns: rho found in 8 of 8 sessions, their
    # mean within 5 sd of 0.8 (one session's sd measured 0.075 over 12); columns new in every
    # frame: no rho in 20 of 20 (kept at 4 standard errors over 8 groups of columns)
    base = [synth({}, batch=8, size=128, seed=s, sigma_g=1.0, sequence=1) for s in range(1, 5)]
    rhos = [column_noise.estimate(synth({"Col": col}, batch=8, size=128, seed=40 + s, sigma_g=1.0, sequence=1), base, K)
            .get("rho", [0.0])[0] for s in range(8)]
    assert min(rhos) > 0 and abs(np.mean(rhos) - 0.8) < 5 * 0.075 / math.sqrt(8), rhos
    white = dict(col, rho=[0.0])
    found = [column_noise.estimate(synth({"Col": white}, batch=8, size=128, seed=60 + s, sigma_g=1.0, sequence=1), base, K)
             for s in range(20)]
    assert sum("rho" in e for e in found) == 0, [e.get("rho") for e in found]
    merged = column_noise.combine([found[0], {**found[1], "k": [3.0], "rho": [0.7]}])
    assert merged["rho"] == [0.0, 0.7] and merged["k"] == [K, 3.0], merged
    with pytest.raises(ValueError, match="rho must be in"):
        BASE.with_effect("Col", dict(col, rho=[1.0]))


def test_column_noise_estimate_round_trip():
    truth = {"seed": 3, "k": [K], "sigma_dn": [0.5], "fixed_dn": [1.0]}
    meas = synth({"Col": truth}, batch=8, size=128)
    base = [synth({}, batch=8, size=128, seed=s) for s in range(1, 5)]
    est = column_noise.estimate(meas, base, K)
    # fixed part: 2 x 128 column values -> relative std of a variance ~ sqrt(2/256)
    assert abs(est["fixed_dn"][0] - 1.0) < 0.35
    assert abs(est["sigma_dn"][0] - 0.5) < 0.1


def test_dark_shading_pattern_is_fixed_and_grid_recovered():
    grid = [[0.0, 2.0], [4.0, 6.0]]
    p = {"seed": 5, "k": [K], "sigma_dn": [1.5], "shading_dn": [grid]}
    a, b = synth({"FPN": p}, seed=1, sigma_g=0.5), synth({"FPN": p}, seed=2, sigma_g=0.5)
    fixed_a, fixed_b = a.mean(axis=0), b.mean(axis=0)
    assert np.corrcoef(fixed_a.ravel(), fixed_b.ravel())[0, 1] > 0.95  # same pattern in every call
    est = dark_shading.estimate(a, [synth({}, seed=s, sigma_g=0.5) for s in (3, 4)], K)
    up_true = dark_shading.upsample_grid(np.array(grid) - np.mean(grid), 64, 64)
    up_est = dark_shading.upsample_grid(np.array(est["shading_dn"][0]), 64, 64)
    # The fit is a projection P = U pinv(U) per axis: its bias is (P_y T P_x - T) for the true
    # map T (an 8x8 grid cannot hold a 2x2 one exactly), its noise at (y, x) has variance
    # s^2 P_y[y, y] P_x[x, x], s^2 the per-pixel variance of the 4-channel, 8-frame mean map.
    u = dark_shading._upsampling_matrix(64, dark_shading._grid_shape(64, 64)[0])
    proj = u @ np.linalg.pinv(u)
    bias = proj @ up_true @ proj.T - up_true
    sd = math.sqrt((1.5**2 + 0.5**2 / 8) / 4) * np.sqrt(np.outer(np.diag(proj), np.diag(proj)))
    assert (np.abs(up_est - up_true) <= np.abs(bias) + 5 * sd).all()
    assert abs(est["sigma_dn"][0] - 1.5) < 0.15


def test_fpn_shading_leaves_out_a_field_new_in_every_frame():
    # A per-frame smooth field (LowFreq, 2x2 grid, 3 DN) leaves 1/8 of its power in the mean
    # of 8 frames; fixed_shading_grid shrinks that away, a fixed shading it keeps. Measured over
    # seeds 200-219: rms ratio (fixed / raw grid) 0.28 on average for the field (max 0.87: a
    # 2x2 field has few modes), >= 0.9996 for the fixed shading.
    field = {"grid": [2, 2], "k": [K], "sigma_dn": [3.0]}
    shading = {"seed": 5, "k": [K], "sigma_dn": [0.0], "shading_dn": [[[0.0, 2.0], [4.0, 6.0]]]}
    ratios = {"field": [], "fixed": []}
    for seed in range(10):
        for name, token, params in (("field", "LowFreq", field), ("fixed", "FPN", shading)):
            meas = synth({token: params}, batch=8, size=64, seed=200 + seed)
            rms = lambda g: float(np.sqrt(np.mean(np.square(g))))  # noqa: E731
            ratios[name].append(rms(dark_shading.fixed_shading_grid(meas)) / rms(dark_shading.shading_grid(meas)))
    assert np.mean(ratios["field"]) < 0.5
    assert min(ratios["fixed"]) > 0.99


@pytest.mark.parametrize("grid", [[2, 2], [8, 8]])
def test_low_frequency_estimate_finds_the_field_scale(grid):
    # The grid (cells of 16 px up to 2 across) is chosen by the excess spectrum: right in 20 of
    # 20 seeds for each grid. sigma: a variance from n = 8 frames x gh x gw normals has relative
    # std sqrt(2 / n), so sigma's is about sqrt(1 / (2 n)); the mean of 8 estimates lies within
    # 4 of its standard errors (plus the 10 % bias measured at 2x2: 2.13 over 20 seeds).
    truth = 2.0
    n = 8 * grid[0] * grid[1]
    sigmas = []
    for seed in range(8):
        meas = synth({"LowFreq": {"grid": grid, "k": [K], "sigma_dn": [truth]}}, batch=8, size=128, seed=100 + seed)
        base = [synth({}, batch=8, size=128, seed=1000 + 10 * seed + s) for s in range(4)]
        est = low_frequency.estimate(meas, base, K)
        assert est["grid"] == grid
        sigmas.append(est["sigma_dn"][0])
    se = truth * math.sqrt(1 / (2 * n)) / math.sqrt(len(sigmas))
    assert abs(np.mean(sigmas) - truth) < 4 * se + 0.1 * truth


GLOW_GRID = np.outer([0.0, 0.5, 1.0, 3.0], [0.0, 1.0, 2.0, 4.0, 8.0])  # e-/s, a corner glow on a 4 x 5 grid, far field 0


def test_amp_glow_estimate_round_trip_and_far_field():
    # The glow's electrons at 4 s (up to 96 e-) over the dark stack of a model without it; the
    # grid is fitted at glow_grid_shape (16 x 16 on 64 x 64) and compared upsampled, within
    # the grid's projection bias and 5 sd of noise (Poisson + read, mean of 8 frames and 4 channels)
    glow = {"k": [K], "rate_e_per_s": [GLOW_GRID.tolist()]}
    t = 4.0
    meas = synth({"Glow": glow}, model="G+P*", seed=1, exposure_s=t)
    base = [synth({}, model="G+P*", seed=s, exposure_s=t) for s in (2, 3)]
    est = amp_glow.estimate(meas, base, K, exposure_s=t)
    shape = amp_glow.glow_grid_shape(64, 64)
    assert np.asarray(est["rate_e_per_s"][0]).shape == shape == (16, 16)
    true = dark_shading.upsample_grid(GLOW_GRID, 64, 64)
    up = dark_shading.upsample_grid(np.asarray(est["rate_e_per_s"][0]), 64, 64)
    u = dark_shading._upsampling_matrix(64, 16)
    proj = u @ np.linalg.pinv(u)
    bias = np.abs(proj @ true @ proj.T - true)
    sd = np.sqrt((K * t * true + 1.0) / 32) / (K * t) * np.sqrt(np.outer(np.diag(proj), np.diag(proj)))
    far = abs(float(np.min(up)))  # the far field the estimate takes for Dark's (its minimum, with noise)
    assert (np.abs(up - true) <= bias + 5 * sd + far).all(), np.abs(up - true).max()
    assert far < 5 * sd.max()
    # a dark signal the model lacks, uniform (Dark: 3 e-/s), is left to Dark: the glow grid
    # is the part above the far field, the same as without it
    dark = {"seed": 21, "k": [K], "rate_e_per_s": [3.0], "dsnu": [0.0]}
    with_dark = amp_glow.estimate(synth({"Glow": glow, "Dark": dark}, model="G+P*", seed=1, exposure_s=t), base, K,
                                  exposure_s=t)
    up_dark = dark_shading.upsample_grid(np.asarray(with_dark["rate_e_per_s"][0]), 64, 64)
    assert np.abs(up_dark - true).max() <= (bias + 5 * sd).max() + far + 5 * math.sqrt(3.0 * t / (32 * 64 * 64)) / t
    # a model that holds the uniform part in excess (Dark fitted to the mean, glow included):
    # the grid keeps its zero mean, so the mean is not counted twice
    mean_rate = float(true.mean())
    dark_all = dict(dark, rate_e_per_s=[3.0 + mean_rate])
    over = [synth({"Dark": dark_all}, model="G+P*", seed=s, exposure_s=t) for s in (2, 3)]
    zero_mean = amp_glow.estimate(synth({"Glow": glow, "Dark": dark}, model="G+P*", seed=1, exposure_s=t), over, K,
                                  exposure_s=t)
    mean_sd = math.sqrt(2 * (K * t * (3.0 + mean_rate) + 1.0) / meas.size) / (K * t)  # two stack means' noise
    assert abs(np.mean(zero_mean["rate_e_per_s"][0])) < 5 * mean_sd < 0.01 * mean_rate
    # no glow: a grid of noise only (a cell: 4 x 4 pixels, 4 channels, 8 frames of 1 DN read noise)
    none = amp_glow.estimate(synth({}, model="G+P*", seed=1, exposure_s=t), base, K, exposure_s=t)
    assert np.abs(np.asarray(none["rate_e_per_s"][0])).max() < 5 / math.sqrt(16 * 4 * 8) / (K * t)
    with pytest.raises(ValueError, match="exposure_s"):
        amp_glow.estimate(meas, base, K, exposure_s=None)


def test_amp_glow_grid_is_as_fine_as_the_dark_frames_support():
    # a dark rate that varies over a few pixels (a 64 x 64 grid smoothed over 2 of its cells, on
    # 128 x 128 packed pixels) gets the finest grid, cells of 4 pixels, in 3 of 3 stacks of 4
    # frames; no glow at all gets one of the two coarsest (4 x 4 or 5 x 5) in 10 of 10: the grid
    # that predicts the odd frames from the even ones best (``split_half_errors``)
    from scipy.ndimage import gaussian_filter

    t = 4.0
    z = gaussian_filter(np.random.default_rng(5).standard_normal((64, 64)), 2.0, mode="wrap")
    glow = {"k": [K], "rate_e_per_s": [(2.0 * np.exp(0.6 * z / z.std())).tolist()]}
    base = [synth({}, model="G+P*", seed=s, exposure_s=t, size=128, batch=4) for s in (2, 3)]
    assert amp_glow.glow_grid_shapes(128, 128)[0] == (32, 32)
    for s in range(3):
        est = amp_glow.estimate(synth({"Glow": glow}, model="G+P*", seed=10 + s, exposure_s=t, size=128, batch=4), base, K,
                                exposure_s=t)
        assert np.asarray(est["rate_e_per_s"][0]).shape == (32, 32), np.asarray(est["rate_e_per_s"][0]).shape
    for s in range(10):
        est = amp_glow.estimate(synth({}, model="G+P*", seed=30 + s, exposure_s=t, size=128, batch=4), base, K, exposure_s=t)
        assert np.asarray(est["rate_e_per_s"][0]).shape in ((4, 4), (5, 5)), np.asarray(est["rate_e_per_s"][0]).shape
    # combine takes the grid whose split-half errors summed over the stacks are least
    one = {"k": [K], "exposure_s": [t], "frame_h": 8, "frame_w": 8, "split_half_error": {(2, 2): 1.0, (1, 1): 2.0},
           "grids": {(2, 2): [[1.0, 1.0], [1.0, 1.0]], (1, 1): [[5.0]]}, "rate_e_per_s": [[[1.0, 1.0], [1.0, 1.0]]]}
    two = {**one, "split_half_error": {(2, 2): 3.0, (1, 1): 1.5}}
    assert np.asarray(amp_glow.combine([one, two])["rate_e_per_s"][0]).shape == (1, 1)


def test_amp_glow_combine_fits_the_rate_through_the_origin():
    # grids at 1 s and 4 s, weighted by t^2: (1 * 1 * a + 16 * b) / 17
    a, b = np.full((2, 2), 2.0), np.full((2, 2), 3.0)
    rec = amp_glow.combine([{"k": [K], "rate_e_per_s": [a.tolist()], "exposure_s": [1.0], "frame_h": 8, "frame_w": 8},
                            {"k": [K], "rate_e_per_s": [b.tolist()], "exposure_s": [4.0], "frame_h": 8, "frame_w": 8},
                            {"k": [3.0], "rate_e_per_s": [a.tolist()], "exposure_s": [2.0], "frame_h": 8, "frame_w": 8}])
    assert rec["k"] == [K, 3.0]
    assert np.allclose(rec["rate_e_per_s"][0], (2.0 + 16 * 3.0) / 17) and np.allclose(rec["rate_e_per_s"][1], 2.0)
    NoiseProfile.load("SonyA7S2").with_effect("Glow", rec)  # a valid profile entry


def test_fpn_reads_its_grid_from_a_table_padded_for_a_larger_glow_grid():
    # FPN's 2 x 2 grid beside Glow's 4 x 5 in one table: at exposure 0 the glow adds nothing,
    # so the output is FPN's alone, bit for bit
    fpn = {"seed": 5, "k": [K], "sigma_dn": [1.0], "shading_dn": [[[0.0, 2.0], [4.0, 6.0]]]}
    glow = {"k": [K], "rate_e_per_s": [GLOW_GRID.tolist()]}
    alone = synth({"FPN": fpn}, seed=4)
    beside = synth({"Glow": glow, "FPN": fpn}, seed=4)
    assert np.array_equal(alone, beside)
    assert not np.array_equal(beside, synth({"Glow": glow, "FPN": fpn}, seed=4, exposure_s=1.0))


def test_hot_tiles_are_drawn_whole_and_estimated():
    """Hot 2x2 tiles (a shared readout's defect) beside isolated hot pixels, over 6 sensor
    instances: the tiles' and the pixels' densities within 5 Poisson sd; isolated hot pixels
    alone (3e-3) make no tile in 10 of 10 stacks."""
    p = {"seed": 7, "density": 1e-3, "log_std": 0.2, "k": [K], "median_dn": [80.0], "tile_density": 1e-3}
    est = [hot_pixels.estimate(synth({"Hot": p}, batch=4, size=128, sensor=s), [], K) for s in range(6)]
    tiles, pixels = 6 * 128 * 128, 6 * 4 * 128 * 128
    assert abs(sum(e["tile_density"] for e in est) / 6 - 1e-3) < 5 * math.sqrt(1e-3 / tiles), est
    assert abs(sum(e["density"] for e in est) / 6 - 1e-3) < 5 * math.sqrt(1e-3 / pixels), est
    f = synth({"Hot": p}, batch=4, size=128)
    whole = hot_pixels.hot_tiles(hot_pixels.detect(f)[0])
    assert np.all(hot_pixels.detect(f)[0][:, whole].sum(axis=0) == 4)  # one amplitude, 80 DN: all four seen
    alone = [hot_pixels.estimate(synth({"Hot": {**p, "seed": 30 + s, "density": 3e-3, "tile_density": 0.0}}, batch=4, size=128), [], K)
             for s in range(10)]
    assert not any("tile_density" in e for e in alone) and all(e["density"] > 2e-3 for e in alone), alone


def test_hot_pixels_density_and_estimate():
    p = {"seed": 7, "density": 2e-3, "log_std": 0.2, "k": [K], "median_dn": [80.0]}
    f = synth({"Hot": p}, batch=4, size=128)
    n = 4 * 128 * 128
    hot, amp = hot_pixels.detect(f)
    assert abs(hot.sum() - 2e-3 * n) < 5 * math.sqrt(2e-3 * n)
    est = hot_pixels.estimate(f, [synth({}, batch=4, size=128, seed=9)], K)
    assert abs(est["density"] - 2e-3) < 5 * math.sqrt(2e-3 / n)
    assert abs(math.log(est["median_dn"][0] / 80.0)) < 0.1
    # a flat's shot noise hides the dimmer ones: bias and dark stacks only
    with pytest.raises(ValueError, match="bias and dark"):
        hot_pixels.estimate(f + 300.0, [f], K, kind="flat")
    # one population over the stacks: the density their mean, one median per gain
    two = hot_pixels.combine([est, {**est, "density": 1e-3, "median_dn": [20.0]}, {**est, "k": [2 * K], "median_dn": [160.0]}])
    assert two["k"] == [K, 2 * K] and two["density"] == pytest.approx((2 * est["density"] + 1e-3) / 3)
    assert two["median_dn"] == pytest.approx([math.sqrt(est["median_dn"][0] * 20.0), 160.0])


DARK_HOT = {"seed": 61, "density": 2e-3, "median_e_per_s": 40.0, "log_std": 0.3}


def test_dark_hot_pixels_grow_with_exposure_and_carry_their_shot_noise():
    n = 4 * 128 * 128
    bias = synth({"DarkHot": DARK_HOT}, batch=4, size=128, model="G+P*", exposure_s=0.0)
    assert not hot_pixels.detect(bias)[0].any()  # no dark electrons without an exposure
    stacks = {t: synth({"DarkHot": DARK_HOT}, batch=16, size=128, model="G+P*", exposure_s=t) for t in (2.0, 8.0)}
    masks = {t: hot_pixels.detect(f)[0].reshape(4, 128, 128) for t, f in stacks.items()}
    hot = masks[2.0]
    m = int(hot.sum())
    assert abs(m - 2e-3 * n) < 5 * math.sqrt(2e-3 * n), m  # binomial count of the seeded positions
    assert np.array_equal(masks[8.0], hot)  # the same pixels at every exposure
    excess = {t: f.mean(axis=0)[hot] - np.median(f.mean(axis=0)) for t, f in stacks.items()}  # DN = electrons (K = 1)
    # linear in exposure: the summed excess of m pixels, Poisson counts of ~80 e- each in 16 frames
    assert abs(excess[8.0].sum() / excess[2.0].sum() - 4.0) < 0.1
    # their electrons' median 40 e-/s, log-normal spread 0.3: the mean log of m pixels within 5 standard errors
    assert abs(np.log(excess[2.0] / 2.0).mean() - math.log(40.0)) < 5 * 0.3 / math.sqrt(m)
    # shot noise: temporal variance less the read noise's (1 DN^2) over the mean excess is K = 1; each pixel's
    # variance of 16 frames has a relative sd sqrt(2 / 15), their mean over m pixels sqrt(2 / 15 / m)
    ratio = float(np.mean((stacks[8.0].var(axis=0, ddof=1)[hot] - 1.0) / excess[8.0]))
    assert abs(ratio - 1.0) < 5 * math.sqrt(2 / 15 / m), ratio


def test_dark_hot_pixels_estimate_round_trip_and_none_in_white_dark_stacks():
    n = 4 * 128 * 128
    dark = {"model": "G+P*", "sigma_g": 2.0, "exposure_s": 4.0}
    meas = synth({"DarkHot": DARK_HOT}, batch=6, size=128, **dark)
    base = [synth({}, batch=6, size=128, seed=s, **dark) for s in range(1, 5)]
    est = dark_hot_pixels.estimate(meas, base, K, exposure_s=4.0, kind="dark")
    assert abs(est["density"] - 2e-3) < 5 * math.sqrt(2e-3 / n), est
    m = 2e-3 * n
    assert abs(math.log(est["median_e_per_s"] / 40.0)) < 5 * 0.3 / math.sqrt(m), est
    assert abs(est["log_std"] - 0.3) < 0.1, est  # plus the shot noise of 160 e-: ~0.08 in log
    # white dark stacks: 8 robust sigma above the median is out of reach of read and shot noise
    white = [dark_hot_pixels.estimate(synth({}, batch=6, size=128, seed=s, **dark), base, K, exposure_s=4.0, kind="dark")
             for s in range(20, 30)]
    assert all(w["density"] == 0.0 for w in white), white
    with pytest.raises(ValueError, match="dark stacks"):
        dark_hot_pixels.estimate(meas, base, K, exposure_s=None, kind="bias")


DARK_COL = {"seed": 71, "density": 0.03, "median_e_per_s": 15.0, "log_std": 0.3}


def test_leaky_columns_grow_with_exposure_along_whole_sensor_columns():
    from rawaug.effects.dark_columns import _COL_SETS

    size = 128
    bias = synth({"DarkCol": DARK_COL}, batch=4, size=size, model="G+P*", exposure_s=0.0)
    stacks = {t: synth({"DarkCol": DARK_COL}, batch=16, size=size, model="G+P*", exposure_s=t) for t in (2.0, 8.0)}
    assert dark_columns.bright_columns(bias)[0] == 0.0  # no dark electrons without an exposure
    # sensor column means (DN = electrons at K = 1), each of two packed channels' column means
    cols = {t: np.concatenate([f.mean(axis=(0, 2))[list(c)].mean(axis=0) for c in _COL_SETS]) for t, f in stacks.items()}
    leaky = {t: c - np.median(c) > 5.0 for t, c in cols.items()}
    m = int(leaky[2.0].sum())
    assert abs(m - 0.03 * 2 * size) < 5 * math.sqrt(0.03 * 2 * size), m  # binomial count of the seeded columns
    assert np.array_equal(leaky[8.0], leaky[2.0])  # the same columns at every exposure
    excess = {t: c[leaky[2.0]] - np.median(c) for t, c in cols.items()}
    assert abs(excess[8.0].sum() / excess[2.0].sum() - 4.0) < 0.1  # linear in exposure
    # both packed channels of a leaky sensor column carry it: their column means agree within the noise
    f = stacks[8.0].mean(axis=(0, 2))
    for chans, half in zip(_COL_SETS, np.split(leaky[8.0], 2)):
        a, b = f[chans[0]][half], f[chans[1]][half]
        assert np.all(np.abs(a - b) < 5 * np.sqrt(2 * (1.0 + a) / (16 * size))), (a, b)
    # shot noise: temporal variance less the read noise's (1 DN^2) over the excess is K = 1
    var = np.concatenate([stacks[8.0].var(axis=0, ddof=1).mean(axis=1)[list(c)].mean(axis=0) for c in _COL_SETS])
    ratio = float(np.mean((var[leaky[8.0]] - 1.0) / excess[8.0]))
    assert abs(ratio - 1.0) < 5 * math.sqrt(2 / 15 / (size * 2 * m)), ratio


def test_leaky_columns_estimate_round_trip_and_none_in_white_dark_stacks():
    dark = {"model": "G+P*", "sigma_g": 2.0, "exposure_s": 4.0}
    meas = synth({"DarkCol": DARK_COL}, batch=6, size=128, **dark)
    base = [synth({}, batch=6, size=128, seed=s, **dark) for s in range(1, 5)]
    est = dark_columns.estimate(meas, base, K, exposure_s=4.0, kind="dark")
    m = 0.03 * 256
    assert abs(est["density"] - 0.03) < 5 * math.sqrt(0.03 / 256), est
    assert abs(math.log(est["median_e_per_s"] / 15.0)) < 5 * 0.3 / math.sqrt(m), est
    assert abs(est["log_std"] - 0.3) < 0.15, est
    white = [dark_columns.estimate(synth({}, batch=6, size=128, seed=s, **dark), base, K, exposure_s=4.0, kind="dark")
             for s in range(20, 30)]
    assert all(w["density"] == 0.0 for w in white), white  # 8 robust sigma: out of reach of read and shot noise
    assert dark_columns.empty(white[0]) and not dark_columns.empty(est)
    with pytest.raises(ValueError, match="dark stacks"):
        dark_columns.estimate(meas, base, K, exposure_s=4.0, kind="bias")


DARK_ROW = {"seed": 79, "density": 0.03, "median_e_per_s": 15.0, "log_std": 0.3}


def test_leaky_rows_lie_along_whole_sensor_rows_and_round_trip():
    from rawaug.effects.dark_columns import _ROW_SETS

    dark = {"model": "G+P*", "sigma_g": 2.0, "exposure_s": 4.0}
    meas = synth({"DarkRow": DARK_ROW}, batch=6, size=128, **dark)
    assert dark_rows.bright_rows(synth({"DarkRow": DARK_ROW}, batch=4, size=128, model="G+P*", exposure_s=0.0))[0] == 0.0
    # both packed channels of a leaky sensor row carry it (sensor row means, DN = electrons at K = 1)
    f = meas.mean(axis=(0, 3))
    for chans in _ROW_SETS:
        a, b = f[chans[0]], f[chans[1]]
        leaky = a - np.median(a) > 20.0  # 15 e-/s x 4 s = 60 e- in median
        assert leaky.any() and np.array_equal(leaky, b - np.median(b) > 20.0)
        assert not np.any((meas.mean(axis=(0, 2))[list(chans)] - np.median(meas) > 20.0))  # no leaky column
    base = [synth({}, batch=6, size=128, seed=s, **dark) for s in range(1, 5)]
    est = dark_rows.estimate(meas, base, K, exposure_s=4.0, kind="dark")
    m = 0.03 * 256
    assert abs(est["density"] - 0.03) < 5 * math.sqrt(0.03 / 256), est
    assert abs(math.log(est["median_e_per_s"] / 15.0)) < 5 * 0.3 / math.sqrt(m), est
    assert abs(est["log_std"] - 0.3) < 0.15, est
    white = [dark_rows.estimate(synth({}, batch=6, size=128, seed=s, **dark), base, K, exposure_s=4.0, kind="dark")
             for s in range(20, 30)]
    assert all(w["density"] == 0.0 for w in white), white
    assert dark_rows.empty(white[0]) and not dark_rows.empty(est)
    cols = dark_columns.estimate(meas, base, K, exposure_s=4.0, kind="dark")
    assert cols["density"] == 0.0, cols  # rows are no columns
    with pytest.raises(ValueError, match="dark stacks"):
        dark_rows.estimate(meas, base, K, exposure_s=4.0, kind="bias")


def test_dark_offset_moves_the_black_level_with_exposure_and_adds_no_noise():
    sag = {"k": [K], "dn_per_s": [-0.75]}
    for t in (0.0, 4.0):
        with_sag = synth({"DarkOffset": sag}, batch=4, size=64, model="G+P*", exposure_s=t, seed=3)
        without = synth({}, batch=4, size=64, model="G+P*", exposure_s=t, seed=3)
        assert np.allclose(with_sag - without, -0.75 * t, atol=1e-9)  # the same noise, shifted


def test_dark_offset_estimate_separates_an_offset_from_dark_electrons():
    dark = {"model": "G+P*", "sigma_g": 2.0, "exposure_s": 4.0}
    base = [synth({}, batch=6, size=64, seed=s, **dark) for s in range(1, 5)]
    sag = synth({"DarkOffset": {"k": [K], "dn_per_s": [-0.75]}}, batch=6, size=64, **dark)
    est = dark_offset.combine([dark_offset.estimate(sag, base, K, exposure_s=4.0, kind="dark")])
    # the spread of a (6, 4, 64, 64) stack's temporal variance: 4 DN^2 * sqrt(2 / 5 / 16384); its mean's 2 / sqrt(6 * 16384)
    assert abs(est["dn_per_s"][0] + 0.75) < 5 * (4 * math.sqrt(2 / 5 / 16384) + 2 / math.sqrt(6 * 16384)) / 4.0, est
    # dark current (3 e-/s, K = 1) moves the mean by 12 DN with its shot noise: no offset
    current = synth({"Dark": {"seed": 19, "k": [K], "rate_e_per_s": [3.0], "dsnu": [0.0]}}, batch=6, size=64, **dark)
    est = dark_offset.estimate(current, base, K, exposure_s=4.0, kind="dark")
    assert abs(est["dn_per_s"][0]) < 5 * (4 * math.sqrt(2 / 5 / 16384) + 3.6 / math.sqrt(6 * 16384)) / 4.0, est
    # exposures of 2 and 8 s: one slope through the bias level
    two = dark_offset.combine([{"k": [K], "dn_per_s": [-1.0], "exposure_s": [2.0]}, {"k": [K], "dn_per_s": [-0.5], "exposure_s": [8.0]}])
    assert two["dn_per_s"][0] == pytest.approx((-2.0 * 2 - 4.0 * 8) / (4 + 64))
    with pytest.raises(ValueError, match="dark stacks"):
        dark_offset.estimate(sag, base, K, exposure_s=None, kind="dark")


SPIKES = {"density": 1e-3, "density_per_s": 2e-4, "log_std": 0.4, "k": [K], "median_dn": [60.0]}


def test_spikes_hit_new_pixels_in_every_frame_and_grow_with_exposure():
    from rawaug.statistics import spikes

    n_px = 4 * 96 * 96
    for t, density in ((0.0, 1e-3), (5.0, 2e-3)):
        frames = synth({"Spikes": SPIKES}, batch=12, size=96, model="G", exposure_s=t)
        mask = spikes(frames)
        m = int(mask.sum())
        # binomial count over 12 frames (those below 8 sigma of 1 DN, ~0 of 60 DN spikes, are missed)
        assert abs(m - density * 12 * n_px) < 5 * math.sqrt(density * 12 * n_px), (t, m)
        assert mask.sum(axis=0).max() == 1  # never the same pixel twice in 12 frames (expected 0.4 pixels at most)
        excess = frames[mask] - np.median(frames, axis=0)[mask.any(axis=0)]
        assert abs(np.log(excess).mean() - math.log(60.0)) < 5 * 0.4 / math.sqrt(m)


def test_spikes_estimate_round_trip_and_none_in_white_or_heavy_tailed_stacks():
    from rawaug.statistics import spike_fraction

    n_px = 4 * 128 * 128
    base = [synth({}, batch=6, size=128, seed=s) for s in range(1, 5)]
    meas = synth({"Spikes": {**SPIKES, "density_per_s": 0.0}}, batch=6, size=128)
    est = impulses.estimate(meas, base, K, exposure_s=1e-4, kind="bias")
    assert abs(est["density"] - 1e-3) < 5 * math.sqrt(1e-3 / (6 * n_px)), est
    assert abs(math.log(est["median_dn"][0] / 60.0)) < 5 * 0.4 / math.sqrt(1e-3 * 6 * n_px), est
    assert abs(est["log_std"] - 0.4) < 0.1, est
    # bias at t = 0 and dark at 5 s: a per-frame and a per-second density
    dark = synth({"Spikes": SPIKES}, batch=6, size=128, exposure_s=5.0, seed=9)
    both = impulses.combine([impulses.estimate(synth({"Spikes": SPIKES}, batch=6, size=128, seed=8), base, K, exposure_s=0.0, kind="bias"),
                             impulses.estimate(dark, base, K, exposure_s=5.0, kind="dark")])
    assert abs(both["density"] - 1e-3) < 5 * math.sqrt(1e-3 / (6 * n_px)) and abs(both["density_per_s"] - 2e-4) < 5 * math.sqrt(2e-3 / (6 * n_px)) / 5, both
    # heavy-tailed read noise (Tukey lambda -0.3) makes ~0.2 % bright single-frame extremes and as
    # many dark ones: their difference within 5 sd of a difference of two Poisson counts
    from rawaug.statistics import spikes

    for seed in range(20, 25):
        f = synth({}, batch=6, size=128, seed=seed, model="G*", sigma_tl=1.0, **{"lambda": -0.3})
        n_both = int(spikes(f).sum() + spikes(-f).sum())
        assert n_both > 100 and abs(spike_fraction(f)) * f.size < 5 * math.sqrt(n_both), (seed, n_both, spike_fraction(f))
    white = [impulses.estimate(synth({}, batch=6, size=128, seed=s), base, K, exposure_s=0.0, kind="bias") for s in range(30, 40)]
    assert all(impulses.empty(w) for w in white), white
    with pytest.raises(ValueError, match="bias or dark stacks"):
        impulses.estimate(meas, base, K, kind="flat")


def test_dark_events_take_their_share_and_are_estimated_as_dark():
    """Lost charge packets: ``negative`` 0.3 of the events read low. The stage's dark events are
    within 5 binomial sd of 0.3 of all; a stack of dark events only (``negative`` 1) gives them
    back: share 1, the density within 5 Poisson sd, the median within 5 sd of its log."""
    from rawaug.statistics import spikes

    n_px = 4 * 128 * 128
    frames = synth({"Spikes": {**SPIKES, "density_per_s": 0.0, "negative": 0.3}}, batch=12, size=128, model="G")
    bright, dark = int(spikes(frames).sum()), int(spikes(-frames).sum())
    n = bright + dark
    assert abs(dark - 0.3 * n) < 5 * math.sqrt(0.3 * 0.7 * n), (bright, dark)
    base = [synth({}, batch=6, size=128, seed=s) for s in range(1, 5)]
    meas = synth({"Spikes": {**SPIKES, "density_per_s": 0.0, "negative": 1.0}}, batch=6, size=128, seed=11)
    est = impulses.combine([impulses.estimate(meas, base, K, exposure_s=0.0, kind="bias")])
    assert est["negative"] == 1.0, est
    assert abs(est["density"] - 1e-3) < 5 * math.sqrt(1e-3 / (6 * n_px)), est
    assert abs(math.log(est["median_dn"][0] / 60.0)) < 5 * 0.4 / math.sqrt(1e-3 * 6 * n_px), est


def test_events_of_both_signs_are_estimated_as_both():
    """Bit errors on a data link: events of one size (+-512 DN, log spread 0.05) in both
    directions, half of each. Over 10 bias stacks the estimate takes both sides: the dark
    share within 5 binomial sd of 0.5 and the density within 5 Poisson sd, in every stack;
    10 white stacks give none (the one-sided test, as before, and each side's at 5 sd)."""
    n_px = 4 * 64 * 64
    flips = {"density": 1e-3, "density_per_s": 0.0, "log_std": 0.05, "negative": 0.5, "k": [K], "median_dn": [512.0]}
    base = [synth({}, batch=6, size=64, seed=s) for s in range(1, 5)]
    n = 1e-3 * 6 * n_px
    for seed in range(50, 60):
        est = impulses.estimate(synth({"Spikes": flips}, batch=6, size=64, seed=seed), base, K, exposure_s=0.0, kind="bias")
        assert abs(est["negative"] - 0.5) < 5 * math.sqrt(0.25 / n), est
        assert abs(est["density"] - 1e-3) < 5 * math.sqrt(1e-3 / (6 * n_px)), est
        assert abs(math.log(est["median_dn"][0] / 512.0)) < 0.02, est
    white = [impulses.estimate(synth({}, batch=6, size=64, seed=s), base, K, exposure_s=0.0, kind="bias") for s in range(60, 70)]
    assert all(impulses.empty(w) for w in white), white


def test_far_events_of_both_signs_are_outliers_and_heavy_tails_are_not():
    """``spike_outliers`` on stacks of 8 frames (4 x 96 x 128): +-512 DN events in 1e-4 of
    the values, as many of each sign, are all marked (none of the others) over Gaussian noise
    and over a Tukey lambda -0.14 tail of sd ~4 DN, in 5 stacks each; without them nothing is
    marked in 10 of 10 stacks of either."""
    from scipy import stats

    from rawaug.statistics import spike_outliers

    for seed in range(5):
        rng = np.random.default_rng(seed)
        shape = (8, 4, 96, 128)
        for base in (rng.normal(0.0, 2.0, shape), 2.0 * stats.tukeylambda.rvs(-0.14, size=shape, random_state=seed)):
            assert not spike_outliers(base).any()
            hit = rng.random(shape) < 1e-4
            marked = spike_outliers(base + hit * rng.choice([-512.0, 512.0], shape))
            assert np.array_equal(marked, hit), (int(hit.sum()), int(marked.sum()), int((marked & hit).sum()))
    for seed in range(5, 10):
        rng = np.random.default_rng(seed)
        assert not spike_outliers(rng.normal(0.0, 2.0, (8, 4, 96, 128))).any()
        assert not spike_outliers(2.0 * stats.tukeylambda.rvs(-0.14, size=(8, 4, 96, 128), random_state=seed)).any()


COLRTS = {"seed": 79, "density": 0.05, "high": 0.3, "log_std": 0.2, "k": [K], "median_dn": [6.0]}


def test_telegraph_columns_jump_between_their_level_and_a_step_above():
    from rawaug.statistics import sensor_col_means

    frames = synth({"ColRTS": COLRTS}, batch=40, size=64)
    m = sensor_col_means(frames)  # (40, 128) DN; white noise of 1 DN over 128 pixels: 0.09 DN
    m = m - m.mean(axis=1, keepdims=True)
    jumpy = m.std(axis=0) > 1.0  # a 6 DN step in 30 % of the frames: sd 2.7 DN
    n = int(jumpy.sum())
    assert abs(n - 0.05 * 128) < 5 * math.sqrt(0.05 * 128), n  # binomial count of the seeded columns
    for col in np.flatnonzero(jumpy):
        v = m[:, col]
        high = v > v.min() + 0.5 * (v.max() - v.min())
        assert abs(high.mean() - 0.3) < 5 * math.sqrt(0.3 * 0.7 / 40), high.mean()  # a state per frame
        # the low state is the column's level without the trap: its neighbours' (the frame centring
        # moves both by the others' steps / 128, < 0.1 DN)
        assert abs(v[~high].mean()) < 5 * 0.09 / math.sqrt(40) + 0.1, v[~high].mean()
        assert v[high].std() < 0.3 and v[~high].std() < 0.3  # two levels, the column noise apart


def test_telegraph_columns_estimate_round_trip_and_none_in_white_stacks():
    base = [synth({}, batch=12, size=64, seed=s) for s in range(1, 5)]
    meas = synth({"ColRTS": COLRTS}, batch=12, size=64)
    est = column_telegraph.estimate(meas, base, K, kind="bias")
    n = 0.05 * 128
    assert abs(est["density"] - 0.05) < 5 * math.sqrt(0.05 / 128), est
    assert abs(math.log(est["median_dn"][0] / 6.0)) < 5 * 0.2 / math.sqrt(n), est
    assert abs(est["high"] - 0.3) < 5 * math.sqrt(0.21 / (12 * n)), est
    white = [column_telegraph.estimate(synth({}, batch=12, size=64, seed=s), base, K, kind="bias") for s in range(20, 30)]
    assert all(column_telegraph.empty(w) for w in white), white
    with pytest.raises(ValueError, match="bias or dark stacks"):
        column_telegraph.estimate(meas[:3], base, K, kind="bias")


def test_telegraph_rows_jump_between_two_levels_and_are_estimated():
    from rawaug.statistics import col_flicker_fraction, row_flicker_fraction, sensor_row_means

    frames = synth({"RowRTS": COLRTS}, batch=40, size=64)
    m = sensor_row_means(frames)  # (40, 128) DN; white noise of 1 DN over 128 pixels: 0.09 DN
    m = m - m.mean(axis=1, keepdims=True)
    jumpy = m.std(axis=0) > 1.0  # a 6 DN step in 30 % of the frames: sd 2.7 DN
    assert abs(int(jumpy.sum()) - 0.05 * 128) < 5 * math.sqrt(0.05 * 128), int(jumpy.sum())
    for row in np.flatnonzero(jumpy):
        v = m[:, row]
        high = v > v.min() + 0.5 * (v.max() - v.min())
        assert abs(high.mean() - 0.3) < 5 * math.sqrt(0.3 * 0.7 / 40), high.mean()  # a state per frame
        assert v[high].std() < 0.3 and v[~high].std() < 0.3  # two levels, the row noise apart
    assert col_flicker_fraction(frames) == 0.0 and row_flicker_fraction(frames) > 0.8 * jumpy.mean()
    base = [synth({}, batch=12, size=64, seed=s) for s in range(1, 5)]
    est = row_telegraph.estimate(synth({"RowRTS": COLRTS}, batch=12, size=64, seed=3), base, K, kind="bias")
    n = 0.05 * 128
    assert abs(est["density"] - jumpy.mean()) < 5 * math.sqrt(0.05 / 128), est
    assert abs(math.log(est["median_dn"][0] / 6.0)) < 5 * 0.2 / math.sqrt(n), est
    assert abs(est["high"] - 0.3) < 5 * math.sqrt(0.21 / (12 * n)), est
    white = [row_telegraph.estimate(synth({}, batch=12, size=64, seed=s), base, K, kind="bias") for s in range(20, 30)]
    assert all(row_telegraph.empty(w) for w in white), white
    with pytest.raises(ValueError, match="RowRTS is measured on bias or dark stacks"):
        row_telegraph.estimate(frames[:3], base, K, kind="bias")


def test_frame_noise_scales_each_frame_read_noise_and_keeps_its_mean_variance():
    frames = synth({"FrameNoise": {"k": [K], "log_std": [0.3]}}, batch=200, size=32, model="G", sigma_g=2.0)
    v = frames.reshape(200, -1).var(axis=1)  # 4096 pixels: each variance within 2.2 % of its frame's
    # log variance: 2 x 0.3 spread; the mean variance stays 4 DN^2 (the factor is normalised)
    assert abs(np.log(v).std(ddof=1) - 0.6) < 5 * 0.6 / math.sqrt(2 * 199) + 0.03, np.log(v).std()
    assert abs(v.mean() / 4.0 - 1.0) < 5 * math.sqrt(math.exp(4 * 0.09) - 1) / math.sqrt(200), v.mean()


def test_frame_noise_estimate_round_trip_and_nothing_for_a_steady_read_noise():
    from rawaug.statistics import frame_noise_spread

    base = [synth({}, batch=16, size=64, seed=s) for s in range(1, 9)]
    est = [frame_noise.estimate(synth({"FrameNoise": {"k": [K], "log_std": [0.25]}}, batch=16, size=64, seed=s), base, K, kind="bias")
           for s in range(20, 30)]
    # each from 16 frames: the spread of a std of 16 values is 1 / sqrt(30) of it, ~0.05 here
    got = np.array([e["log_std"][0] for e in est])
    assert abs(got.mean() - 0.25) < 5 * 0.25 / math.sqrt(30 * 10), got
    steady = [frame_noise.estimate(synth({}, batch=16, size=64, seed=s), base, K, kind="bias")["log_std"][0] for s in range(40, 50)]
    assert max(steady) < 0.03, steady  # sqrt(2 / 16384) per frame: a spread of ~0.011
    assert frame_noise_spread(base[0]) < 0.03
    with pytest.raises(ValueError, match="bias and dark stacks"):
        frame_noise.estimate(base[0], base, K, kind="flat")


def test_frame_gain_scales_each_flat_frame_and_leaves_bias_frames_alone():
    from rawaug.statistics import flat_gain_spread

    flats = synth({"FrameGain": {"sigma": 0.01}}, batch=100, size=32, level_dn=1000.0, model="G+P*")
    means = flats.mean(axis=(1, 2, 3)) / 1000.0 - 1.0  # shot noise of a 4096-pixel mean: 0.05 %
    assert abs(means.std(ddof=1) - 0.01) < 5 * 0.01 / math.sqrt(2 * 99) + 0.0005, means.std()
    assert abs(flat_gain_spread(flats, 1000.0) - means.std(ddof=1)) < 1e-12
    bias = [synth({"FrameGain": {"sigma": 0.01}}, batch=4, size=32, seed=3), synth({}, batch=4, size=32, seed=3)]
    assert np.array_equal(bias[0], bias[1])  # no signal: nothing to scale


def test_frame_gain_estimate_pools_flat_pairs():
    base = [synth({}, batch=2, size=32, level_dn=1000.0, model="G+P*", seed=s) for s in range(1, 9)]
    pairs = [synth({"FrameGain": {"sigma": 0.01}}, batch=2, size=32, level_dn=1000.0, model="G+P*", seed=s) for s in range(20, 60)]
    est = frame_gain.combine([frame_gain.estimate(f, base, K, kind="flat", level_dn=1000.0) for f in pairs])
    # 40 pairs: one degree of freedom each, the pooled variance within 5 x sqrt(2 / 40) of itself
    assert abs(est["sigma"] ** 2 / 1e-4 - 1.0) < 5 * math.sqrt(2 / 40), est
    steady = frame_gain.combine([frame_gain.estimate(synth({}, batch=2, size=32, level_dn=1000.0, model="G+P*", seed=s), base, K,
                                                     kind="flat", level_dn=1000.0) for s in range(60, 100)])
    # shot noise alone (0.05 % on a frame mean): the pooled excess variance is 0 within 5 sd,
    # (0.05 %)^2 x 5 x sqrt(2 / 40): sigma below 0.05 % x 1.06
    assert steady["sigma"] < 0.0006, steady
    with pytest.raises(ValueError, match="flat stacks"):
        frame_gain.estimate(pairs[0], base, K, kind="bias")


COLGAIN = {"seed": 67, "sigma": 0.005}


def test_column_gain_scales_the_signal_per_sensor_column_and_leaves_bias_frames_alone():
    level = 2000.0
    assert np.array_equal(synth({"ColGain": COLGAIN}, batch=2, model="G+P*"), synth({}, batch=2, model="G+P*"))  # no signal
    f = synth({"ColGain": COLGAIN}, batch=8, size=128, level_dn=level, model="G+P*")
    cols = f.mean(axis=(0, 2)) / level - 1.0  # (4, w) relative column means
    # the two channels of a sensor column share its gain: R with G2, G1 with B (shot noise ~5e-4 per column mean)
    assert np.corrcoef(cols[0], cols[3])[0, 1] > 0.9 and np.corrcoef(cols[1], cols[2])[0, 1] > 0.9
    assert abs(np.corrcoef(cols[0], cols[1])[0, 1]) < 5 / math.sqrt(128)
    # 2 x 128 independent column gains: the std of a std of n normals is ~1 / sqrt(2 n)
    spread = math.sqrt(float(np.mean(cols**2)) - 1.0 / (level * 8 * 128))  # less the shot noise of a column mean
    assert abs(spread / 0.005 - 1.0) < 5 / math.sqrt(2 * 256), spread


def test_column_gain_estimate_round_trip_and_white_flats_get_almost_none():
    level = 2000.0
    flat = {"model": "G+P*", "level_dn": level}
    meas = synth({"ColGain": COLGAIN}, batch=8, size=128, **flat)
    base = [synth({}, batch=8, size=128, seed=s, **flat) for s in range(1, 5)]
    est = column_gain.estimate(meas, base, K, level_dn=level)
    # a robust variance of 127 column differences per channel, two independent patterns: ~10 % in sigma
    assert abs(est["sigma"] / 0.005 - 1.0) < 0.3, est
    # white flats: the excess is chance, of the order of the shot noise a column mean keeps (~5e-4)
    white = [column_gain.estimate(synth({}, batch=8, size=128, seed=s, **flat), base, K, level_dn=level)["sigma"] for s in range(20, 30)]
    assert max(white) < 0.001, white
    with pytest.raises(ValueError, match="flat stack"):
        column_gain.estimate(meas, base, K)


def test_column_gain_per_frame_is_found_apart_from_the_fixed_part():
    """Flats of 8 frames whose columns' gains move 0.5 % per frame (no fixed part): the per-frame
    part within 25 % and the fixed part under 0.2 % in 10 of 10 sessions (a robust variance of
    127 column differences x 8 frames per channel: ~5 % in sigma); a fixed 0.5 % alone: the
    per-frame part under 0.1 % in 10 of 10 (what the shot noise leaves, ~2e-4)."""
    level = 2000.0
    flat = {"model": "G+P*", "level_dn": level}
    base = [synth({}, batch=8, size=128, seed=s, **flat) for s in range(1, 5)]
    for session in range(10):
        est = column_gain.estimate(synth({"ColGain": {"seed": 67, "sigma": 0.0, "frame": 0.005}}, batch=8, size=128,
                                         seed=40 + session, **flat), base, K, level_dn=level)
        assert abs(est["frame"] / 0.005 - 1.0) < 0.25 and est["sigma"] < 0.002, est
        est = column_gain.estimate(synth({"ColGain": COLGAIN}, batch=8, size=128, seed=60 + session, **flat), base, K,
                                   level_dn=level)
        assert est["frame"] < 0.001, est



def test_column_gain_per_gain_is_estimated_and_synthesized_per_gain():
    """Column amplifiers mismatched at the high gain only (K 3: 0.8 %; K 0.75: none): the spread
    at each gain within 30 % (K 3) and under 0.1 % (K 0.75) in 5 of 5 sessions (before, one spread
    pooled over both; the loop rejected it for the gain that has none), and the profile's record
    at each K is the one a frame of that K gets (the same seeded pattern, scaled)."""
    level = 2000.0
    per_k = {"seed": 67, "k": [0.75, 3.0], "sigma": [0.0, 0.008]}
    flat = {"model": "G+P*", "level_dn": level, "batch": 8, "size": 128}
    for session in range(5):
        records = []
        for k in (0.75, 3.0):
            base = [synth({}, seed=s, k=k, **flat) for s in (1, 2, 3)]
            meas = synth({"ColGain": per_k}, seed=80 + 10 * session, k=k, **flat)
            records.append(column_gain.estimate(meas, base, k, level_dn=level))
        got = column_gain.combine(records[::-1])
        assert got["k"] == [0.75, 3.0] and got["sigma"][0] < 0.001 and abs(got["sigma"][1] / 0.008 - 1.0) < 0.3, got
    NoiseProfile.load("SonyA7S2").with_effect("ColGain", got)  # a valid profile entry
    low = synth({"ColGain": per_k}, batch=2, size=64, level_dn=level, model="G+P*", k=0.75)
    assert np.array_equal(low, synth({}, batch=2, size=64, level_dn=level, model="G+P*", k=0.75))
    high = synth({"ColGain": per_k}, batch=2, size=64, level_dn=level, model="G+P*", k=3.0)
    flat_high = synth({"ColGain": {"seed": 67, "sigma": 0.008}}, batch=2, size=64, level_dn=level, model="G+P*", k=3.0)
    assert np.array_equal(high, flat_high)
    with pytest.raises(ValueError, match="one value per k"):
        BASE.with_effect("ColGain", {"seed": 67, "k": [0.75, 3.0], "sigma": [0.01]})
    with pytest.raises(ValueError, match=r"must be in \[0, 0.5\)"):
        BASE.with_effect("ColGain", {"seed": 67, "k": [0.75], "sigma": [0.7]})

ROWGAIN = {"seed": 71, "fixed": 0.004, "frame": 0.003}


def test_row_gain_scales_the_signal_per_sensor_row_fixed_and_per_frame():
    level = 2000.0
    assert np.array_equal(synth({"RowGain": ROWGAIN}, batch=2, model="G+P*"), synth({}, batch=2, model="G+P*"))  # no signal
    f = synth({"RowGain": ROWGAIN}, batch=8, size=128, level_dn=level, model="G+P*")
    rows = f.mean(axis=3) / level - 1.0  # (N, 4, h) relative row means
    fixed, frame = rows.mean(axis=0), rows - rows.mean(axis=0)
    # the two channels of a sensor row share its gains: R with G1, B with G2 (shot noise ~2e-4 per row mean)
    assert np.corrcoef(fixed[0], fixed[1])[0, 1] > 0.9 and np.corrcoef(fixed[2], fixed[3])[0, 1] > 0.9
    assert abs(np.corrcoef(fixed[0], fixed[2])[0, 1]) < 5 / math.sqrt(128)
    shot = 1.0 / (level * 128)  # the relative variance shot noise leaves in one row mean
    # per frame the shared gain is 0.003 beside a row mean's shot noise: correlation 9e-6 / (9e-6 + shot) ~ 0.70
    r = 0.003**2 / (0.003**2 + shot)
    assert abs(np.corrcoef(frame[:, 0].ravel(), frame[:, 1].ravel())[0, 1] - r) < 5 * (1 - r * r) / math.sqrt(8 * 128)
    # 2 x 128 fixed gains (the stack mean keeps 1/8 of the per-frame part): std of a std of n normals ~1 / sqrt(2 n)
    spread = math.sqrt(float(np.mean(fixed**2)) - (0.003**2 + shot) / 8)
    assert abs(spread / 0.004 - 1.0) < 5 / math.sqrt(2 * 256), spread
    # 8 frames x 2 x 128 per-frame gains, 7 degrees of freedom per row
    spread = math.sqrt(float(np.mean(frame**2)) * 8 / 7 - shot)
    assert abs(spread / 0.003 - 1.0) < 5 / math.sqrt(2 * 7 * 256), spread


def test_row_gain_estimate_round_trip_and_white_flats_get_almost_none():
    level = 2000.0
    flat = {"model": "G+P*", "level_dn": level}
    meas = synth({"RowGain": ROWGAIN}, batch=8, size=128, **flat)
    base = [synth({}, batch=8, size=128, seed=s, **flat) for s in range(1, 5)]
    est = row_gain.estimate(meas, base, K, level_dn=level)
    # robust variances of 127 row differences per channel, two independent patterns: ~10 % in each part
    assert abs(est["fixed"] / 0.004 - 1.0) < 0.3 and abs(est["frame"] / 0.003 - 1.0) < 0.3, est
    assert est["weight"] == level**2
    # two stacks at another level: combined by variance, weighted by level^2
    both = row_gain.combine([est, {**est, "fixed": 0.0, "frame": 0.0, "weight": level**2 / 4}])
    assert both["fixed"] == pytest.approx(est["fixed"] * math.sqrt(0.8)) and both["seed"] == 71
    # white flats: the excess is chance, of the order of the shot noise a row mean keeps (~2e-4)
    white = [row_gain.estimate(synth({}, batch=8, size=128, seed=s, **flat), base, K, level_dn=level) for s in range(20, 30)]
    assert max(max(w["fixed"], w["frame"]) for w in white) < 0.001, white
    with pytest.raises(ValueError, match="flat stack"):
        row_gain.estimate(meas, base, K)
    with pytest.raises(ValueError, match=">= 2 frames"):
        row_gain.estimate(meas[:1], base, K, level_dn=level)


def test_defect_lines_estimate_round_trip():
    # 2 frames of 4 x 512 x 512 packed: 1024 sensor rows and columns; offsets 40 DN (+-0.3 in
    # log), far above the 8-sigma detection threshold of a line mean (~0.35 DN here)
    p = {"seed": 5, "row_density": 0.01, "col_density": 0.03, "log_std": 0.3, "negative": 0.4, "k": [K], "median_dn": [40.0]}
    f = synth({"Lines": p}, batch=2, size=512)
    est = defect_lines.estimate(f, [synth({}, batch=2, size=512, seed=9)], K)
    n = 1024
    for key, density in (("row_density", 0.01), ("col_density", 0.03)):
        assert abs(est[key] - density) < 5 * math.sqrt(density * (1 - density) / n), (key, est[key])
    lines = (0.01 + 0.03) * n  # ~41 lines: the log-normal's mean within 5 standard errors
    assert abs(math.log(est["median_dn"][0] / 40.0)) < 5 * 0.3 / math.sqrt(lines)
    assert abs(est["log_std"] - 0.3) < 0.15
    assert abs(est["negative"] - 0.4) < 5 * math.sqrt(0.24 / lines)
    none = defect_lines.estimate(synth({}, batch=2, size=512, seed=4), [synth({}, batch=2, size=512, seed=9)], K)
    assert none["row_density"] == 0.0 and none["col_density"] == 0.0


def test_defect_lines_over_a_part_are_synthesized_and_found():
    # half the lines offset from a break in [0.2, 0.8] of the line to its end (to_end 1): on a
    # 4 x 256 x 256 stack of 2 frames (512 sensor lines each way) each such column reads its
    # 40 DN below the break and nothing above, both packed channels alike; the estimate finds
    # the partial share within 5 binomial sd, every found break within [0.2, 0.8] widened by
    # 2 % (a break within a few pixels), to_end 1, and the part's offset (not the diluted mean)
    p = {"seed": 5, "row_density": 0.0, "col_density": 0.04, "log_std": 0.0, "negative": 0.0, "k": [K], "median_dn": [40.0],
         "partial": 0.5, "to_end": 1.0, "cut_lo": 0.2, "cut_hi": 0.8}
    f = synth({"Lines": p}, batch=2, size=256)
    base = synth({}, batch=2, size=256)  # the same frames without the lines
    moved = (f - base).mean(axis=0)  # (4, 256, 256) the lines' offsets
    col = np.zeros((512, 512))  # sensor (row, column)
    for c in range(4):
        col[ROW_SET[c]::2, COLUMN_SET[c]::2] = moved[c]
    hit = np.flatnonzero(np.abs(col).max(axis=0) > 1.0)
    parts = [(col[:, j] > 1.0).mean() for j in hit]
    assert all(np.allclose(col[col[:, j] > 1.0, j], 40.0) for j in hit)
    partial = [q for q in parts if q < 1.0]
    assert all(0.2 - 1 / 512 <= 1 - q <= 0.8 + 1 / 512 for q in partial), partial  # the offset runs from the break to the end
    n = len(hit)
    assert abs(len(partial) / n - 0.5) < 5 * math.sqrt(0.25 / n), (len(partial), n)
    est = defect_lines.estimate(f, [synth({}, batch=2, size=256, seed=9)], K)
    assert abs(est["partial"] - len(partial) / n) < 5 * math.sqrt(0.25 / n), est
    assert est["to_end"] == 1.0 and 0.2 - 0.02 - est["cut_lo"] < 0.1 and est["cut_hi"] - 0.8 - 0.02 < 0.1, est
    assert est["cut_lo"] >= 0.2 - 0.1 and est["cut_hi"] <= 0.8 + 0.1, est
    assert abs(math.log(est["median_dn"][0] / 40.0)) < 0.05, est
    # whole lines stay whole: no partial share on the round trip's lines
    whole = defect_lines.estimate(synth({"Lines": dict(p, partial=0.0)}, batch=2, size=256), [synth({}, batch=2, size=256, seed=9)], K)
    assert "partial" not in whole, whole
    with pytest.raises(ValueError, match="cut_lo"):
        BASE.with_effect("Lines", dict(p, cut_lo=0.9))


def test_black_clip_piles_up_at_the_floor():
    f = synth({"Clip": {"floor_dn": -1.0}}, sigma_g=2.0)
    assert f.min() == -1.0
    from scipy import stats
    expected = stats.norm.cdf(-0.5)  # P(N(0, 2^2) + U < -1) ~ P(N(0, 2) < -1)
    assert abs((f == -1.0).mean() - expected) < 0.02
    assert black_clip.estimate(np.rint(f), [], K) == {"floor_dn": -1.0}



def test_black_clip_floor_is_the_lowest_over_every_stack():
    """A dark stack that reaches the floor (-1 DN) and a flat at 500 DN that never does, in either
    order: the camera's floor is the dark's (before, the loop took the first stack's lowest code)."""
    dark = black_clip.estimate(np.rint(synth({"Clip": {"floor_dn": -1.0}}, sigma_g=2.0)), [], K)
    flat = black_clip.estimate(np.rint(synth({"Clip": {"floor_dn": -1.0}}, level_dn=500.0, model="G+P*", seed=3)), [], K)
    assert dark == {"floor_dn": -1.0} and flat["floor_dn"] > 300.0, (dark, flat)
    assert black_clip.combine([flat, dark]) == black_clip.combine([dark, flat]) == {"floor_dn": -1.0}


def test_every_candidate_joins_its_stacks_records():
    """The loop joins an effect's per-stack records by its module's combine, or by gain where every
    record carries its K; an effect with neither is refused (one stack cannot stand for the camera)."""
    from rawaug.loop.frames_loop import CANDIDATES, _estimate
    frames = synth({}, batch=4, size=64)
    for token, cand in CANDIDATES.items():
        if hasattr(cand.module, "combine"):
            continue
        rec = cand.estimate(frames, [synth({}, batch=4, size=64, seed=5)], K, level_dn=None, exposure_s=None, seed=1,
                            series=None, kind="bias", black_dn=0.0, black_code=512)
        assert rec is None or "k" in rec, (token, rec)
    stack = SimpleNamespace(frames_dn=frames, k=K, level_dn=None, exposure_s=None, series=None, kind="bias",
                            black_code=512, label="bias")
    token = next(iter(CANDIDATES))
    original = CANDIDATES[token]
    CANDIDATES[token] = SimpleNamespace(module=SimpleNamespace(__name__="no_join"), wants=lambda key: False,
                                        estimate=lambda *a, **kw: {"floor_dn": 0.0})
    try:
        with pytest.raises(TypeError, match="no combine"):
            _estimate(token, [stack], {"bias": (None, [])}, 0)
    finally:
        CANDIDATES[token] = original

def test_frame_black_level_common_and_per_channel():
    p = {"k": [K], "sigma_dn": [0.5], "channel_sigma_dn": [0.3]}
    f = synth({"BLE": p}, batch=200, size=16, sigma_g=0.5)
    m = f.mean(axis=(2, 3))
    c = np.cov(m.T)
    n = m.shape[0]
    assert abs(frame_black_level.common_covariance(m) - 0.25) < 5 * 0.25 * math.sqrt(2 / n)
    assert abs(np.diag(c).mean() - 0.34) < 5 * 0.34 * math.sqrt(2 / (4 * n))
    est = frame_black_level.estimate(f, [synth({}, batch=200, size=16, seed=3, sigma_g=0.5)], K)
    assert abs(est["sigma_dn"][0] - 0.5) < 0.1 and abs(est["channel_sigma_dn"][0] - 0.3) < 0.1


def test_prnu_scales_with_signal_and_estimate():
    p = {"seed": 11, "sigma": 0.02}
    level = 2000.0
    f = synth({"PRNU": p}, batch=8, size=64, level_dn=level, model="P*")
    est = prnu.estimate(f, [synth({}, batch=8, size=64, level_dn=level, model="P*", seed=s) for s in (1, 2)], K, level_dn=level)
    assert abs(est["sigma"] - 0.02) < 0.002


def test_prnu_is_fitted_to_every_flat_stack_not_the_first():
    """A dim flat (50 DN, where 1 % gains add 0.25 DN^2 under about 50 DN^2 of shot noise: its
    own estimate is anywhere from 0 to 2 %) and a bright one (2000 DN), in either order: the
    spread fitted to both is the bright one's, 1 % within 0.15 % (before, the loop took the
    first stack's)."""
    p = {"seed": 11, "sigma": 0.01}
    ests = [prnu.estimate(synth({"PRNU": p}, batch=4, size=64, level_dn=level, model="P*", seed=20 + i),
                          [synth({}, batch=4, size=64, level_dn=level, model="P*", seed=s) for s in (1, 2)], K, level_dn=level)
            for i, level in enumerate((50.0, 2000.0))]
    assert abs(prnu.combine(ests)["sigma"] - 0.01) < 0.0015
    assert abs(prnu.combine(ests[::-1])["sigma"] - 0.01) < 0.0015


@pytest.mark.parametrize("c", [4e-6, -2e-6])
def test_gain_non_linearity_estimate_round_trip(c):
    # a flat series (5 exposures, one light) synthesized with the stage: the joint fit gives
    # c and the rates back; the mean of 8 x 4096 pixels per channel has a relative se of
    # ~1e-4 at the dimmest level, against deviations of c x ~ 4e-2 at the brightest
    exposures = np.array([0.02, 0.1, 0.3, 0.5, 0.8])
    rate = BASE.span_dn * np.array([1.0, 0.9, 0.8, 1.1])  # DN/s per channel
    means = []
    for i, t in enumerate(exposures):
        prof = BASE.with_effect("NonLin", {"k": [K], "compression_per_dn": [c]})
        aug = RawNoiseAugment(prof, model="G+P*", ratio=1.0, fixed={"k": K, "sigma_g": 2.0},
                              generator=torch.Generator().manual_seed(i), rank_seeding=False)
        x = torch.from_numpy(rate * t / prof.span_dn).view(1, 4, 1, 1).expand(8, 4, 64, 64).contiguous()
        means.append((aug(x) * prof.span_dn).numpy().mean(axis=(0, 2, 3)))
    means = np.array(means)
    fitted, rates = gain_nonlinearity.fit_series(exposures, means, K)
    assert abs(fitted / c - 1) < 0.02, fitted
    assert np.allclose(rates, rate, rtol=1e-3) and np.allclose(gain_nonlinearity.fit_rates(exposures, means, c, K), rate, rtol=1e-3)
    linear = gain_nonlinearity.linear_rates(exposures, means)
    assert np.all(linear < rate) if c > 0 else np.all(linear > rate)  # a line through compressed means runs low


def _nonlin_series(c, seed):
    """(exposures, (5, 4) channel means in DN) of a flat series synthesized with ``NonLin`` ``c``."""
    exposures = np.array([0.02, 0.1, 0.3, 0.5, 0.8])
    rate = BASE.span_dn * np.array([1.0, 0.9, 0.8, 1.1])  # DN/s per channel
    prof = BASE.with_effect("NonLin", {"k": [K], "compression_per_dn": [c]})
    means = []
    for i, t in enumerate(exposures):
        aug = RawNoiseAugment(prof, model="G+P*", ratio=1.0, fixed={"k": K, "sigma_g": 2.0},
                              generator=torch.Generator().manual_seed(100 * seed + i), rank_seeding=False)
        x = torch.from_numpy(rate * t / prof.span_dn).view(1, 4, 1, 1).expand(4, 4, 64, 64).contiguous()
        means.append((aug(x) * prof.span_dn).numpy().mean(axis=(0, 2, 3)))
    return exposures, np.array(means)


def test_gain_non_linearity_of_one_channel_is_estimated_per_channel():
    # the red channel alone compresses (3 % at 6000 DN): channel_linearity sees it against the
    # others (the common light cancels), and the estimate gives each channel its own c; a
    # common compression keeps one c. The channels' own fits leave a spread of 1e-4 to 3e-4
    # (the means' noise); the common fit leaves 1.6e-2 with the red channel planted, and
    # 1.0 to 1.25 times the own fits' without (the choice needs 3 times and 5e-4): 6 seeds
    # of each, every one right.
    planted = [5e-6, 0.0, 0.0, 0.0]
    for seed in range(6):
        t, means = _nonlin_series(planted, seed)
        series = SimpleNamespace(doses=t, signal_dn=means)
        c = gain_nonlinearity.estimate(None, [], K, series=series)["compression_per_dn"][0]
        assert isinstance(c, list) and abs(c[0] / 5e-6 - 1) < 0.05 and max(abs(v) for v in c[1:]) < 2.5e-7, c
        level = gain_nonlinearity.linear_rates(t, means) * t[-1]
        assert channel_linearity(np.broadcast_to(means[-1][None, :, None, None], (1, 4, 2, 2)), level) > 4e-3
        t, means = _nonlin_series(3e-6, seed)
        c = gain_nonlinearity.estimate(None, [], K, series=SimpleNamespace(doses=t, signal_dn=means))["compression_per_dn"][0]
        assert isinstance(c, float) and abs(c / 3e-6 - 1) < 0.05, c
    common = np.broadcast_to(np.array([1000.0, 900.0, 800.0, 1100.0])[None, :, None, None], (1, 4, 2, 2))
    assert channel_linearity(common * 1.01, [1000.0, 900.0, 800.0, 1100.0]) < 1e-12  # a brighter light: no spread


def test_flat_series_needs_three_exposures_under_one_light(capsys):
    from rawaug.loop.command import flat_series

    level = lambda t: np.array([1000.0, 900.0, 800.0, 1100.0]) * t  # noqa: E731
    offsets = np.zeros(4)
    assert flat_series(800, [(t, level(t)) for t in (0.1, 0.5, 1.0)], offsets) is not None
    assert flat_series(800, [(t, level(t)) for t in (0.1, 1.0, 1.0)], offsets) is None  # two exposures
    assert flat_series(800, [(1.0, level(f)) for f in (0.1, 0.5, 1.0)], offsets) is None  # one exposure, the light changed
    assert capsys.readouterr().out == ""
    assert flat_series(800, [(t, level(f)) for t, f in ((0.1, 0.1), (0.5, 1.0), (1.0, 0.5))], offsets) is None
    assert "not checked" in capsys.readouterr().out  # exposures that do not track the means: said, not used


def test_gain_non_linearity_must_keep_the_output_rising():
    prof = BASE.with_effect("NonLin", {"k": [K], "compression_per_dn": [1e-4]})  # the output would peak at 5000 DN
    with pytest.raises(ValueError, match=r"compression_per_dn 0.0001 /DN makes the output fall before the white level"):
        RawNoiseAugment(prof)


XTALK = {"k": [K], "tap_0_0_dn": [1.0], "tap_0_1_dn": [0.6], "tap_1_1_dn": [-0.5], "tap_2_0_dn": [0.4], "tap_1_-1_dn": [0.0]}
XTALK_TAPS_DN = [XTALK.get(key, [0.0])[0] for key in crosstalk.KEYS]


def _raw(f):
    """(N, 2h, 2w) raw mosaics of packed frames (R, G1, B, G2) of an RGGB sensor."""
    raw = np.empty((f.shape[0], 2 * f.shape[2], 2 * f.shape[3]))
    raw[:, 0::2, 0::2], raw[:, 0::2, 1::2], raw[:, 1::2, 1::2], raw[:, 1::2, 0::2] = f[:, 0], f[:, 1], f[:, 2], f[:, 3]
    return raw


def test_crosstalk_covariance_at_each_lag():
    f = synth({"Xtalk": XTALK}, batch=8, size=64, sigma_g=0.0)
    raw = _raw(f)
    var = sum(h * h for h in XTALK_TAPS_DN)
    assert abs(raw.var() / var - 1) < 5 * math.sqrt(2 / raw.size) * 3  # pixel variance sum h^2 (taps correlate pixels)
    hh, ww = raw.shape[1:]
    expected = crosstalk.autocovariance(XTALK_TAPS_DN)
    # by hand: lag (1, 0) pairs taps (0, 1) and (1, 1); lag (2, 0) taps (0, 0) and (2, 0); lag (0, 1) taps (0, 0)-(0, 1) and (1, 0)-(1, 1)
    assert expected[XTALK_LAGS.index((1, 0))] == pytest.approx(0.6 * -0.5)
    assert expected[XTALK_LAGS.index((2, 0))] == pytest.approx(1.0 * 0.4)
    assert expected[XTALK_LAGS.index((0, 1))] == pytest.approx(1.0 * 0.6)
    for (dy, dx), c in zip(XTALK_LAGS, expected):
        x = raw[:, : hh - dy, max(0, -dx) : ww - max(0, dx)]
        y = raw[:, dy:, max(0, dx) : ww - max(0, -dx)]
        cov = float(np.mean(x * y))
        # the mean of n products of correlated normals has sd <= var / sqrt(n / 3) (neighbouring products share draws)
        assert abs(cov - c) < 5 * var / math.sqrt(x.size / 3), ((dy, dx), cov, c)


def test_crosstalk_kernel_of_least_variance():
    # a coupling of the left and upper neighbours (1.5 DN plus 0.6 and 0.4 of theirs): one field
    # through a kernel holds it with its own 3.42 DN^2; a field per lag needed 2 sum |c| = 5.58
    true = [1.5, 0.9, 0.6, 0.0, 0.0, 0.0, 0.0]
    cov = crosstalk.autocovariance(true)
    assert cov == pytest.approx([1.35, 0.9, 0.0, 0.54, 0.0, 0.0])
    h = crosstalk.kernel_for(cov)
    assert crosstalk.autocovariance(h) == pytest.approx(cov, abs=0.01)
    assert sum(x * x for x in h) <= sum(x * x for x in true) + 0.01
    # one lag alone: two equal taps, variance 2c, the least any kernel can have
    h = crosstalk.kernel_for([0.0, 0.0, 0.0, 0.0, 0.8, 0.0])
    assert h[0] == pytest.approx(0.8**0.5, rel=1e-3) and h[crosstalk.KEYS.index("tap_0_2_dn")] == pytest.approx(0.8**0.5, rel=1e-3)
    assert not np.any(crosstalk.kernel_for(np.zeros(6)))


def test_crosstalk_estimate_round_trip_and_white_noise_gives_nothing():
    meas = synth({"Xtalk": XTALK}, batch=8, size=64, sigma_g=1.5)
    # the base model as calibrated: its white read noise holds all of the pixel variance
    white_sigma = math.sqrt(1.5**2 + sum(h * h for h in XTALK_TAPS_DN))
    base = [synth({}, batch=8, size=64, seed=s, sigma_g=white_sigma) for s in range(1, 7)]
    est = crosstalk.estimate(meas, base, K)
    got = crosstalk.autocovariance([est[key][0] for key in crosstalk.KEYS])
    for lag, c, true in zip(XTALK_LAGS, got, crosstalk.autocovariance(XTALK_TAPS_DN)):
        # the residual is high-passed (7x7 local mean out): covariances within a few per cent of the truth
        assert abs(c - true) < 0.1 + 0.1 * abs(true), (lag, c, true)
    # the kernel of least variance: no more than the planted one's
    assert sum(est[key][0] ** 2 for key in crosstalk.KEYS) <= sum(h * h for h in XTALK_TAPS_DN) + 0.1
    white = crosstalk.estimate(synth({}, batch=8, size=64, seed=9, sigma_g=white_sigma), base, K)
    covs = crosstalk.autocovariance([white[key][0] for key in crosstalk.KEYS])
    assert np.count_nonzero(np.abs(covs) > 1e-6) <= 1, white  # 3 sd per lag: P(any of 6) ~ 1.6 %
    with pytest.raises(ValueError, match="bias and dark"):
        crosstalk.estimate(meas, base, K, level_dn=100.0)


def test_temporal_mosaic_puts_each_channel_at_its_sensor_position():
    f = np.zeros((2, 4, 16, 16))
    f[0, 2, 5, 7] = 1.0  # B of tile (5, 7): raw (11, 15)
    raw = temporal_mosaic(f)
    assert np.unravel_index(np.argmax(raw[0]), raw[0].shape) == (11, 15)


BAND = {"k": [K], "freq_per_row": [[0.0713, 0.23]], "amplitude_dn": [[1.2, 0.6]]}
COLBAND = {"k": [K], "freq_per_col": [[0.0713, 0.23]], "amplitude_dn": [[1.2, 0.6]]}
# token, its record, its frequency key, the sensor-line means it lies on, the channel pair on one sensor line, its module
TONE_AXES = {"rows": ("Band", BAND, "freq_per_row", sensor_row_means, (0, 1), banding),
             "columns": ("ColBand", COLBAND, "freq_per_col", sensor_col_means, (0, 3), column_banding)}


@pytest.mark.parametrize("axis", list(TONE_AXES))
def test_banding_tones_have_their_amplitude_and_a_uniform_phase_per_frame(axis):
    token, record, key, line_means, pair, _ = TONE_AXES[axis]
    f = synth({token: record}, batch=64, size=32, sigma_g=0.01)
    m = line_means(f)  # (64 frames, 64 sensor lines)
    y = np.arange(m.shape[1])
    for freq, amp in zip(record[key][0], record["amplitude_dn"][0]):
        basis = np.stack([np.cos(2 * np.pi * freq * y), np.sin(2 * np.pi * freq * y)], axis=1)
        coef, *_ = np.linalg.lstsq(basis, (m - m.mean(axis=1, keepdims=True)).T, rcond=None)
        # the other tone leaks into the fit by at most ~1 / (pi x 64 x 0.16) of its amplitude
        assert np.allclose(np.hypot(*coef), amp, atol=0.05), np.hypot(*coef)
        phase = (np.arctan2(-coef[1], coef[0]) / (2 * np.pi)) % 1.0
        ks = np.abs(np.sort(phase) - (np.arange(1, 65) - 0.5) / 64).max()  # Kolmogorov-Smirnov distance to U(0, 1)
        assert ks < 1.95 / np.sqrt(64), ks  # 0.1 % critical value
    # both channels of a sensor line carry the same offset
    along = 2 if axis == "rows" else 1  # average along the line: each line's offset
    assert np.allclose(f[:, pair[0]].mean(axis=along), f[:, pair[1]].mean(axis=along), atol=0.02)
    # the other axis's line means carry none of it: within 5 sd of the read noise's
    other = sensor_col_means(f) if axis == "rows" else sensor_row_means(f)
    resid = other - other.mean(axis=1, keepdims=True)
    assert resid.std() < 5 * 0.01 / np.sqrt(2 * 32), resid.std()


@pytest.mark.parametrize("axis", list(TONE_AXES))
def test_banding_estimate_finds_the_tones_and_nothing_in_white_line_noise(axis):
    token, record, key, _, _, module = TONE_AXES[axis]
    row = {"sigma_g": 2.0, "model": "G+R", "sigma_r": 0.5}  # one camera: its row noise fixed, as the loop's syntheses have it
    meas = synth({token: record}, batch=8, size=64, **row)
    base = [synth({}, batch=8, size=64, seed=s, **row) for s in range(1, 6)]
    est = module.estimate(meas, base, K)
    order = np.argsort(est[key][0])
    assert np.allclose(np.array(est[key][0])[order], record[key][0], atol=0.1 / 128), est
    assert np.allclose(np.array(est["amplitude_dn"][0])[order], record["amplitude_dn"][0], rtol=0.15), est
    # family-wise 1e-3 per stack: 10 white stacks find a tone with probability ~1 %
    found = [module.estimate(synth({}, batch=8, size=64, seed=s, **row), base, K)[key][0] for s in range(20, 30)]
    assert sum(bool(t) for t in found) <= 1, found
    with pytest.raises(ValueError, match="bias and dark"):
        module.estimate(meas, base, K, level_dn=100.0)


# the columns share the rows' code (banding.line_tones, draw_tones): checked in the slow run
ROWS_NOW = ["rows", pytest.param("columns", marks=pytest.mark.slow)]


@pytest.mark.parametrize("axis", ROWS_NOW)
def test_a_tone_switched_on_in_a_share_of_the_frames_is_drawn_and_estimated(axis):
    token, record, key, line_means, _, module = TONE_AXES[axis]
    record = {**record, "on_share": [[0.5, 1.0]]}  # the first tone on in half the frames, the second in all
    m = line_means(synth({token: record}, batch=64, size=32, sigma_g=0.01))
    y = np.arange(m.shape[1])
    amps = []
    for freq in record[key][0]:
        basis = np.stack([np.cos(2 * np.pi * freq * y), np.sin(2 * np.pi * freq * y)], axis=1)
        coef, *_ = np.linalg.lstsq(basis, (m - m.mean(axis=1, keepdims=True)).T, rcond=None)
        amps.append(np.hypot(*coef))
    on = amps[0] > 0.6  # 1.2 DN or (off) its leakage from the other tone, < 0.05
    assert np.all((np.abs(amps[0] - 1.2) < 0.05) | (amps[0] < 0.05)), amps[0]
    assert abs(on.sum() - 32) <= 13, on.sum()  # binomial(64, 0.5): sd 4; 3.3 sd
    assert np.allclose(amps[1], 0.6, atol=0.05), amps[1]  # on in every frame
    # estimated: 6 stacks of 8 frames, the share pooled within 3.3 binomial sd of 0.5 over 48 frames
    row = {"sigma_g": 2.0, "model": "G+R", "sigma_r": 0.5}
    base = [synth({}, batch=8, size=64, seed=s, **row) for s in range(1, 5)]
    est = [module.estimate(synth({token: record}, batch=8, size=64, seed=40 + s, **row), base, K) for s in range(6)]
    shares = [dict(zip(np.round(e[key][0], 2), e["on_share"][0])) for e in est]
    first = [sh.get(round(record[key][0][0], 2)) for sh in shares]
    assert all(v is not None for v in first), est
    assert abs(np.mean(first) - 0.5) < 3.3 * math.sqrt(0.25 / 48), first
    # the tone on in every frame: the mixture is kept at p 1e-3 per stack: in none of 6, or 1 by chance
    assert sum(sh.get(round(record[key][0][1], 2), 1.0) < 1.0 for sh in shares) <= 1, shares
    out = module.combine(est)
    assert abs(out["on_share"][0][0] - 0.5) < 3.3 * math.sqrt(0.25 / 48) and out["on_share"][0][1] > 0.8, out
    assert abs(out["amplitude_dn"][0][0] - 1.2) < 0.15 * 1.2, out


@pytest.mark.parametrize("axis", ROWS_NOW)
def test_a_tone_whose_frequency_wanders_is_drawn_and_estimated(axis):
    """A 1.2 DN tone at 0.12 cycles per line, its frequency off by a normal 0.01 per frame: the
    frames' own peaks (64 nearly noiseless frames) spread with an sd within 4 chi sd of 0.01;
    estimated on 16 stacks of 8 frames (128 lines; 25 and 26 of 30 such stacks found the tone,
    rows and columns), found in at least 10, the sd pooled over them within 35 % (detection
    favours the stacks whose frames spread less: 0.0082 and 0.0096 over those 30) and the
    amplitude within 15 %; a tone of fixed frequency gets no spread in 10 of 10 stacks."""
    token, _, key, line_means, _, module = TONE_AXES[axis]
    record = {"k": [K], key: [[0.12]], "amplitude_dn": [[1.2]], "freq_sd": [[0.01]]}
    m = line_means(synth({token: record}, batch=64, size=64, sigma_g=0.01))
    _, peaks, amps = banding.frequency_wander(m - m.mean(axis=1, keepdims=True), 0.12, 1e-6, 0.0)
    assert abs(np.std(peaks, ddof=1) / 0.01 - 1) < 4 / math.sqrt(2 * 63), np.std(peaks, ddof=1)
    assert np.allclose(amps, 1.2, rtol=0.05), amps
    row = {"sigma_g": 2.0, "model": "G+R", "sigma_r": 0.5}
    base = [synth({}, batch=8, size=64, seed=s, **row) for s in range(1, 5)]
    est = [module.estimate(synth({token: record}, batch=8, size=64, seed=60 + s, **row), base, K) for s in range(16)]
    found = [e for e in est if e[key][0]]
    assert len(found) >= 10, est
    assert all(abs(e[key][0][0] - 0.12) < 0.02 and e["freq_sd"][0][0] > 0 for e in found), found
    out = module.combine(found)
    assert abs(out["freq_sd"][0][0] - 0.01) < 0.0035 and abs(out["amplitude_dn"][0][0] - 1.2) < 0.18, out
    fixed = {"k": [K], key: [[0.12]], "amplitude_dn": [[1.2]]}
    sds = [module.estimate(synth({token: fixed}, batch=8, size=64, seed=80 + s, **row), base, K)["freq_sd"][0]
           for s in range(10)]
    assert all(sd == [0.0] for sd in sds), sds


DIAGBAND = {"k": [K], "freq_per_col": [[0.11, 0.3]], "freq_per_row": [[0.23, -0.17]], "amplitude_dn": [[1.2, 0.6]]}


def test_diag_tone_does_not_take_a_sparse_fixed_pattern_for_a_tone():
    # hot 2x2 tiles (12 of 4096 tiles, 30 DN, sigma_g 2 DN) in every frame: their broad fixed
    # spectrum, the same in every frame, puts the raw mosaic's largest bin above the ring
    # around it at 2.5 times the noise's (19.3 against 7.6 DN^2 over 12 seeds); with the mean
    # map's outliers set aside the statistic keeps its null distribution, and a diagonal tone
    # beside the tiles is still seen (~2000 DN^2)
    tiles = np.random.default_rng(5).random((64, 64)) < 2e-3
    plain, tiled, unmasked, toned = [], [], [], []
    for s in range(12):
        f = synth({}, batch=8, size=64, sigma_g=2.0, seed=s)
        g = f + 30.0 * tiles[None, None]
        plain.append(statistics.diag_tone(f))
        tiled.append(statistics.diag_tone(g))
        raw = statistics.frame_mosaic(g)
        p, (_, _, keep) = statistics.windowed_periodogram(raw), statistics.diagonal_bins(raw.shape[1:])
        unmasked.append(float((p[keep] - statistics.local_background(p)[keep]).max()))
        toned.append(statistics.diag_tone(synth({"DiagBand": DIAGBAND}, batch=8, size=64, sigma_g=2.0, seed=s) + 30.0 * tiles[None, None]))
    se = np.std(plain, ddof=1) / np.sqrt(12)
    assert np.mean(unmasked) > np.mean(plain) + 10 * se  # the tiles do show in the plain periodogram
    assert abs(np.mean(tiled) - np.mean(plain)) < 4 * se, (np.mean(tiled), np.mean(plain))
    assert min(toned) > 20 * max(plain)


def test_diagonal_banding_tones_have_their_amplitude_and_a_uniform_phase_per_frame():
    from rawaug.statistics import frame_mosaic

    f = synth({"DiagBand": DIAGBAND}, batch=64, size=32, sigma_g=0.01)
    raw = frame_mosaic(f)  # (64 frames, 64 sensor rows, 64 sensor columns)
    yy, xx = np.arange(64)[:, None], np.arange(64)[None, :]
    for fx, fy, amp in zip(DIAGBAND["freq_per_col"][0], DIAGBAND["freq_per_row"][0], DIAGBAND["amplitude_dn"][0]):
        arg = 2 * np.pi * (fx * xx + fy * yy)
        basis = np.stack([np.cos(arg).ravel(), np.sin(arg).ravel()], axis=1)
        coef, *_ = np.linalg.lstsq(basis, raw.reshape(64, -1).T, rcond=None)
        # the other tone and the channel means leak into the fit by a few per cent at most
        assert np.allclose(np.hypot(*coef), amp, atol=0.05), np.hypot(*coef)
        phase = (np.arctan2(-coef[1], coef[0]) / (2 * np.pi)) % 1.0
        ks = np.abs(np.sort(phase) - (np.arange(1, 65) - 0.5) / 64).max()  # Kolmogorov-Smirnov distance to U(0, 1)
        assert ks < 1.95 / np.sqrt(64), ks  # 0.1 % critical value


FIXED_TONE = {"k": [K], "freq_per_col": [[0.13]], "freq_per_row": [[0.07]], "amplitude_dn": [[0.0]], "fixed_dn": [[0.8]]}


def test_diagonal_banding_fixed_part_is_the_same_in_every_frame_and_uniform_over_sensors():
    from rawaug.statistics import frame_mosaic

    yy, xx = np.arange(64)[:, None], np.arange(64)[None, :]
    arg = 2 * np.pi * (0.13 * xx + 0.07 * yy)
    basis = np.stack([np.cos(arg).ravel(), np.sin(arg).ravel()], axis=1)

    def coefficients(frames):
        return np.linalg.lstsq(basis, frame_mosaic(frames).reshape(frames.shape[0], -1).T, rcond=None)[0]  # (2, N)

    one = coefficients(synth({"DiagBand": FIXED_TONE}, batch=16, size=32, sigma_g=0.01))
    assert np.allclose(np.hypot(*one), 0.8, atol=0.02), np.hypot(*one)
    assert np.ptp(one, axis=1).max() < 0.01, one  # one sensor: one phase in all 16 frames
    # 64 samples, each of a sensor instance of its own (the default): the fixed phase is uniform over instances
    prof = BASE.with_effect("DiagBand", FIXED_TONE)
    aug = RawNoiseAugment(prof, model="G", ratio=1.0, fixed={"k": K, "sigma_g": 0.01},
                          generator=torch.Generator().manual_seed(5), rank_seeding=False)
    many = coefficients((aug(torch.zeros(64, 4, 32, 32, dtype=torch.float64)) * prof.span_dn).numpy())
    phase = (np.arctan2(-many[1], many[0]) / (2 * np.pi)) % 1.0
    ks = np.abs(np.sort(phase) - (np.arange(1, 65) - 0.5) / 64).max()
    assert ks < 1.95 / np.sqrt(64), ks  # Kolmogorov-Smirnov, 0.1 % critical value


def test_diagonal_banding_estimate_tells_a_fixed_tone_from_one_new_in_every_frame():
    row = {"sigma_g": 2.0, "model": "G+R", "sigma_r": 0.5}
    base = [synth({}, batch=8, size=64, seed=s, **row) for s in range(1, 6)]
    est = diagonal_banding.estimate(synth({"DiagBand": FIXED_TONE}, batch=8, size=64, **row), base, K)
    assert np.allclose(est["freq_per_col"][0], [0.13], atol=0.1 / 128) and np.allclose(est["freq_per_row"][0], [0.07], atol=0.1 / 128)
    assert abs(est["fixed_dn"][0][0] - 0.8) < 0.12, est  # coherent power over 8 frames of 128 x 128
    assert est["amplitude_dn"][0][0] < 0.3, est  # the circle of 8 points about a fixed centre: noise only
    # a tone whose phase is new in every frame has no fixed part: F test at FIXED_P = 1e-3 per
    # tone and stack, so over 2 tones x 20 stacks a fixed part appears with probability ~4 %
    fixed = [diagonal_banding.estimate(synth({"DiagBand": DIAGBAND}, batch=8, size=64, seed=s, **row), base, K).get("fixed_dn")
             for s in range(40, 60)]
    assert sum(f is not None for f in fixed) <= 1, fixed
    # a phase that jitters about a fixed one (0.3 rad rms; an arc, not a circle about the fixed part):
    # fixed part 0.6 exp(-0.3^2 / 2) = 0.574, the part new in every frame 0.6 sqrt(1 - exp(-0.3^2)) = 0.176
    from rawaug.bayer import pack

    yy, xx = np.arange(128)[:, None], np.arange(128)[None, :]
    jitter = np.random.default_rng(3).normal(0.0, 0.3, 8)
    tone = 0.6 * np.cos(2 * np.pi * (0.19 * xx - 0.11 * yy)[None] + 2.0 + jitter[:, None, None])  # raw (sensor) pixels
    arc = synth({}, batch=8, size=64, seed=11, **row) + pack(tone, "RGGB")  # packed R, G1, B, G2 as the stages lay it
    got = diagonal_banding.estimate(arc, base, K)
    assert abs(got["fixed_dn"][0][0] - 0.574) < 0.06 and abs(got["amplitude_dn"][0][0] - 0.176) < 0.08, got
    # stacks at one K: the fixed part is the rms over those that found one (a stack of few frames may not)
    few = diagonal_banding.estimate(synth({"DiagBand": FIXED_TONE}, batch=3, size=64, seed=7, **row), base, K)
    few["fixed_dn"] = [[0.0]]
    both = diagonal_banding.combine([est, few])
    assert both["fixed_dn"] == est["fixed_dn"] and not diagonal_banding.empty(both), both
    assert diagonal_banding.empty({"amplitude_dn": [[0.0]]}) and not diagonal_banding.empty({"amplitude_dn": [[0.0]], "fixed_dn": [[0.5]]})


def test_diagonal_banding_estimate_finds_the_tones_and_nothing_in_white_noise():
    row = {"sigma_g": 2.0, "model": "G+R", "sigma_r": 0.5}
    meas = synth({"DiagBand": DIAGBAND}, batch=8, size=64, **row)
    base = [synth({}, batch=8, size=64, seed=s, **row) for s in range(1, 6)]
    est = diagonal_banding.estimate(meas, base, K)
    order = np.argsort(est["freq_per_col"][0])
    for key in ("freq_per_col", "freq_per_row"):
        assert np.allclose(np.array(est[key][0])[order], DIAGBAND[key][0], atol=0.1 / 128), est
    assert np.allclose(np.array(est["amplitude_dn"][0])[order], DIAGBAND["amplitude_dn"][0], rtol=0.15), est
    # family-wise 1e-3 per stack: 10 white stacks find a tone with probability ~1 %
    found = [diagonal_banding.estimate(synth({}, batch=8, size=64, seed=s, **row), base, K)["freq_per_col"][0] for s in range(20, 30)]
    assert sum(bool(t) for t in found) <= 1, found
    # a tone along one axis is Band's or ColBand's: not found here
    along = diagonal_banding.estimate(synth({"ColBand": COLBAND}, batch=8, size=64, **row), base, K)
    assert along["freq_per_col"] == [[]], along
    with pytest.raises(ValueError, match="bias and dark"):
        diagonal_banding.estimate(meas, base, K, level_dn=100.0)


def test_column_banding_records_combine_per_gain():
    a = {"k": [1.0], "freq_per_col": [[0.1, 0.3]], "amplitude_dn": [[1.0, 0.5]]}
    b = {"k": [1.0], "freq_per_col": [[0.1002]], "amplitude_dn": [[2.0]]}  # the same tone in a dark stack of the same gain
    c = {"k": [3.0], "freq_per_col": [[0.2]], "amplitude_dn": [[0.7]]}
    out = column_banding.combine([a, b, c])
    assert out["k"] == [1.0, 3.0] and out["freq_per_col"] == [[0.1, 0.3], [0.2]]
    assert np.allclose(out["amplitude_dn"][0], [math.sqrt(2.5), 0.5]) and out["amplitude_dn"][1] == [0.7]


def test_fixed_row_pattern_is_shared_by_a_sensor_row_and_estimated():
    truth = {"seed": 5, "k": [K], "fixed_dn": [1.0]}
    meas = synth({"RowFix": truth}, batch=8, size=64, model="G+R", sigma_g=1.0, sigma_r=0.6)
    rows = meas.mean(axis=(0, 3))  # (4, h) stack-mean row means
    assert np.corrcoef(rows[0], rows[1])[0, 1] > 0.9  # R and G1 share a sensor row
    assert abs(np.corrcoef(rows[0], rows[2])[0, 1]) < 5 / math.sqrt(64)  # B is on the other sensor row
    # the model as calibrated: sigma_r holds the fixed rows' variance (it is read frame by frame)
    base = [synth({}, batch=8, size=64, seed=s, model="G+R", sigma_g=1.0, sigma_r=math.sqrt(0.36 + 1.0)) for s in range(1, 5)]
    est = row_pattern.estimate(meas, base, K)
    # 128 sensor-row values: the relative sd of their variance ~ sqrt(2 / 128) = 0.125 (x1.5 for the robust scale)
    assert abs(est["fixed_dn"][0] ** 2 - 1.0) < 3 * 0.125 * 1.5, est
    white = row_pattern.estimate(synth({}, batch=8, size=64, seed=9, model="G+R", sigma_g=1.0, sigma_r=0.6),
                                 [synth({}, batch=8, size=64, seed=s, model="G+R", sigma_g=1.0, sigma_r=0.6) for s in range(1, 5)], K)
    assert white["fixed_dn"][0] < 0.3, white  # no fixed rows: at most the spread of the estimate


def test_row_noise_per_channel_is_its_own_and_estimated():
    f = synth({"RowCh": {"k": [K], "sigma_dn": [1.5]}}, batch=16, size=64, sigma_g=0.5)
    rows = f.mean(axis=3)  # (16, 4, 64)
    n = rows[:, 0].size
    assert abs(np.corrcoef(rows[:, 0].ravel(), rows[:, 1].ravel())[0, 1]) < 5 / math.sqrt(n)  # R and G1 do not share it
    var = rows.var(axis=2, ddof=1).mean() - 0.25 / 64  # less read noise / row length
    assert abs(var / 2.25 - 1) < 5 * math.sqrt(2 / (4 * n)), var  # chi-square spread over 4 x 16 x 64 row offsets
    base = [synth({}, batch=8, size=64, seed=s, sigma_g=0.5) for s in range(1, 5)]
    est = row_channel.estimate(f[:8], base, K)
    assert abs(est["sigma_dn"][0] ** 2 / 2.25 - 1) < 5 * math.sqrt(2 / (2 * 8 * 64)), est
    with pytest.raises(ValueError, match="bias and dark"):
        row_channel.estimate(f, base, K, level_dn=100.0)


def test_effects_replay_bit_exactly():
    prof = BASE.with_effect("BLE", {"k": [K], "sigma_dn": [0.5]}).with_effect(
        "Col", {"seed": 1, "k": [K], "sigma_dn": [1.0], "fixed_dn": [1.0]})
    aug = RawNoiseAugment(prof, ratio=1.0, fixed={"k": K})
    x = torch.zeros(2, 4, 16, 16)
    y = aug(x)
    assert torch.equal(y, aug(x, params=aug._params))


@pytest.mark.parametrize("token,params,match", [
    ("Col", {"seed": 1, "k": [1.0], "sigma_dn": [-1.0], "fixed_dn": [0.0]}, "sigma_dn must be >= 0"),
    ("Col", {"seed": 1, "k": [1.0, 2.0], "sigma_dn": [1.0], "fixed_dn": [0.0, 0.0]}, "one value per k"),
    ("FPN", {"seed": 1, "k": [1.0], "sigma_dn": [1.0], "shading_dn": [[1.0, 2.0]]}, "2-D grid"),
    ("Hot", {"seed": 1, "density": 0.5, "log_std": 0.0, "k": [1.0], "median_dn": [1.0]}, "density"),
    ("Clip", {}, "floor_dn"),
    ("Lines", {"seed": 1, "row_density": 0.2, "col_density": 0.0, "log_std": 0.0, "negative": 0.0, "k": [1.0], "median_dn": [1.0]},
     r"row_density \(fraction of sensor lines\) must be in \[0, 0.1\], got 0.2"),
    ("Lines", {"seed": 1, "row_density": 0.0, "col_density": 0.0, "log_std": 0.0, "negative": 1.5, "k": [1.0], "median_dn": [1.0]},
     "negative"),
    ("BLE", {"k": [0.0], "sigma_dn": [1.0]}, "k must be > 0"),
    ("PRNU", {"seed": -1, "sigma": 0.01}, "seed"),
    ("Xtalk", {"k": [1.0]}, "at least one of"),
    ("Band", {"k": [1.0], "freq_per_row": [[0.6]], "amplitude_dn": [[1.0]]}, r"must be in \(0, 0.5\], got 0.6"),
    ("RowFix", {"seed": 1, "k": [1.0], "fixed_dn": [-1.0]}, "fixed_dn must be >= 0"),
    ("RowFix", {"k": [1.0], "fixed_dn": [1.0]}, "seed"),
    ("RowCh", {"k": [1.0], "sigma_dn": [-0.5]}, "sigma_dn must be >= 0"),
    ("Shared", {"k": [1.0], "sigma_dn": [-0.1]}, "sigma_dn must be >= 0"),
    ("RTS", {"seed": 1, "density": 0.01, "high": 1.0, "log_std": 0.0, "k": [1.0], "median_dn": [10.0]},
     r"high \(share of frames in the high state\) must be in \(0, 1\), got 1.0"),
    ("RTS", {"seed": 1, "density": 0.5, "high": 0.5, "log_std": 0.0, "k": [1.0], "median_dn": [10.0]}, "density"),
    ("Dead", {"seed": 1, "density": 0.2, "levels_dn": [0.0]}, r"density \(fraction of pixels\) must be in \[0, 0.1\], got 0.2"),
    ("Dead", {"seed": 1, "density": 0.01, "levels_dn": []}, "levels_dn must be a list of 1 to 8 levels"),
    ("Dead", {"seed": 1, "density": 0.01, "levels_dn": [float("inf")]}, "Dead.levels_dn"),
    ("Dead", {"density": 0.01, "levels_dn": [0.0]}, "seed"),
    ("DarkHot", {"seed": 1, "density": 0.2, "median_e_per_s": 1.0, "log_std": 0.0}, r"density \(fraction of pixels\) must be in \[0, 0.1\], got 0.2"),
    ("DarkHot", {"seed": 1, "density": 0.01, "median_e_per_s": -1.0, "log_std": 0.0}, "median_e_per_s must be >= 0, got -1.0"),
    ("DarkHot", {"seed": 1, "density": 0.01, "median_e_per_s": float("nan"), "log_std": 0.0}, "DarkHot.median_e_per_s must be finite"),
    ("DarkHot", {"density": 0.01, "median_e_per_s": 1.0, "log_std": 0.0}, "seed"),
    ("NoisyCol", {"seed": 1, "density": 1.2, "log_std": 0.0, "k": [1.0], "median_dn": [3.0]}, r"density \(fraction of sensor columns\) must be in \[0, 1\], got 1.2"),
    ("NoisyCol", {"seed": 1, "density": 0.01, "log_std": -0.5, "k": [1.0], "median_dn": [3.0]}, "log_std must be >= 0, got -0.5"),
    ("NoisyCol", {"density": 0.01, "log_std": 0.0, "k": [1.0], "median_dn": [3.0]}, "seed"),
    ("TapBlack", {"col_edges": [64], "row_edges": [], "k": [1.0], "sigma_dn": [0.5]}, "needs frame_h and frame_w"),
    ("TapBlack", {"col_edges": [64, 32], "row_edges": [], "frame_h": 64, "frame_w": 64, "k": [1.0], "sigma_dn": [0.5]},
     r"col_edges must be strictly increasing, got \[64, 32\]"),
    ("TapBlack", {"col_edges": [], "row_edges": [128], "frame_h": 64, "frame_w": 64, "k": [1.0], "sigma_dn": [0.5]},
     r"row_edges values must be whole sensor lines in \(0, 128\), got 128"),
    ("TapBlack", {"col_edges": list(range(8, 72, 8)), "row_edges": [], "frame_h": 64, "frame_w": 64, "k": [1.0], "sigma_dn": [0.5]},
     "col_edges must be a list of at most 7 sensor lines"),
    ("TapBlack", {"col_edges": [64], "row_edges": [], "frame_h": 64, "frame_w": 64, "k": [1.0], "sigma_dn": [-0.5]}, "sigma_dn must be >= 0"),
    ("TapGain", {"col_edges": [64], "row_edges": [], "gain": [[1.0, 1.01]]}, "needs frame_h and frame_w"),
    ("TapGain", {"col_edges": [64], "row_edges": [], "frame_h": 64, "frame_w": 64, "gain": [[1.0, 1.01, 1.0]]},
     r"gain must be 1 x 2 \(row taps x column taps\) finite gains > 0"),
    ("TapGain", {"col_edges": [64], "row_edges": [], "frame_h": 64, "frame_w": 64, "gain": [[1.0, 0.0]]}, "finite gains > 0"),
    ("TapGain", {"col_edges": [], "row_edges": [0], "frame_h": 64, "frame_w": 64, "gain": [[1.0], [1.0]]},
     r"row_edges values must be whole sensor lines in \(0, 128\), got 0"),
    ("TapGain", {"col_edges": [], "row_edges": [], "frame_h": 64, "frame_w": 64, "gain": [[1.0]], "sigma": 1}, "unknown keys"),
    ("DarkRTS", {"seed": 1, "density": 0.01, "high": 1.5, "median_e_per_s": 1.0, "log_std": 0.0}, r"high \(share of frames in the high state\) must be in \(0, 1\), got 1.5"),
    ("DarkRTS", {"seed": 1, "density": 0.01, "high": 0.5, "median_e_per_s": -2.0, "log_std": 0.0}, "median_e_per_s must be >= 0, got -2.0"),
    ("DarkCol", {"seed": 1, "density": 0.2, "median_e_per_s": 1.0, "log_std": 0.0}, r"density \(fraction of sensor columns\) must be in \[0, 0.1\], got 0.2"),
    ("DarkCol", {"seed": 1, "density": 0.01, "median_e_per_s": 1.0, "log_std": -0.1}, "log_std must be >= 0, got -0.1"),
    ("DarkOffset", {"k": [1.0], "dn_per_s": [float("inf")]}, "finite"),
    ("FrameGain", {"sigma": -0.01}, r"sigma \(fraction of the signal, per frame\) must be in \[0, 0.1\], got -0.01"),
    ("FrameNoise", {"k": [1.0], "log_std": [1.5]}, r"log_std \(spread of the log read-noise scale over frames\) must be in \[0, 1\], got 1.5"),
    ("ColRTS", {"seed": 1, "density": 0.01, "high": 0.0, "log_std": 0.0, "k": [1.0], "median_dn": [5.0]}, r"high \(share of frames in the high state\) must be in \(0, 1\), got 0.0"),
    ("ColRTS", {"density": 0.01, "high": 0.5, "log_std": 0.0, "k": [1.0], "median_dn": [5.0]}, "seed"),
    ("RowRTS", {"seed": 1, "density": 0.3, "high": 0.5, "log_std": 0.0, "k": [1.0], "median_dn": [5.0]}, r"density \(fraction of sensor rows\) must be in \[0, 0.1\], got 0.3"),
    ("RowRTS", {"seed": 1, "density": 0.01, "high": 1.0, "log_std": 0.0, "k": [1.0], "median_dn": [5.0]}, r"high \(share of frames in the high state\) must be in \(0, 1\), got 1.0"),
    ("Spikes", {"density": 0.5, "log_std": 0.0, "k": [1.0], "median_dn": [10.0]}, r"density \(fraction of pixels per frame\) must be in \[0, 0.01\], got 0.5"),
    ("Spikes", {"density": 0.0, "density_per_s": -1e-3, "log_std": 0.0, "k": [1.0], "median_dn": [10.0]}, "density_per_s"),
    ("DarkOffset", {"k": [1.0, 2.0], "dn_per_s": [1.0]}, "one value per k"),
    ("Dark", {"seed": 1, "k": [1.0], "rate_e_per_s": [1.0], "dsnu": [0.1], "channel": [1.0, 1.0, 1.0]},
     r"channel \(relative dark rates of R, G1, B, G2\) must be 4 numbers >= 0 with mean 1"),
    ("Dark", {"seed": 1, "k": [1.0], "rate_e_per_s": [1.0], "dsnu": [0.1], "channel": [2.0, 1.0, 1.0, 1.0]}, "with mean 1"),
    ("Dark", {"seed": 1, "k": [1.0], "rate_e_per_s": [1.0], "dsnu": [0.1], "channel": [-1.0, 2.0, 2.0, 1.0]}, "with mean 1"),
    ("DarkNoise", {"k": [1.0], "rate_dn2_per_s": [float("nan")]}, "finite"),
    ("ColGain", {"seed": 1, "sigma": 0.6}, r"sigma \(fraction of the signal\) must be in \[0, 0.5\), got 0.6"),
    ("ColGain", {"sigma": 0.01}, "seed"),
    ("RowGain", {"seed": 1, "frame": 0.6}, r"frame \(fraction of the signal\) must be in \[0, 0.5\), got 0.6"),
    ("RowGain", {"seed": 1}, "at least one of"),
    ("RowGain", {"seed": 1, "fixed": 0.01, "sigma": 0.01}, r"unknown keys \['sigma'\]"),
    ("RowGain", {"fixed": 0.01}, "seed"),
    ("DiagBand", {"k": [1.0], "freq_per_col": [[0.0]], "freq_per_row": [[0.0]], "amplitude_dn": [[1.0]]}, "not both 0, got"),
    ("DiagBand", {"k": [1.0], "freq_per_col": [[0.6]], "freq_per_row": [[0.1]], "amplitude_dn": [[1.0]]}, r"freq_per_col in \[0, 0.5\]"),
    ("DiagBand", {"k": [1.0], "freq_per_col": [[0.1, 0.2]], "freq_per_row": [[0.1]], "amplitude_dn": [[1.0]]}, "equal lists"),
    ("DiagBand", {"k": [1.0], "freq_per_col": [[0.1]], "freq_per_row": [[0.1]], "amplitude_dn": [[1.0]], "fixed_dn": [[-1.0]]}, "fixed_dn must be >= 0"),
    ("DiagBand", {"k": [1.0], "freq_per_col": [[0.1]], "freq_per_row": [[0.1]], "amplitude_dn": [[1.0]], "fixed_dn": [[1.0, 2.0]]}, "equal lists"),
    ("RowDrift", {"k": [1.0], "octave_dn": [[0.0] * 7]}, "octave_dn record 0 must list 8 values"),
    ("CodeMap", {"k": [1.0], "lo_dn": [0.0], "map_dn": [[0.0, 2.0, 2.0]], "period_dn": [4]}, r"period_dn\[0\] must be 0"),
    ("CodeMap", {"k": [1.0], "lo_dn": [0.0], "map_dn": [[0.0, 2.0, 2.0]], "period_dn": [1.5]}, "whole DN"),
    ("RowDrift", {"k": [1.0], "octave_dn": [[0.0] * 7 + [-1.0]]}, "finite and >= 0"),
    ("ReadMap", {"k": [1.0], "channel_dn": [[0.0] * 3], "row_block_dn": [[0.0] * 8], "col_block_dn": [[0.0] * 8]},
     "channel_dn record 0 must list 4 values"),
    ("ReadMap", {"k": [1.0], "channel_dn": [[0.0] * 4], "row_block_dn": [[-1.0] * 8], "col_block_dn": [[0.0] * 8]},
     "finite and >= 0"),
    ("Band", {"k": [1.0], "freq_per_row": [[0.1, 0.2]], "amplitude_dn": [[1.0]]}, "equal lists"),
    ("Band", {"k": [1.0], "freq_per_row": [[0.1, 0.2, 0.3, 0.4]], "amplitude_dn": [[1.0] * 4]}, "at most 3 tones"),
    ("ColBand", {"k": [1.0], "freq_per_col": [[0.0]], "amplitude_dn": [[1.0]]}, r"freq_per_col \(cycles per sensor column\) must be in \(0, 0.5\], got 0.0"),
    ("ColBand", {"k": [1.0], "freq_per_col": [[0.1]], "amplitude_dn": [[-1.0]]}, "amplitude_dn must be >= 0, got -1.0"),
    ("ColBand", {"k": [1.0], "freq_per_row": [[0.1]], "amplitude_dn": [[1.0]]}, "freq_per_col"),
    ("Xtalk", {"k": [1.0], "tap_0_1_dn": [1.0], "tap_3_0_dn": [1.0]}, r"unknown keys \['tap_3_0_dn'\]"),
    ("Xtalk", {"k": [1.0], "lag_0_1_dn": [1.0]}, "no longer an amplitude per lag: run rawaug loop again"),
    ("Xtalk", {"k": [1.0], "tap_0_1_dn": [float("nan")]}, "finite"),
])
def test_bad_effect_params_raise(token, params, match):
    with pytest.raises(ValueError, match=match):
        BASE.with_effect(token, params)


READ_MAP = {"k": [K], "channel_dn": [[0.0, 2.0, 0.0, 0.0]], "row_block_dn": [[0.0] * 8],
            "col_block_dn": [[0.0] * 4 + [1.5] * 4]}  # a noisy G1 amplifier; the right half read by a noisier one


def test_read_noise_map_adds_its_variance_where_it_says():
    f = synth({"ReadMap": READ_MAP}, batch=16, size=64, sigma_g=1.0)
    var = f.var(axis=0, ddof=1)  # (4, 64, 64) temporal variance, DN^2
    left, right = var[:, :, :32].mean(axis=(1, 2)), var[:, :, 32:].mean(axis=(1, 2))
    truth_left = 1.0 + np.array([0.0, 4.0, 0.0, 0.0])
    truth_right = truth_left + 2.25
    # each mean: 64 x 32 pixels x 15 degrees of freedom, relative sd of a variance sqrt(2 / 15) / sqrt(2048)
    sd = math.sqrt(2 / 15) / math.sqrt(64 * 32)
    assert np.all(np.abs(left / truth_left - 1) < 5 * sd), left
    assert np.all(np.abs(right / truth_right - 1) < 5 * sd), right


def test_read_noise_map_is_estimated_and_white_stacks_get_none():
    meas = synth({"ReadMap": READ_MAP}, batch=6, size=64, sigma_g=1.0)
    # the model as calibrated: one read noise, the frame's average variance
    avg = math.sqrt(1.0 + 4.0 / 4 + 2.25 / 2)
    base = [synth({}, batch=6, size=64, seed=s, sigma_g=avg) for s in range(1, 9)]
    est = read_map.combine([read_map.estimate(meas, base, K)])
    ch, cols, rows = np.square(est["channel_dn"][0]), np.square(est["col_block_dn"][0]), np.square(est["row_block_dn"][0])
    # a channel mean pools 64 x 64 pixels x 5 degrees of freedom (relative sd ~ 0.01 of ~3 DN^2 plus the
    # median's inefficiency), a run's mean 4 x 64 x 32 x 5: bounds of 0.35 DN^2 are several sd
    assert abs(ch[1] - 4.0) < 0.35 and np.all(ch[[0, 2, 3]] < 0.35), ch
    assert est["col_block_edges"] == [0.5], est  # the two halves, cut where they meet
    assert abs(cols[1] - 2.25) < 0.35 and cols[0] == 0.0 and np.all(cols[2:] == 0.0), cols
    assert np.all(rows == 0.0) and "row_block_edges" not in est, rows  # no row structure: the group is not significant
    # white stacks: a group is kept where an F-test gives p < 1e-3: 30 groups keep 2 or more with p ~ 4e-4
    white_base = [synth({}, batch=6, size=64, seed=s, sigma_g=1.0) for s in range(1, 9)]
    white = [read_map.combine([read_map.estimate(synth({}, batch=6, size=64, seed=s, sigma_g=1.0), white_base, K)])
             for s in range(20, 30)]
    kept = sum(any(v > 0 for v in w[key][0]) for w in white for key in ("channel_dn", "row_block_dn", "col_block_dn"))
    assert kept <= 2, white
    with pytest.raises(ValueError, match="bias stacks"):
        read_map.estimate(meas, base, K, level_dn=100.0)


def test_read_noise_map_blocks_at_measured_edges():
    # a noisy edge of the array: the first 12 packed columns (24 sensor columns) with 2 DN more;
    # the synthesis adds the variance at the edge it is given, and the estimate cuts the runs
    # there (not at a block of 1/8 of the frame), within a line, over 6 stacks, every one
    edge = {"k": [K], "channel_dn": [[0.0] * 4], "row_block_dn": [[0.0] * 8], "col_block_dn": [[2.0] + [0.0] * 7],
            "col_block_edges": [12 / 64]}
    f = synth({"ReadMap": edge}, batch=16, size=64, sigma_g=1.0)
    var = f.var(axis=0, ddof=1)
    sd = math.sqrt(2 / 15) / math.sqrt(4 * 64 * 12)  # relative sd of a mean variance over 12 columns
    assert abs(var[:, :, :12].mean() / 5.0 - 1) < 5 * sd and abs(var[:, :, 12:].mean() / 1.0 - 1) < 5 * sd
    avg = math.sqrt(1.0 + 4.0 * 12 / 64)
    base = [synth({}, batch=6, size=64, seed=s, sigma_g=avg) for s in range(1, 9)]
    for s in range(6):
        est = read_map.combine([read_map.estimate(synth({"ReadMap": edge}, batch=6, size=64, seed=50 + s, sigma_g=1.0), base, K)])
        cols = np.square(est["col_block_dn"][0])
        assert len(est["col_block_edges"]) == 1 and abs(est["col_block_edges"][0] * 64 - 12) <= 1, est
        assert abs(cols[0] - 4.0) < 0.8 and np.all(cols[1:] == 0.0), cols


def test_read_noise_map_cells_hold_a_region_of_its_own():
    # a damaged patch: rows 16..31 x columns 32..47 of 64 with 2 DN more. The synthesis puts the
    # variance in that cell alone; the estimate finds the blocks' edges and holds the patch in
    # its cell (not in a row block and a column block, which would make a cross), in 5 of 5
    # sessions; blocks whose levels add up (a noisy row block and a noisy column block) get no
    # cells in 30 of 30 (the interaction's chi-square at p 1e-3: about 0.03 expected)
    cells = np.zeros((8, 8))
    cells[1, 1] = 2.0
    patch = {"k": [K], "channel_dn": [[0.0] * 4], "row_block_dn": [[0.0] * 8], "col_block_dn": [[0.0] * 8],
             "row_block_edges": [0.25, 0.5], "col_block_edges": [0.5, 0.75], "cell_dn": [cells.tolist()]}
    var = synth({"ReadMap": patch}, batch=16, size=64, sigma_g=1.0).var(axis=0, ddof=1)
    sd = math.sqrt(2 / 15) / math.sqrt(4 * 16 * 16)  # relative sd of the patch's mean variance
    assert abs(var[:, 16:32, 32:48].mean() / 5.0 - 1) < 5 * sd, var[:, 16:32, 32:48].mean()
    assert abs(var[:, 16:32, :32].mean() - 1.0) < 5 * sd * 2 and abs(var[:, :16].mean() - 1.0) < 5 * sd * 2
    base = [synth({}, batch=6, size=64, seed=s, sigma_g=math.sqrt(1.0 + 4.0 / 16)) for s in range(1, 9)]
    for s in range(5):
        est = read_map.combine([read_map.estimate(synth({"ReadMap": patch}, batch=6, size=64, seed=50 + s, sigma_g=1.0), base, K)])
        assert est["row_block_edges"] == [0.25, 0.5] and est["col_block_edges"] == [0.5, 0.75], est
        got = np.square(est["cell_dn"][0])[:3, :3]
        # the patch's cell pools 16 x 16 x 4 pixels x 5 degrees of freedom: sd ~ 0.15 DN^2 of 4
        assert abs(got[1, 1] - 4.0) < 0.6 and np.delete(got.ravel(), 4).max() < 0.3, got
        assert not any(est["row_block_dn"][0]) and not any(est["col_block_dn"][0]), est
    add = {"k": [K], "channel_dn": [[0.0] * 4], "row_block_dn": [[0.0, 1.5] + [0.0] * 6],
           "col_block_dn": [[0.0, 0.0, 1.5] + [0.0] * 5], "row_block_edges": [0.25, 0.5], "col_block_edges": [0.5, 0.75]}
    base = [synth({}, batch=6, size=64, seed=s, sigma_g=math.sqrt(1.0 + 2.25 / 2)) for s in range(1, 9)]
    found = [read_map.combine([read_map.estimate(synth({"ReadMap": add}, batch=6, size=64, seed=100 + s, sigma_g=1.0), base, K)])
             for s in range(30)]
    assert all("cell_dn" not in e for e in found), [e.get("cell_dn") for e in found]
    assert sum(e.get("row_block_edges") == [0.25, 0.5] for e in found) >= 25, [e.get("row_block_edges") for e in found]
    with pytest.raises(ValueError, match="cell_dn must hold one 8 x 8 grid"):
        BASE.with_effect("ReadMap", {**patch, "cell_dn": [cells[:4].tolist()]})


def test_read_noise_map_segments_find_runs_and_no_more():
    # runs of one level in white noise of sd 1: the edges of steps of 3 sd over runs of 20 lines
    # or more are found within a line; a profile of noise alone stays one run (BIC), over 20 seeds each
    rng = np.random.default_rng(0)
    for _ in range(20):
        y = np.concatenate([np.zeros(40), np.full(30, 3.0), np.full(60, -1.0), np.full(20, 2.0)]) + rng.standard_normal(150)
        edges = read_map.segments([y], [1.0])
        assert len(edges) == 3 and np.all(np.abs(np.array(edges) - [40, 70, 130]) <= 1), edges
        assert read_map.segments([rng.standard_normal(150)], [1.0]) == []


def test_shared_pixel_noise_is_shared_by_a_tile_and_estimated():
    f = synth({"Shared": {"k": [K], "sigma_dn": [1.2]}}, batch=8, size=64, sigma_g=1.0)
    r = f - f.mean(axis=0, keepdims=True)
    n = f.shape[0] * 64 * 64
    # the four channels at one packed position share 1.44 of 2.44 DN^2: correlation 0.59 (sd ~ 1 / sqrt(n))
    corr = np.corrcoef(r[:, 0].ravel(), r[:, 2].ravel())[0, 1]
    assert abs(corr - 1.44 / 2.44) < 5 / math.sqrt(n), corr
    # neighbouring tiles do not share it: R at x and G1 at x - 1 (the left tile)
    assert abs(np.corrcoef(r[:, 0, :, 1:].ravel(), r[:, 1, :, :-1].ravel())[0, 1]) < 5 / math.sqrt(n)
    base = [synth({}, batch=8, size=64, seed=s, sigma_g=math.sqrt(2.44)) for s in range(1, 6)]
    est = shared_pixel.estimate(f, base, K)
    assert abs(est["sigma_dn"][0] ** 2 - 1.44) < 5 * 2.44 / math.sqrt(n), est  # a covariance of n pairs x 4 lags
    # coupling between all neighbours alike (Xtalk) is not a shared readout, and white noise is neither
    assert shared_pixel.estimate(synth({"Xtalk": XTALK}, batch=8, size=64, sigma_g=1.0), base, K)["sigma_dn"][0] == 0.0
    assert shared_pixel.estimate(synth({}, batch=8, size=64, seed=9, sigma_g=1.0), base, K)["sigma_dn"][0] == 0.0
    # Xtalk reads the pairs in different tiles: a shared readout leaves it (nearly) nothing; read
    # from all pairs, lags (0, 1), (1, 0), (1, 1), (1, -1) would get 0.72 DN^2 (|a| 0.85)
    xt = crosstalk.estimate(f, base, K)
    assert np.all(np.abs(crosstalk.autocovariance([xt[key][0] for key in crosstalk.KEYS])) < 0.09), xt


RTS = {"seed": 41, "density": 0.02, "high": 0.4, "log_std": 0.3, "k": [K], "median_dn": [20.0]}


def test_telegraph_pixels_jump_between_two_levels_and_are_estimated():
    f = synth({"RTS": RTS}, batch=12, size=64, sigma_g=1.0)
    where = (f.max(axis=0) - f.min(axis=0)) > 10.0  # a step of ~20 DN against 1 DN of read noise
    n = where.size
    # pixels that flicker: the density, less those high or low in all 12 frames (0.4^12 + 0.6^12 ~ 0.2 %)
    assert abs(where.mean() - 0.02) < 5 * math.sqrt(0.02 / n), where.mean()
    # the same pixels in every call (a fixed pattern), each in the high state in ~40 % of the frames
    g = synth({"RTS": RTS}, batch=12, size=64, sigma_g=1.0, seed=5)
    again = (g.max(axis=0) - g.min(axis=0)) > 10.0  # a pixel may sit in one state in all 12 frames, or a small step near 10 DN
    assert (where & again).sum() / (where | again).sum() > 0.95
    high = (f[:, where] - np.median(f, axis=0)[where] > 10.0) | (f[:, where] - f[:, where].min(axis=0) > 10.0)
    assert abs(high.mean() - 0.4) < 5 * math.sqrt(0.24 / high.size), high.mean()
    base = [synth({}, batch=12, size=64, seed=s, sigma_g=1.0) for s in range(1, 5)]
    est = telegraph.estimate(f, base, K)
    # ~330 pixels: density within ~3 sd (Poisson), median step within a few % (log sd 0.3 / sqrt(330))
    assert abs(est["density"] - 0.02) < 3 * math.sqrt(0.02 / n), est
    assert abs(est["median_dn"][0] / 20.0 - 1) < 0.05 and abs(est["log_std"] - 0.3) < 0.05, est
    assert abs(est["high"] - 0.4) < 0.05, est
    assert telegraph.estimate(base[0], base[1:], K)["density"] == 0.0  # white noise does not flicker
    with pytest.raises(ValueError, match="bias stacks"):
        telegraph.estimate(f, base, K, kind="dark")


NOISY_COL = {"seed": 101, "density": 0.05, "log_std": 0.2, "k": [K], "median_dn": [3.0]}


def test_noisy_columns_add_white_noise_along_whole_columns_and_are_estimated():
    from rawaug.statistics import col_flicker_fraction, column_pixel_noise, noisy_col_fraction, sensor_col_means

    f = synth({"NoisyCol": NOISY_COL}, batch=16, size=64)
    v = column_pixel_noise(f)  # (128,) sensor columns: the pixels' median temporal variance
    med = float(np.median(v))
    noisy = v > 3.0 * med  # 1 DN^2 of read noise; a noisy column's pixels have ~10
    n = noisy.size
    assert abs(noisy.mean() - 0.05) < 5 * math.sqrt(0.05 / n), noisy.mean()
    again = column_pixel_noise(synth({"NoisyCol": NOISY_COL}, batch=16, size=64, seed=5))
    assert np.array_equal(again > 3.0 * float(np.median(again)), noisy)  # the same columns in every call
    # white along the column: no column offset (the column means vary by the pixels' noise over
    # 128 of them), the pixels of a noisy column uncorrelated
    m = sensor_col_means(f)  # (16, 128)
    assert m[:, noisy].var(axis=0, ddof=1).mean() < 3 * (10.0 / 128)
    cols = np.flatnonzero(noisy)
    x = f[:, [0, 3]][..., cols[cols % 2 == 0] // 2]  # R and G2 of the even noisy sensor columns: (16, 2, 64, m)
    r = x - x.mean(axis=0)
    corr = float(np.mean(r[:, :, 1:] * r[:, :, :-1]) / np.mean(r**2))
    assert abs(corr) < 5 / math.sqrt(r[:, :, 1:].size), corr
    # the extra noise: log-normal about 3 DN, spread 0.2, over ~6 columns: median within 0.3
    extra = np.log(np.sqrt(v[noisy] * 15 / stats.chi2.median(15) - 1.0))
    assert abs(float(np.median(extra)) - math.log(3.0)) < 0.3
    assert noisy_col_fraction(f) == pytest.approx(noisy.mean())  # 6 robust sigmas: the same columns
    base = [synth({}, batch=8, size=64, seed=s) for s in range(1, 5)]
    est = noisy_columns.estimate(synth({"NoisyCol": NOISY_COL}, batch=8, size=64, seed=7), base, K)
    assert abs(est["density"] - noisy.mean()) <= 1 / n + 1e-12, est  # within one column of the pattern's
    assert abs(math.log(est["median_dn"][0] / 3.0)) < 0.3, est
    white = [noisy_columns.estimate(synth({}, batch=8, size=64, seed=s), base, K) for s in range(20, 30)]
    assert all(noisy_columns.empty(w) for w in white), white
    # telegraph columns (ColRTS) move the whole column: taken out with its frame means
    colrts = synth({"ColRTS": {"seed": 79, "density": 0.05, "high": 0.5, "log_std": 0.2, "k": [K], "median_dn": [6.0]}},
                   batch=8, size=64)
    assert noisy_col_fraction(colrts) == 0.0 and col_flicker_fraction(colrts) > 0.02
    with pytest.raises(ValueError, match="bias stacks"):
        noisy_columns.estimate(f, base, K, kind="dark")


def test_every_column_with_a_noise_of_its_own_is_estimated_as_a_spread():
    """Every sensor column's extra noise log-normal about 1 DN (spread 0.5 in log; 1 DN^2 of read
    noise, 16 frames of 256 sensor columns), in five sessions: density 1, median within 25 %,
    log spread within 0.15 (the quantiles of 256 columns, each a median of 15 degrees); the
    sparse noisy columns (5 %, 3 DN) and the white model's stacks stay as they were (a
    density under 0.1, and none); combined with a sparse stack's, the spread holds."""
    spread = {"seed": 103, "density": 1.0, "log_std": 0.5, "k": [K], "median_dn": [1.0]}
    base = [synth({}, batch=16, size=128, seed=s) for s in range(1, 4)]
    for session in range(5):
        est = noisy_columns.estimate(synth({"NoisyCol": spread}, batch=16, size=128, seed=40 + session), base, K)
        assert est["density"] == 1.0, est
        assert abs(math.log(est["median_dn"][0])) < math.log(1.25) and abs(est["log_std"] - 0.5) < 0.15, est
    sparse = noisy_columns.estimate(synth({"NoisyCol": NOISY_COL}, batch=16, size=128, seed=50), base, K)
    assert 0.0 < sparse["density"] <= 0.1, sparse
    # a gain whose read noise hides the spread sees its tail only, as sparse columns: the camera's spread holds
    both = noisy_columns.combine([sparse, est])
    assert both["density"] == 1.0 and both["median_dn"] == est["median_dn"] and both["log_std"] == est["log_std"], both
    for session in range(5):
        assert noisy_columns.empty(noisy_columns.estimate(synth({}, batch=16, size=128, seed=60 + session), base, K))


DARK_RTS = {"seed": 97, "density": 0.01, "high": 0.4, "median_e_per_s": 25.0, "log_std": 0.3}


def test_dark_telegraph_pixels_switch_their_dark_current_and_are_estimated():
    dark = {"model": "G+P*", "sigma_g": 2.0}
    assert not (synth({"DarkRTS": DARK_RTS}, batch=12, size=64, exposure_s=0.0, **dark).var(axis=0, ddof=1) > 30.0).any()
    f = synth({"DarkRTS": DARK_RTS}, batch=12, size=64, exposure_s=4.0, **dark)  # steps of ~100 e- (K = 1)
    spread = f.max(axis=0) - f.min(axis=0)
    where = spread > 50.0  # read noise 2 DN, shot noise of the step 10 DN: two states 100 DN apart
    n = where.size
    # the density, less those high or low in all 12 frames (0.4^12 + 0.6^12 ~ 0.2 %)
    assert abs(where.mean() - 0.01) < 5 * math.sqrt(0.01 / n), where.mean()
    high = f[:, where] > 0.5 * (f[:, where].max(axis=0) + f[:, where].min(axis=0))  # above the midpoint of its two states
    assert abs(high.mean() - 0.4) < 5 * math.sqrt(0.24 / high.size), high.mean()
    # the step grows with the exposure and is electrons: 4 x as large at 16 s, its variance in
    # the high state the step (shot noise, K = 1) plus the read noise's 4 DN^2
    g = synth({"DarkRTS": DARK_RTS}, batch=12, size=64, exposure_s=16.0, seed=3, **dark)
    again = g.max(axis=0) - g.min(axis=0) > 200.0
    assert (where & again).sum() / (where | again).sum() > 0.95  # the same pixels (a few sit in one state in all 12 frames)
    G = g[:, where & again]
    up = G > 0.5 * (G.max(axis=0) + G.min(axis=0))
    count = up.sum(axis=0)
    level = (G * up).sum(axis=0) / np.maximum(count, 1)  # each pixel's mean in its high frames: 16 s of its rate (K = 1)
    assert abs(float(np.median(np.log(level / 16.0))) - math.log(25.0)) < 5 * 0.3 * 1.25 / math.sqrt(level.size)
    # shot noise: the high frames' variance about their mean is the step in electrons plus the
    # read noise's 4 DN^2 (pooled over the pixels with two high frames or more)
    ok = count >= 2
    dof = int((count[ok] - 1).sum())
    ss = float((((G - level) * up)[:, ok] ** 2).sum())
    assert abs(ss / float(((count[ok] - 1) * (level[ok] + 4.0)).sum()) - 1.0) < 5 * math.sqrt(2 / dof), (ss, dof)
    low = G[~up]
    assert abs(low.var() - 4.0) < 5 * 4.0 * math.sqrt(2 / low.size)  # the low state: read noise only
    # round trip from 8 darks of 4 s, against the model's darks: ~160 pixels
    base = [synth({}, batch=8, size=64, seed=s, exposure_s=4.0, **dark) for s in range(1, 5)]
    meas = synth({"DarkRTS": DARK_RTS}, batch=8, size=64, exposure_s=4.0, seed=7, **dark)
    est = dark_telegraph.estimate(meas, base, K, exposure_s=4.0, kind="dark")
    assert abs(est["density"] - 0.01) < 3 * math.sqrt(0.01 / n / 0.5), est
    assert abs(math.log(est["median_e_per_s"] / 25.0)) < 0.1 and abs(est["log_std"] - 0.3) < 0.1, est
    assert abs(est["high"] - 0.4) < 0.1, est
    white = [dark_telegraph.estimate(synth({}, batch=8, size=64, seed=s, exposure_s=4.0, **dark), base, K, exposure_s=4.0,
                                     kind="dark") for s in range(20, 30)]
    assert all(dark_telegraph.empty(w) for w in white), white
    with pytest.raises(ValueError, match="dark stacks"):
        dark_telegraph.estimate(meas, base, K, exposure_s=4.0, kind="bias")
    both = dark_telegraph.combine([est, {**est, "density": 0.0}, {**est, "median_e_per_s": 4 * est["median_e_per_s"]}])
    assert both["density"] == est["density"] and both["median_e_per_s"] == pytest.approx(2 * est["median_e_per_s"])


NOISY = {"seed": 83, "density": 0.02, "log_std": 0.3, "k": [K], "median_dn": [6.0]}


def test_noisy_pixels_are_fixed_gaussian_and_estimated():
    f = synth({"Noisy": NOISY}, batch=40, size=64)
    var = f.var(axis=0, ddof=1)
    where = var > 4.0  # 1 DN^2 of read noise, chi-square of 39 degrees: no white pixel; every noisy one above 2 DN
    n = where.size
    assert abs(where.mean() - 0.02) < 5 * math.sqrt(0.02 / n), where.mean()
    again = synth({"Noisy": NOISY}, batch=40, size=64, seed=5).var(axis=0, ddof=1) > 4.0
    assert (where & again).sum() / (where | again).sum() > 0.95  # the same pixels in every call
    # unimodal and Gaussian, unlike a telegraph pixel's two states: the kurtosis of each pixel's
    # standardized values is a normal sample's, 3 (n - 1) / (n + 1) = 2.85 for n = 40
    z = (f[:, where] - f[:, where].mean(axis=0)) / f[:, where].std(axis=0, ddof=1)
    assert abs(float(np.mean(z**4)) - 3 * 39 / 41) < 5 * math.sqrt(24 / z.size), float(np.mean(z**4))
    logs = np.log(np.sqrt(var[where] - 1.0))  # the extra noise: log-normal about 6 DN, spread 0.3 (+ 0.11 of the sample variance)
    assert abs(float(np.median(logs)) - math.log(6.0)) < 5 * 0.32 * 1.25 / math.sqrt(logs.size)
    assert abs(float(logs.std()) - math.hypot(0.3, 0.5 * math.sqrt(2 / 39))) < 0.05
    # the estimate from 8 frames: about half the noisy pixels stand out and show no two states
    base = [synth({}, batch=8, size=64, seed=s) for s in range(1, 5)]
    est = noisy_pixels.estimate(synth({"Noisy": NOISY}, batch=8, size=64, seed=7), base, K)
    assert abs(est["density"] - 0.02) < 3 * math.sqrt(0.02 / n / 0.5), est  # ~160 pixels counted
    assert abs(math.log(est["median_dn"][0] / 6.0)) < 0.15 and abs(est["log_std"] - 0.3) < 0.1, est
    white = [noisy_pixels.estimate(synth({}, batch=8, size=64, seed=s), base, K) for s in range(20, 30)]
    assert all(noisy_pixels.empty(w) for w in white), white
    with pytest.raises(ValueError, match="bias stacks"):
        noisy_pixels.estimate(f, base, K, kind="dark")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_telegraph_steps_hidden_in_noise_take_the_population_of_the_clearest_stack(seed):
    """One telegraph population (1 % of the pixels, 20 DN steps of log spread 0.3) under read
    noise of 2, 4.6 and 9 DN (three ISOs). At 9 DN a stack sees ~1/10 of it, the steps the
    noise made larger: alone it estimates ~0.1 % of pixels with ~35 DN steps. Combined, the
    density comes from the 2 DN stack and each stack's step matches its detected fraction."""
    rng = np.random.default_rng(500 + seed)
    shape = (4, 96, 128)
    where = rng.random(shape) < 0.01
    size = 20.0 * np.exp(0.3 * rng.standard_normal(shape))
    records = []
    for j, sigma in enumerate((2.0, 4.6, 9.0)):
        frames = sigma * rng.standard_normal((8,) + shape) + where * size * (rng.random((8,) + shape) < 0.5)
        base = [sigma * rng.standard_normal(frames.shape) for _ in range(4)]
        records.append(telegraph.estimate(frames, base, 0.5 * 2**j, seed=40 + seed))
    assert records[2]["density"] < 0.004 and records[2]["median_dn"][0] > 28.0, records[2]  # alone: few and large
    got = telegraph.combine(records)
    n = where.size
    assert abs(got["density"] - 0.01) < 4 * math.sqrt(0.01 / n), got
    # the medians of ~500 steps (log sd 0.3 / sqrt(500) ~ 1.3 %), at 9 DN through a detection
    # fraction of ~1/10 (its binomial error ~ 1/sqrt(50) in the fraction, ~ 8 % in the step)
    assert np.all(np.abs(np.array(got["median_dn"]) / 20.0 - 1.0) < [0.05, 0.08, 0.2]), got
    assert "_detection" not in got and got["k"] == [0.5, 1.0, 2.0]


def test_every_pixel_with_a_read_noise_of_its_own_is_estimated_as_a_spread():
    """Every pixel an extra read noise of 1.5 DN x a log-normal of 0.4 over 2 DN of white noise,
    against syntheses whose read noise holds their mean (as calibration's does), 8 frames of
    4 x 128 x 128, 5 sessions: density 1, the log spread within 0.1 and the median within 20 %
    in 5 of 5 (measured: 0.35 to 0.41, 1.48 to 1.69 DN; the spread and the median trade off over
    8 frames' chi-square); the same frames without it give no spread in 10 of 10 (before, only
    the tail was seen, as sparse noisy pixels, or nothing); sparse noisy pixels stay sparse."""
    spread = {"seed": 83, "density": 1.0, "log_std": 0.4, "k": [K], "median_dn": [1.5]}
    total = math.sqrt(4.0 + 1.5**2 * math.exp(2 * 0.4**2))
    for session in range(5):
        base = [synth({}, batch=8, size=128, sigma_g=total, seed=200 + 10 * session + i) for i in range(4)]
        est = noisy_pixels.estimate(synth({"Noisy": spread}, batch=8, size=128, sigma_g=2.0, seed=20 + session), base, K)
        assert est["density"] == 1.0 and abs(est["log_std"] - 0.4) < 0.1, est
        assert abs(est["median_dn"][0] / 1.5 - 1.0) < 0.2, est
    base = [synth({}, batch=8, size=128, sigma_g=total, seed=300 + i) for i in range(4)]
    plain = [noisy_pixels.estimate(synth({}, batch=8, size=128, sigma_g=total, seed=60 + s), base, K) for s in range(10)]
    assert all(e["density"] < 1.0 for e in plain), plain
    sparse = {"seed": 83, "density": 0.02, "k": [K], "median_dn": [6.0], "log_std": 0.3}
    # a sparse population (2 % at 6 DN over 2 and over 4 DN of read noise) raises the halves' log
    # covariance (0.02 to 0.07: alone, it would call every one of these dense) but not the bulk's:
    # sparse in 10 of 10, its density within 0.03
    for sigma_g in (2.0, 4.0):
        for session in range(5):
            base = [synth({}, batch=8, size=128, sigma_g=sigma_g, seed=400 + 10 * session + i) for i in range(4)]
            est = noisy_pixels.estimate(synth({"Noisy": sparse}, batch=8, size=128, sigma_g=sigma_g, seed=30 + session), base, K)
            assert est["density"] < 1.0 and abs(est["density"] - 0.02) < 0.03, est
    joined = noisy_pixels.combine([sparse, {**spread, "k": [3.0], "median_dn": [3.0]}, {**spread, "median_dn": [1.4]}])
    assert joined["density"] == 1.0 and joined["k"] == [K, 3.0] and np.allclose(joined["median_dn"], [1.4, 3.0]), joined

def test_noisy_fraction_tells_noisy_pixels_from_telegraph_pixels():
    """Of the pixels of high temporal variance in 8 frames, about half of the noisy ones show no
    two states and stay high without their most extreme value (``noisy_fraction``); telegraph
    pixels show two states, or (high or low in all but one frame) are not high without it."""
    from rawaug.statistics import flicker_fraction, noisy_fraction

    noisy = synth({"Noisy": NOISY}, batch=8, size=64)
    rts = synth({"RTS": {**RTS, "high": 0.5}}, batch=8, size=64)
    n = noisy[0].size
    assert noisy_fraction(noisy) > 0.3 * 0.02 and flicker_fraction(noisy) > 0.3 * 0.02
    assert noisy_fraction(rts) < 0.15 * flicker_fraction(rts) and flicker_fraction(rts) > 0.8 * 0.02
    white = synth({}, batch=8, size=64)
    assert noisy_fraction(white) <= 2 / n and flicker_fraction(white) <= 2 / n  # 1e-6 of a white pixel


DEAD = {"seed": 47, "density": 0.01, "levels_dn": [-40.0, -40.0, -40.0, 300.0]}  # 3/4 stuck low, 1/4 stuck high


def test_dead_pixels_are_stuck_at_their_levels_and_estimated():
    f = synth({"Dead": DEAD}, batch=6, size=64, level_dn=200.0, sigma_g=1.0)
    stuck, levels = stuck_pixels(f)
    n = stuck.size
    # pixels at one value in all 6 frames: the dead ones (shot and read noise of ~14 DN leave no other)
    assert abs(stuck.mean() - 0.01) < 5 * math.sqrt(0.01 / n), stuck.mean()
    assert set(np.unique(levels)) == {-40.0, 300.0}
    assert abs(np.mean(levels == 300.0) - 0.25) < 5 * math.sqrt(0.25 * 0.75 / levels.size)
    again = stuck_pixels(synth({"Dead": DEAD}, batch=6, size=64, level_dn=200.0, sigma_g=1.0, seed=3))[0]
    assert np.array_equal(stuck, again)  # a fixed pattern: the same pixels in every call
    base = [synth({}, batch=6, size=64, level_dn=200.0, seed=s, sigma_g=1.0) for s in range(1, 4)]
    est = dead_pixels.estimate(f, base, K)
    assert abs(est["density"] - 0.01) < 5 * math.sqrt(0.01 / n), est
    assert sorted(set(est["levels_dn"])) == [-40.0, 300.0] and est["levels_dn"].count(300.0) == 2, est
    with pytest.raises(ValueError, match="shows no dead pixels"):  # live pixels move
        dead_pixels.estimate(base[0], base[1:], K)
    with pytest.raises(ValueError, match=">= 2 frames"):
        dead_pixels.estimate(f[:1], base, K)


def test_dead_pixels_at_black_are_measured_on_a_flat_pair():
    # a pixel dead at black hides in bias and dark frames and shows in flats only; flat pairs
    # (EMVA 1288's protocol, the issue's manifests) were below the 3 frames the statistic and
    # the estimator asked for, so the loop never saw them. A flat's shot noise (~17 DN here)
    # keeps a live pixel far from the noise from reading one value twice
    from rawaug.statistics import STATISTICS

    assert STATISTICS["stuck_fraction"].applies(2, "flat")
    at_black = {"seed": 47, "density": 0.005, "levels_dn": [0.0]}
    f = synth({"Dead": at_black}, batch=2, size=64, level_dn=300.0, model="G+P", sigma_g=2.0)
    n = f[0].size
    base = [synth({}, batch=2, size=64, level_dn=300.0, model="G+P", sigma_g=2.0, seed=s) for s in range(1, 4)]
    est = dead_pixels.estimate(f, base, K)
    assert abs(est["density"] - 0.005) < 5 * math.sqrt(0.005 / n) and est["levels_dn"] == [0.0] * 8, est
    # counted once: the other statistics read the pair with its dead pixels repaired
    assert (f == 0.0).all(axis=0).sum() > 0 and not np.any(repaired(f) == 0.0)
    # ELD-model flat pairs: no dead pixel found in 10 of 10 (a live pixel 5 robust sigma out and
    # equal in both frames: about 1e-7 of the pixels)
    for seed in range(10, 20):
        pair = synth({}, batch=2, size=64, level_dn=300.0, model="G+P", sigma_g=2.0, seed=seed)
        with pytest.raises(ValueError, match="shows no dead pixels"):
            dead_pixels.estimate(pair, base, K)


DEAD_LINES = {"seed": 5, "density": 0.002, "levels_dn": [-40.0], "col_density": 0.04, "row_density": 0.02, "partial": 0.5,
              "to_end": 0.75, "cut_lo": 0.2, "cut_hi": 0.8}  # broken column and row buses: half of the lines dead from a break on


def test_dead_lines_whole_and_partial_are_estimated():
    """Dead lines over 8 sensor instances (256 sensor columns and rows each): the pooled line
    counts within 4 Poisson sd, the shares partial and reaching the end within 4 binomial sd,
    the isolated pixels' density within 5 Poisson sd, the breaks' range within 0.05 of the
    planted one (its ends' error ~ range / partial lines, ~0.01 here); dead pixels alone (1 %)
    make no line in 10 of 10 stacks."""
    est = [dead_pixels.estimate(synth({"Dead": DEAD_LINES}, batch=4, size=128, sigma_g=2.0, sensor=s), [], K)
           for s in range(8)]
    lines = 8 * 256
    for key in ("col_density", "row_density"):
        n = sum(e[key] for e in est) * 256  # lines found
        assert abs(n - DEAD_LINES[key] * lines) < 4 * math.sqrt(DEAD_LINES[key] * lines), (key, n)
    found = [dead_pixels.dead_parts(synth({"Dead": DEAD_LINES}, batch=4, size=128, sigma_g=2.0, sensor=s))[2]
             for s in range(8)]
    n_lines, partial, to_end = sum(f[4] for f in found), sum(f[2] for f in found), sum(f[3] for f in found)
    assert abs(partial / n_lines - 0.5) < 4 * math.sqrt(0.25 / n_lines), (partial, n_lines)
    assert abs(to_end / partial - 0.75) < 4 * math.sqrt(0.75 * 0.25 / partial), (to_end, partial)
    cuts = dead_pixels.cut_range(np.concatenate([f[5] for f in found]))
    assert abs(cuts["cut_lo"] - 0.2) < 0.05 and abs(cuts["cut_hi"] - 0.8) < 0.05, cuts
    pixels = 8 * 4 * 128 * 128
    density = np.mean([e["density"] for e in est])
    assert abs(density - 0.002) < 5 * math.sqrt(0.002 / pixels), density
    assert all(e["levels_dn"] == [-40.0] * 8 for e in est)
    alone = [dead_pixels.estimate(synth({"Dead": {**DEAD, "seed": 60 + s}}, batch=4, size=128, sigma_g=2.0), [], K)
             for s in range(10)]
    assert not any("col_density" in e for e in alone) and all(e["density"] > 0.005 for e in alone)


def test_impulses_count_once_as_impulses():
    """Cosmic-ray-like impulses (300 DN over 1 DN of noise, 0.1 % of the values) are seen by the
    impulse statistics only: line, hot-pixel and tail statistics read them replaced."""
    from rawaug.statistics import (hot_fraction, spike_fraction, statistic_view, with_impulses, without_impulses,
                                   without_outliers)

    big = {**SPIKES, "density_per_s": 0.0, "median_dn": [300.0], "log_std": 0.3}
    clean = synth({}, batch=6, size=64, seed=4)
    f = synth({"Spikes": big}, batch=6, size=64, seed=4)
    assert defect_line_fraction(without_stuck(f)) > 0.02  # the line means a 300 DN value moves by 5 DN
    assert defect_line_fraction(statistic_view("defect_lines", f)) <= defect_line_fraction(clean) + 2 / 1536
    assert hot_fraction(repaired(f)) <= 2 / (4 * 64 * 64) and tail_mass(repaired(f)) < 1e-3
    assert spike_fraction(statistic_view("spike_fraction", f)) > 5e-4 and tail_mass(with_impulses(f)) > 5e-4
    assert np.abs(without_outliers(f) - clean).max() < 10.0  # each replaced by its pixel's median
    # heavy-tailed read noise without impulses (Tukey lambda -0.3: bright and dark extremes alike):
    # nothing replaced, in every one of 20 stacks (a 5-sd rule: expected false rate ~3e-7 each)
    untouched = [without_impulses(g) is g for g in
                 (synth({}, batch=6, size=64, seed=s, model="G*", sigma_tl=1.0, **{"lambda": -0.3}) for s in range(40, 60))]
    assert all(untouched), untouched.count(False)


def test_impulses_replaced_in_an_even_stack_keep_whole_codes():
    """An impulse is replaced by a value its pixel read (an even stack's median, the mean of two
    codes, is a half code): whole codes stay whole, and the code statistics still read them
    (before, one replaced impulse made ``code_dnl`` 0 on every synthesis of a camera)."""
    from rawaug.statistics import code_dnl, statistic_view, without_impulses

    big = {**SPIKES, "density_per_s": 0.0, "median_dn": [300.0], "log_std": 0.3}
    f = np.rint(synth({"Spikes": big}, batch=8, size=64, seed=4, sigma_g=3.0))
    clean = np.rint(synth({}, batch=8, size=64, seed=4, sigma_g=3.0))
    assert without_impulses(f) is not f  # impulses were replaced
    view = statistic_view("code_dnl", f)
    assert np.array_equal(view, np.rint(view))
    assert abs(code_dnl(view) - code_dnl(statistic_view("code_dnl", clean))) < 0.3, (code_dnl(view), code_dnl(clean))


def test_dead_pixels_count_once_and_clipped_pixels_are_not_dead():
    f = synth({"Dead": DEAD}, batch=6, size=64, sigma_g=1.0)
    # every other statistic reads the frames with their dead pixels replaced by live neighbours
    assert stuck_fraction(f) > 0.005 and stuck_fraction(without_stuck(f)) == 0.0
    assert tail_mass(f) > 0.005 and tail_mass(repaired(f)) < 1e-3
    # a bias stack clipped at 0 DN: pixels at the clip in every frame are clipped, not dead
    clipped = np.maximum(synth({}, batch=6, size=64, sigma_g=1.0), 0.0)
    assert np.mean(np.all(clipped == 0.0, axis=0)) > 0.01  # (1/2)^6: ~1.6 % of the pixels
    assert stuck_fraction(clipped) == 0.0
    # dead pixels at that clip level are not told apart in a bias stack; in a flat they are
    dead_at_clip = np.maximum(synth({"Dead": {"seed": 5, "density": 0.01, "levels_dn": [0.0]}}, batch=6, size=64,
                                    level_dn=300.0, sigma_g=1.0), 0.0)
    assert abs(stuck_fraction(dead_at_clip) - 0.01) < 5 * math.sqrt(0.01 / dead_at_clip[0].size)
    # a dead column is a defect line, not 64 dead pixels: the battery counts it once, as a line
    column = synth({}, batch=6, size=64, sigma_g=1.0)
    column[:, 1, :, 10] = -500.0
    assert stuck_fraction(column) == 0.0 and defect_line_fraction(column) > 0.0


DRIFT = {"k": [K], "octave_dn": [[0.0, 0.3, 0.5, 0.8, 1.0, 0.0, 0.0, 0.0]]}  # a 1/f-like drift, 1.3 DN rms


@pytest.mark.parametrize("token, module, axis, line_means", [("RowDrift", row_drift, "row", sensor_row_means),
                                                            ("ColDrift", column_drift, "col", sensor_col_means)])
def test_line_drift_is_shared_by_nearby_lines_and_its_spectrum_estimated(token, module, axis, line_means):
    f = synth({token: DRIFT}, batch=8, size=64, sigma_g=1.0)
    lines = line_means(f)  # (8, 128): per-frame sensor-line offsets plus read noise / 128
    lines = lines - lines.mean(axis=1, keepdims=True)
    lag1 = np.mean(lines[:, 1:] * lines[:, :-1]) / np.mean(lines**2)
    assert lag1 > 0.8, lag1  # neighbouring lines share their offsets (white line noise: ~0 +- 0.03)
    # variance of one octave's field: nodes of unit std every s lines (2^(j + 1) for RowDrift,
    # 2^j for ColDrift), linear between: 2/3 + 1/(3 s^2) of a_j^2
    first = 1 if token == "RowDrift" else 0
    variance = lambda octave: sum(a * a * (2 / 3 + 1 / (3 * (1 << (j + first)) ** 2)) for j, a in enumerate(octave))  # noqa: E731
    var = variance(DRIFT["octave_dn"][0])
    total = np.mean(line_means(f).var(axis=0, ddof=1))  # about the stack mean: the drift and read noise / 128
    assert abs(total - var - 1 / 128) < 0.35 * var, (total, var)  # 8 frames of a field with few independent nodes
    other = (sensor_col_means if axis == "row" else sensor_row_means)(f)
    other = other - other.mean(axis=1, keepdims=True)  # less each frame's mean (the drift's mean over the lines)
    assert np.mean(other**2) < 1.5 / 128  # nothing along the other axis: read noise / 128 (chi-square, 8 x 127 dof: sd 4 %)
    base = [synth({}, batch=8, size=64, seed=s, sigma_g=1.0) for s in range(1, 7)]
    # the octaves overlap in frequency, so their total variance is what is checked: over 6
    # stacks (one stack's estimate spreads by about 25 %: 4 nodes of the coarsest octave per frame)
    ratios = [variance(module.estimate(synth({token: DRIFT}, batch=8, size=64, seed=s, sigma_g=1.0), base, K)["octave_dn"][0]) / var
              for s in range(20, 26)]
    assert abs(np.mean(ratios) - 1) < 0.4, ratios  # the mean of 6: sd about 0.1
    # white stacks: the fit is kept where it beats none at p < 1e-3
    kept = 0
    for s in range(40, 60):
        try:
            module.estimate(synth({}, batch=8, size=64, seed=s, sigma_g=1.0), base, K)
            kept += 1
        except ValueError as e:
            assert f"no {axis} drift" in str(e)
    assert kept <= 1, kept
    with pytest.raises(ValueError, match="bias and dark stacks"):
        module.estimate(f, base, K, level_dn=100.0)


def test_white_column_noise_is_col_not_a_column_drift():
    # ColDrift's octave 0 is a white offset per column: a white excess alone is Col's, so the
    # drift is kept only where its coarser octaves beat that octave alone at p < 1e-3
    base = [synth({}, batch=8, size=64, seed=s, sigma_g=1.0) for s in range(1, 7)]
    kept = 0
    for s in range(60, 70):
        white = synth({"Col": {"seed": 3, "k": [K], "sigma_dn": [1.0], "fixed_dn": [0.0]}}, batch=8, size=64, seed=s, sigma_g=1.0)
        try:
            column_drift.estimate(white, base, K)
            kept += 1
        except ValueError as e:
            assert "no col drift" in str(e)
    assert kept <= 1, kept  # 0.01 expected in 10


TAPS = {"col_edges": [37], "row_edges": [40], "frame_h": 32, "frame_w": 32, "k": [K], "sigma_dn": [1.0]}  # quadrants


def _sensor(f):
    """(N, 2h, 2w) raw mosaics of packed frames (N, 4, h, w)."""
    n, _, h, w = f.shape
    raw = np.empty((n, 2 * h, 2 * w))
    for c in range(4):
        raw[:, ROW_SET[c]::2, COLUMN_SET[c]::2] = f[:, c]
    return raw


def test_readout_taps_offset_each_tap_in_each_frame():
    # 1e-3 DN of read noise: the frames are the taps' offsets
    raw = _sensor(synth({"TapBlack": TAPS}, batch=400, size=32, sigma_g=1e-3))
    quads = [raw[:, :40, :37], raw[:, :40, 37:], raw[:, 40:, :37], raw[:, 40:, 37:]]
    assert max(np.abs(q - q.mean(axis=(1, 2), keepdims=True)).max() for q in quads) < 0.01  # one value per tap and frame
    c = np.cov(np.stack([q.mean(axis=(1, 2)) for q in quads]))
    n = raw.shape[0]
    assert np.all(np.abs(np.diag(c) - 1.0) < 5 * math.sqrt(2 / (n - 1))), c  # sigma_dn 1: variance 1 per tap
    off = c[~np.eye(4, dtype=bool)]
    assert np.all(np.abs(off) < 5 / math.sqrt(n)), c  # independent taps
    # an input smaller than the frame is a window of it: its edges where the window puts them
    small = _sensor(synth({"TapBlack": TAPS}, batch=64, size=16, sigma_g=1e-3))
    cols = {int(j) + 1 for r in small for j in np.flatnonzero(np.abs(np.diff(r[0])) > 0.1)}
    rows = {int(j) + 1 for r in small for j in np.flatnonzero(np.abs(np.diff(r[:, 0])) > 0.1)}
    assert len(cols) > 3 and all(j % 2 == 1 for j in cols), cols  # the odd sensor column 37 - 2 x offset
    assert len(rows) > 3 and all(j % 2 == 0 for j in rows), rows


def test_readout_taps_are_found_and_estimated():
    from rawaug.statistics import sensor_col_means, tap_edges, tap_step_ratio

    base = [synth({}, batch=32, size=64, seed=s) for s in range(1, 4)]
    two = {**TAPS, "row_edges": [], "frame_h": 64, "frame_w": 64, "col_edges": [61]}
    f = synth({"TapBlack": two}, batch=32, size=64, seed=5)
    assert tap_edges(sensor_col_means(f)) == [61]
    assert tap_step_ratio(f) > 20 * max(tap_step_ratio(b) for b in base)
    est = tap_black.estimate(f, base, K, kind="bias")
    seen = est.pop("_seen")
    assert est["col_edges"] == [61] and est["row_edges"] == [] and seen["edges"]["col"] == [61]
    # sigma^2 from 32 frames and 2 taps: the variance of the taps' difference, 31 degrees of freedom
    assert abs(est["sigma_dn"][0] ** 2 - 1.0) < 5 * math.sqrt(2 / 31), est
    quads = tap_black.estimate(synth({"TapBlack": {**TAPS, "frame_h": 64, "frame_w": 64}}, batch=32, size=64, seed=6),
                               base, K, kind="dark")
    assert quads["col_edges"] == [37] and quads["row_edges"] == [40], quads
    assert abs(quads["sigma_dn"][0] ** 2 - 1.0) < 5 * math.sqrt(2 / 31), quads
    # over stacks: an edge one stack of three finds is not the sensor's; the offsets per gain
    low = tap_black.estimate(synth({"TapBlack": {**two, "sigma_dn": [0.5]}}, batch=32, size=64, seed=7), base, K, kind="bias")
    one = tap_black.estimate(synth({"TapBlack": {**two, "col_edges": [20]}}, batch=32, size=64, seed=8), base, 2 * K, kind="bias")
    both = tap_black.combine([{**est, "_seen": seen}, low, one])
    assert both["col_edges"] == [61] and both["k"] == [K, 2 * K], both
    assert abs(both["sigma_dn"][0] ** 2 - (1.0 + 0.25) / 2) < 5 * math.sqrt(2 / 31) / 2, both
    # ELD-model stacks: no edge in 20 seeds
    white = [tap_black.estimate(synth({}, batch=8, size=64, seed=s), base, K, kind="bias") for s in range(20, 40)]
    assert all(tap_black.empty(w) for w in white), [w["col_edges"] + w["row_edges"] for w in white]
    with pytest.raises(ValueError, match="bias or dark stacks of >= 3 frames"):
        tap_black.estimate(f, base, K, kind="flat")
    with pytest.raises(ValueError, match="bias or dark stacks of >= 3 frames"):
        tap_black.estimate(f[:2], base, K, kind="bias")


GAINS = {"col_edges": [37], "row_edges": [40], "frame_h": 32, "frame_w": 32, "gain": [[0.97, 1.01], [1.02, 1.0]]}


def test_readout_taps_gain_the_pixels_signal_and_noise():
    # shot noise only (1e-3 DN of read noise): a tap's mean is its gain times the level, its variance the gain squared times K level
    level = 2000.0
    raw = _sensor(synth({"TapGain": GAINS}, batch=64, size=32, level_dn=level, model="P", sigma_g=1e-3))
    quads = {(0, 0): raw[:, :40, :37], (0, 1): raw[:, :40, 37:], (1, 0): raw[:, 40:, :37], (1, 1): raw[:, 40:, 37:]}
    for (i, j), q in quads.items():
        g = GAINS["gain"][i][j]
        n = q.size
        var = g * g * K * level
        assert abs(q.mean() - g * level) < 5 * math.sqrt(var / n), (i, j, q.mean())
        assert abs(q.var() / var - 1.0) < 5 * math.sqrt(2 / n), (i, j, q.var() / var)
    # ... and the read noise alike (the tap's chain amplifies the pixel's noise), but not the rows' offsets
    dark = _sensor(synth({"TapGain": GAINS}, batch=64, size=32, model="G+R", sigma_g=2.0, sigma_r=1.5))
    rows = dark.mean(axis=2, keepdims=True)  # each frame's sensor-row offsets (and the row's share of the read noise)
    for (i, j), q in {(0, 0): (slice(0, 40), slice(0, 37)), (1, 1): (slice(40, 64), slice(37, 64))}.items():
        g = GAINS["gain"][i][j]
        r = (dark - rows)[:, q[0], q[1]]
        n = r.size
        assert abs(r.var() / (g * g * 4.0 * (1 - 1 / 64)) - 1.0) < 5 * math.sqrt(2 / n), (i, j, r.var())
    # an input smaller than the frame is a window of it: its column edge where the window puts it (odd)
    small = _sensor(synth({"TapGain": {**GAINS, "row_edges": [], "gain": [[0.5, 1.5]]}}, batch=32, size=16, level_dn=level,
                          model="G", sigma_g=1e-3))
    cols = {int(j) + 1 for r in small for j in np.flatnonzero(np.abs(np.diff(r[0])) > 0.5 * level)}
    assert len(cols) > 3 and all(j % 2 == 1 for j in cols), cols


def _light(size):
    """(4, size, size) a vignetting light (30 % down in the far corner) at each channel's sensor positions, mean 1."""
    light = np.empty((4, size, size))
    for c in range(4):
        y, x = np.meshgrid((2 * np.arange(size) + ROW_SET[c]) / (size - 0.5) - 1, (2 * np.arange(size) + COLUMN_SET[c]) / (size - 0.5) - 1,
                           indexing="ij")
        light[c] = 1.0 - 0.15 * ((x - 0.3) ** 2 + (y + 0.2) ** 2)
    return light / light.mean()


def _lit(effects, seed, level=3000.0, n=4, size=96):
    """A flat stack under ``_light``: (N, 4, size, size) DN."""
    prof = BASE
    for token, params in effects.items():
        prof = prof.with_effect(token, params)
    light = _light(size)
    aug = RawNoiseAugment(prof, model="G+P", ratio=1.0, fixed={"k": K, "sigma_g": 1.0, "sensor": 0},
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    clean = torch.from_numpy(np.broadcast_to(level * light / prof.span_dn, (n, 4, size, size)).copy())
    return (aug(clean) * prof.span_dn).numpy()


def test_readout_taps_gains_are_found_and_estimated():
    from rawaug.loop.illumination import illumination_shape
    from rawaug.statistics import gain_step_z

    halves = {"col_edges": [97], "row_edges": [], "frame_h": 96, "frame_w": 96, "gain": [[0.99, 1.01]]}
    base = [_lit({}, s) for s in range(1, 5)]
    f = _lit({"TapGain": halves}, 9)
    # the edge test's threshold (1e-3 over the 2 x 192 gaps of both axes): the lit ELD flats below it, the 2 % step far above
    threshold = stats.norm.isf(1e-3 / (2 * 2 * 192))
    assert max(gain_step_z(b) for b in base) < threshold < gain_step_z(f) / 5
    est = tap_gain.estimate(f, base, K, kind="flat")
    seen = est.pop("_seen")
    assert est["col_edges"] == [97] and est["row_edges"] == [] and seen["edges"]["col"] == [97], est
    # the step's noise: shot noise of 3000 e- over 192 rows and 4 frames per sensor column, 0.67 of it in a 32-line step
    se = 0.67 * math.sqrt(1 / 3000 / (192 * 4))
    ratio = est["gain"][0][1] / est["gain"][0][0]
    assert abs(math.log(ratio) - math.log(1.01 / 0.99)) < 5 * se, ratio
    # quadrants
    quads = {**GAINS, "col_edges": [121], "row_edges": [80], "frame_h": 96, "frame_w": 96}
    q = tap_gain.estimate(_lit({"TapGain": quads}, 10), base, K, kind="flat")
    assert q["col_edges"] == [121] and q["row_edges"] == [80], q
    truth = np.log(quads["gain"]) - np.log(quads["gain"])[0, 0]  # the ratios to one tap
    assert np.all(np.abs(np.log(q["gain"]) - np.log(q["gain"])[0, 0] - truth) < 5 * 2 * se), q["gain"]
    # taps of unequal sizes (rows 0-79 and 80-191, columns 0-120 and 121-191): a flat keeps its
    # level, the gains' mean over the pixels is 1 (their plain mean of 1 made the flats 0.7 %
    # too bright under a band of 40 rows of 192)
    area = np.outer([80, 112], [121, 71])
    assert abs(float(np.sum(area * np.asarray(q["gain"])) / area.sum()) - 1.0) < 1e-5, q["gain"]
    # the light is fitted with the taps' steps divided out: as close to the true light as without taps
    # (a smooth fit of the 2 % step would miss it by about 1 % rms)
    light = _light(96)
    light /= light.mean(axis=(1, 2), keepdims=True)
    plain = max(float((illumination_shape(b.mean(axis=0)) / light - 1).std()) for b in base)
    assert (illumination_shape(f.mean(axis=0)) / light - 1).std() < 1.5 * plain, plain
    # over stacks: an edge one stack of three finds is not the sensor's
    other = tap_gain.estimate(_lit({"TapGain": {**halves, "col_edges": [61]}}, 11), base, K, kind="flat")
    both = tap_gain.combine([{**est, "_seen": seen}, tap_gain.estimate(_lit({"TapGain": halves}, 12), base, K, kind="flat"), other])
    assert both["col_edges"] == [97], both
    # ELD-model flats under the light: no edge in 20 seeds
    white = [tap_gain.estimate(_lit({}, s), base, K, kind="flat") for s in range(20, 40)]
    assert all(tap_gain.empty(w) for w in white), [w["col_edges"] + w["row_edges"] for w in white]
    with pytest.raises(ValueError, match="measured on flat stacks"):
        tap_gain.estimate(f, base, K, kind="bias")


WEAK = {"seed": 31, "row_density": 0.0, "col_density": 0.05, "median": 0.08, "log_std": 0.0, "negative": 1.0}


def test_gain_defect_lines_dim_their_lines_in_proportion_to_the_signal():
    # 16 sensors (a pattern each) of 256 sensor columns: the share of 8 % dimmer columns, binomial
    level = 2000.0
    prof = BASE.with_effect("LineGain", {**WEAK, "col_density": 0.1, "row_density": 0.02})
    aug = RawNoiseAugment(prof, model="G", ratio=1.0, fixed={"k": K, "sigma_g": 1e-3}, generator=torch.Generator().manual_seed(3))
    raw = _sensor((aug(torch.full((16, 4, 128, 128), level / prof.span_dn, dtype=torch.float64)) * prof.span_dn).numpy())
    cols = np.median(raw, axis=1) / level  # (16, 256): a column's gain (rows' defects left out by the median)
    rows = np.median(raw, axis=2) / level
    assert np.all((np.abs(cols - 1.0) < 1e-3) | (np.abs(cols - 0.92) < 1e-3)), np.unique(cols.round(3))
    assert np.all((np.abs(rows - 1.0) < 1e-3) | (np.abs(rows - 0.92) < 1e-3)), np.unique(rows.round(3))
    for share, density in (((cols < 0.96).mean(), 0.1), ((rows < 0.96).mean(), 0.02)):
        assert abs(share - density) < 5 * math.sqrt(density * (1 - density) / 4096), share
    # a crossing pixel takes both gains; bias frames (no signal) see only the read noise scaled
    y, x = np.nonzero((rows[0] < 0.96)[:, None] & (cols[0] < 0.96)[None, :])
    assert y.size == 0 or np.allclose(raw[0, y, x] / level, 0.92 ** 2, atol=1e-3)


def test_gain_defect_lines_are_found_and_estimated():
    from rawaug.effects import line_gain

    # uniform flats (``defect_lines`` reads a line against its running median of 5: under a light
    # steeper than the line noise that median is the line itself, and a dim line of a few per cent
    # goes unseen; see the README)
    flats = lambda effects, seed: synth(effects, batch=4, size=96, level_dn=3000.0, model="G+P", seed=seed)  # noqa: E731
    base = [flats({}, s) for s in range(1, 4)]
    truth = _sensor(synth({"LineGain": WEAK}, batch=1, size=96, level_dn=3000.0, sigma_g=1e-3))[0].mean(axis=0) / 3000.0
    weak = int((truth < 0.96).sum())  # the sensor's dim columns (its seeded pattern)
    est = line_gain.estimate(flats({"LineGain": WEAK}, 7), base, K, kind="flat")
    assert weak >= 5 and est["col_density"] == weak / 192, (weak, est)
    assert est["row_density"] == 0.0 and est["negative"] == 1.0 and abs(est["median"] - 0.08) < 0.005, est
    # ELD-model flats: nothing, 20 seeds
    white = [line_gain.estimate(flats({}, s), base, K, kind="flat") for s in range(20, 40)]
    assert all(line_gain.empty(w) for w in white), white
    with pytest.raises(ValueError, match="measured on flat stacks"):
        line_gain.estimate(base[0], base, K, kind="bias")
