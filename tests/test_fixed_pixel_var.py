"""``fixed_pixel_var``: the white fixed pattern's variance (DSNU of offsets and dark current), and
the estimators built on it (``FPN``'s white part, ``Dark``'s log-normal DSNU). Random things by
distribution, with bounds from the number of draws."""
import math

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import amp_glow, dark_current, dark_shading
from rawaug.statistics import STATISTICS, fixed_pixel_var

BASE = NoiseProfile.load("SonyA7S2")


def stack(rng, n=6, h=64, w=64, temporal=2.0, fixed=0.0, row=0.0, heavy=False):
    """n frames (4, h, w): white temporal noise (Student t with 3 dof, scaled to ``temporal``
    rms, when ``heavy``), a per-frame row offset of ``row`` DN, and a white fixed pattern of
    ``fixed`` DN rms."""
    shape = (n, 4, h, w)
    t = rng.standard_t(3, shape) / math.sqrt(3.0) if heavy else rng.standard_normal(shape)
    return temporal * t + row * rng.standard_normal((n, 4, h, 1)) + fixed * rng.standard_normal((1, 4, h, w))


def test_unbiased_for_any_temporal_noise_and_blind_to_lines_and_shading():
    rng = np.random.default_rng(0)
    draws = 200
    for fixed, kw in ((0.0, {}), (0.8, {}), (0.8, {"row": 1.5}), (0.0, {"heavy": True})):
        v = np.array([fixed_pixel_var(stack(rng, fixed=fixed, **kw)) for _ in range(draws)])
        # the mean of 200 estimates: within 4 standard errors of the truth. Leaving out the cells
        # with an outlier in some frame keeps Gaussian noise unbiased; a heavy tail (Student t,
        # 3 dof) leaves a bias of about 0.14 % of the temporal variance (4 DN^2): 0.2 % allowed
        bias = 0.002 * 4.0 if kw.get("heavy") else 0.0
        assert abs(v.mean() - fixed**2) < bias + 4 * v.std(ddof=1) / math.sqrt(draws), (fixed, kw, v.mean(), v.std())
    # a fixed row and column pattern cancel exactly in the double differences; a smooth shading
    # of 5 DN leaves its mixed second derivative (~0.004 DN a cell)
    f = stack(rng, fixed=0.5)
    y, x = np.mgrid[0:64, 0:64]
    lines = 3.0 * rng.standard_normal((4, 64, 1)) + 2.0 * rng.standard_normal((4, 1, 64))
    assert fixed_pixel_var(f + lines[None]) == pytest.approx(fixed_pixel_var(f), abs=1e-9)
    assert fixed_pixel_var(f + 5.0 * np.cos(x / 20.0) * y / 64) == pytest.approx(fixed_pixel_var(f), rel=1e-4)


def test_hot_pixels_and_impulses_do_not_count():
    rng = np.random.default_rng(1)
    draws = 100
    clean, dirty = [], []
    for _ in range(draws):
        f = stack(rng, fixed=0.8)
        clean.append(fixed_pixel_var(f))
        hot = (rng.random((1, 4, 64, 64)) < 1e-3) * rng.uniform(30, 200, (1, 4, 64, 64))  # fixed
        spikes = (rng.random(f.shape) < 5e-4) * rng.uniform(30, 200, f.shape)  # new in every frame
        dirty.append(fixed_pixel_var(f + hot + spikes))
    clean, dirty = np.array(clean), np.array(dirty)
    # what a cell's exclusion costs a Gaussian pattern: a few cells of 16k, far below the spread
    d = dirty - clean
    assert abs(d.mean()) < 4 * clean.std(ddof=1) / math.sqrt(draws), (d.mean(), clean.std())
    assert np.abs(d).max() < clean.std(ddof=1), (np.abs(d).max(), clean.std())


def test_resolution_covers_two_patterns_realizations():
    """The model holds one realization of a pattern; the sensor another: their values differ by
    about 3 v / sqrt(n) (the statistic's floor), not by the syntheses' temporal spread alone."""
    rng = np.random.default_rng(2)
    frames = stack(rng, fixed=1.0)
    res = STATISTICS["fixed_pixel_var"].resolution(frames, 1.0)
    d = np.array([fixed_pixel_var(stack(rng, temporal=0.01, fixed=1.0)) - fixed_pixel_var(stack(rng, temporal=0.01, fixed=1.0))
                  for _ in range(300)])
    # the rms difference within 20 % of the floor (300 draws: the rms' own spread is 4 %)
    assert 0.8 < d.std() / res < 1.2, (d.std(), res)


def synth(effects, exposure_s, seed, n=6, size=64, k=1.0, sensor=0):
    prof = BASE
    for token, params in effects.items():
        prof = prof.with_effect(token, params)
    aug = RawNoiseAugment(prof, model="G+P*", ratio=1.0, fixed={"k": k, "sigma_g": 2.0, "exposure_s": exposure_s, "sensor": sensor},
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    return (aug(torch.zeros((n, 4, size, size), dtype=torch.float64)) * prof.span_dn).numpy()


def test_dark_dsnu_is_a_log_normal_map_of_mean_one_and_is_estimated():
    dark = {"Dark": {"seed": 21, "k": [1.0], "rate_e_per_s": [50.0], "dsnu": [0.6]}}
    frames = synth(dark, 4.0, seed=1, n=8, size=96)  # 200 e- a pixel
    m = frames.mean(axis=0).ravel()  # the map of 8 frames: rate map x 200 DN, plus shot and read noise / sqrt(8)
    n = m.size
    assert abs(m.mean() - 200.0) < 5 * 200.0 * 0.6 / math.sqrt(n)
    # log-normal: skewed (Gaussian DSNU clipped at 0 has skewness < 0.7 at 0.6), never negative
    skew = float(np.mean((m - m.mean()) ** 3) / m.std() ** 3)
    assert skew > 3 * 0.6 + 0.6**3 - 1.0, skew  # a log-normal of cv 0.6 has 3 cv + cv^3 = 2.0
    base = [synth({}, 4.0, seed=s, n=8, size=96) for s in range(2, 5)]
    est = dark_current.estimate(frames, base, 1.0, exposure_s=4.0, kind="dark")
    assert abs(est["rate_e_per_s"][0] - 50.0) < 1.0
    # one realization of 37k pixels of a log-normal of cv 0.6: its sample cv is off by ~1.5 %
    assert abs(est["dsnu"][0] - 0.6) < 0.05, est


@pytest.mark.parametrize("log_sigma", [0.8, 1.0])
def test_a_heavy_log_normal_tail_is_measured_through_the_trimmed_statistic(log_sigma):
    # a rate map made outside rawaug (numpy), 1 e-/s in median, 4 s: fixed_pixel_var leaves out
    # the far tail (at 0.8 in log the plain excess read 0.88 of a 0.95 spread, at 1.0 0.82)
    base = [synth({}, 4.0, seed=s, n=8, size=96) for s in range(10, 13)]
    for seed in range(3):
        rng = np.random.default_rng(seed)
        rate = np.exp(log_sigma * rng.standard_normal((4, 96, 96)))
        frames = synth({}, 4.0, seed=20 + seed, n=8, size=96) + rng.poisson(rate * 4.0, (8, 4, 96, 96))
        est = dark_current.estimate(frames, base, 1.0, exposure_s=4.0, kind="dark")
        cv = math.sqrt(math.expm1(log_sigma**2))  # the population's (a sample's is led by its few far cells)
        # measured: within 1 % (0.8) and 2.5 % (1.0); the plain excess was 7 % and 18 % low
        assert abs(est["dsnu"][0] / cv - 1.0) < 0.05, (est, cv)


def test_fpn_white_part_is_the_excess_fixed_variance():
    truth = {"seed": 3, "k": [1.0], "sigma_dn": [0.8], "shading_dn": [[[0.0]]]}
    meas = synth({"FPN": truth}, 1e-4, seed=1, n=8, size=96)
    base = [synth({}, 1e-4, seed=s, n=8, size=96) for s in range(2, 5)]
    est = dark_shading.estimate(meas, base, 1.0)
    assert abs(est["sigma_dn"][0] - 0.8) < 0.05, est


def test_dark_current_and_glow_are_not_estimated_from_flats():
    # a flat's exposure carries light: its excess is the light, not dark current or glow
    frames = synth({}, 0.1, seed=1)
    with pytest.raises(ValueError, match="dark stack"):
        dark_current.estimate(frames + 300.0, [frames], 1.0, exposure_s=0.1, kind="flat")
    with pytest.raises(ValueError, match="dark stack"):
        amp_glow.estimate(frames + 300.0, [frames], 1.0, exposure_s=0.1, kind="flat")


def test_column_dsnu_is_a_factor_per_sensor_column_and_is_estimated():
    # a dark rate of 20 e-/s with a sensor-column factor of relative spread 0.3 (and pixel DSNU
    # 0.4), 4 s: the sensor columns' mean dark signal spreads by 0.3 (192 columns: the sample
    # spread within 4 sd, sqrt(1 / (2 x 192)) of it, plus the pixels' share), R and G2 (one sensor
    # column) share the factor; the estimate gives it back within 0.05 in 5 stacks of the sensor, and stacks
    # with pixel DSNU alone get 0 in 10 of 10 (a chi-square of the columns at p 1e-3)
    dark = {"Dark": {"seed": 21, "k": [1.0], "rate_e_per_s": [20.0], "dsnu": [0.4], "col_dsnu": [0.3]}}
    frames = synth(dark, 4.0, seed=1, n=8, size=96)
    m = frames.mean(axis=(0, 2))  # (4, w) packed column means, DN
    assert np.corrcoef(m[0], m[3])[0, 1] > 0.9 and abs(np.corrcoef(m[0], m[1])[0, 1]) < 0.4
    spread = np.concatenate([m[0], m[1]]).std(ddof=1) / m.mean()
    assert abs(spread - 0.3) < 4 * 0.3 * math.sqrt(1 / 192) + 0.03, spread
    base = [synth({}, 4.0, seed=s, n=8, size=96) for s in range(2, 5)]
    for seed in range(5):
        est = dark_current.estimate(synth(dark, 4.0, seed=10 + seed, n=8, size=96), base, 1.0, exposure_s=4.0, kind="dark")
        assert abs(est["col_dsnu"][0] - 0.3) < 0.05, est
    plain = {"Dark": {"seed": 21, "k": [1.0], "rate_e_per_s": [20.0], "dsnu": [0.4]}}
    for seed in range(10):
        frames = synth(plain, 4.0, seed=30 + seed, n=8, size=96, sensor=3 + seed)  # 10 sensor instances of the pixel DSNU
        est = dark_current.estimate(frames, base, 1.0, exposure_s=4.0, kind="dark")
        assert est["col_dsnu"][0] == 0.0, est


def test_row_dsnu_is_a_factor_per_sensor_row_and_is_estimated():
    # as the column DSNU, along the rows: a sensor-row factor of relative spread 0.3 (pixel DSNU
    # 0.4, 20 e-/s, 4 s): R and G1 (one sensor row) share it; the estimate gives it back within
    # 0.05 in 5 stacks, no column DSNU from it, and pixel DSNU alone or column DSNU alone gives
    # no row DSNU in 10 of 10 (5 each; a chi-square of the rows at p 1e-3)
    dark = {"Dark": {"seed": 21, "k": [1.0], "rate_e_per_s": [20.0], "dsnu": [0.4], "row_dsnu": [0.3]}}
    frames = synth(dark, 4.0, seed=1, n=8, size=96)
    m = frames.mean(axis=(0, 3))  # (4, h) packed row means, DN
    assert np.corrcoef(m[0], m[1])[0, 1] > 0.9 and abs(np.corrcoef(m[0], m[2])[0, 1]) < 0.4
    base = [synth({}, 4.0, seed=s, n=8, size=96) for s in range(2, 5)]
    for seed in range(5):
        est = dark_current.estimate(synth(dark, 4.0, seed=10 + seed, n=8, size=96), base, 1.0, exposure_s=4.0, kind="dark")
        assert abs(est["row_dsnu"][0] - 0.3) < 0.05 and est["col_dsnu"][0] == 0.0, est
    for seed in range(10):
        plain = {"Dark": {"seed": 21, "k": [1.0], "rate_e_per_s": [20.0], "dsnu": [0.4], **({"col_dsnu": [0.3]} if seed % 2 else {})}}
        frames = synth(plain, 4.0, seed=30 + seed, n=8, size=96, sensor=3 + seed)
        est = dark_current.estimate(frames, base, 1.0, exposure_s=4.0, kind="dark")
        assert est["row_dsnu"][0] == 0.0, est
    both = dark_current.combine([dark_current.estimate(synth(dark, 4.0, seed=50, n=8, size=96), base, 1.0, exposure_s=4.0,
                                                       kind="dark")])
    assert "row_dsnu" in both and "col_dsnu" not in both, both


def test_row_noise_left_in_a_dark_mean_is_not_row_dsnu():
    # a weak dark signal (1 e-/s, 4 s: 4 DN) under 1 DN of temporal row noise, 4 frames: the rows'
    # noise left in the stack's mean and the model's (0.5 DN, an eighth of the signal) is not a
    # factor of the rows: no row DSNU in 10 of 10 stacks, as none without the temporal part
    # counted (the first loop run of `column_dark_current` found 0.03 to 0.10); 0.3 planted is
    # found within 0.1
    def rows(effects, seed, n=4):
        prof = BASE
        for token, params in effects.items():
            prof = prof.with_effect(token, params)
        aug = RawNoiseAugment(prof, model="G+P*+R", ratio=1.0,
                              fixed={"k": 1.0, "sigma_g": 2.0, "sigma_r": 1.0, "exposure_s": 4.0, "sensor": 0},
                              generator=torch.Generator().manual_seed(seed), rank_seeding=False)
        return (aug(torch.zeros((n, 4, 96, 96), dtype=torch.float64)) * prof.span_dn).numpy()

    dark = {"seed": 21, "k": [1.0], "rate_e_per_s": [1.0], "dsnu": [0.2]}
    base = [rows({}, s) for s in range(2, 5)]
    for seed in range(10):
        est = dark_current.estimate(rows({"Dark": dark}, 10 + seed), base, 1.0, exposure_s=4.0, kind="dark")
        assert est["row_dsnu"][0] == 0.0, est
    found = [dark_current.estimate(rows({"Dark": {**dark, "row_dsnu": [0.3]}}, 30 + seed), base, 1.0, exposure_s=4.0,
                                   kind="dark")["row_dsnu"][0] for seed in range(3)]
    assert all(abs(f - 0.3) < 0.1 for f in found), found


def test_column_dsnu_of_a_camera_whose_one_colour_has_dark_current():
    # only the blue pixels leak (channel rates 0, 0, 4, 0): the columns are read where blue
    # is, and the others' near-zero signal does not blow the relative map up: no column DSNU
    # from pixel DSNU alone in 10 of 10 sensor instances, 0.3 planted found within 0.07 (96 columns)
    blue = {"seed": 21, "k": [1.0], "rate_e_per_s": [20.0], "dsnu": [0.4], "channel": [0.0, 0.0, 4.0, 0.0]}
    base = [synth({}, 4.0, seed=s, n=8, size=96) for s in range(2, 5)]
    for seed in range(10):
        frames = synth({"Dark": blue}, 4.0, seed=60 + seed, n=8, size=96, sensor=20 + seed)
        assert dark_current.estimate(frames, base, 1.0, exposure_s=4.0, kind="dark")["col_dsnu"][0] == 0.0
    est = dark_current.estimate(synth({"Dark": {**blue, "col_dsnu": [0.3]}}, 4.0, seed=80, n=8, size=96), base, 1.0,
                                exposure_s=4.0, kind="dark")
    assert abs(est["col_dsnu"][0] - 0.3) < 0.07, est
