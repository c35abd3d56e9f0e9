"""Bias frames clipped from below: the clip found, the read noise fitted above it."""
import numpy as np
import pytest
from scipy import stats

from rawaug.calibration.censored import black_floor, censored_read_noise, clipped_share, spread_over_cells
from rawaug.calibration.stage1 import bias_frame_noise, calibrate_iso
from rawaug.calibration.synthetic import synthesize_iso_set
from rawaug.profile import NoiseProfile


def frame(rng, sigma, floor=None, shape=(4, 128, 128), row=0.0, offset=0.0):
    """A packed bias frame of whole codes (DN): Gaussian read noise, row noise, clipped at ``floor``."""
    x = offset + rng.normal(0.0, sigma, shape) + rng.normal(0.0, row, (1, shape[1], 1))
    return np.rint(x if floor is None else np.maximum(x, floor))


def test_black_floor_finds_a_clip_and_nothing_in_unclipped_noise():
    # 3 read noises x 20 frames each: no unclipped frame is taken for a clipped one (a noise
    # tail thins towards its lowest code), every clipped one is, at its level (at 0.7 DN a clip
    # one sigma down piles no more on its code than the noise puts there: it hides 2 % of the
    # values, and is not looked for)
    for sigma in (0.7, 2.0, 5.0):
        for seed in range(20):
            rng = np.random.default_rng(seed)
            assert black_floor(frame(rng, sigma)) is None
            assert black_floor(frame(rng, sigma, floor=0.0)) == 0.0
            if sigma > 1:
                assert black_floor(frame(rng, sigma, floor=-sigma)) == np.rint(-sigma)
    rng = np.random.default_rng(1)
    dead = frame(rng, 2.0)
    dead.reshape(-1)[rng.choice(dead.size, 200, replace=False)] = -60.0  # stuck far below the noise: no clip
    assert black_floor(dead) is None
    assert black_floor(np.zeros((4, 8, 8))) is None


def test_spread_over_cells_spreads_each_code_evenly():
    x = spread_over_cells(np.array([0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 3.0]))
    assert np.allclose(x, [-0.25, 0.25, 0.625, 0.875, 1.125, 1.375, 3.0])


@pytest.mark.parametrize("lam", [0.14, -0.1])
def test_censored_fit_recovers_the_noise_under_a_clip(lam):
    # Tukey-lambda read noise of scale 2 at an offset of 0.3 DN, whole codes, half clipped at 0:
    # over 10 seeds of 200000 values each, lambda within 0.03, the scale within 2 % and the
    # location within 0.05 DN (the fit's spread over seeds is a third of these)
    lams, scales, locations = [], [], []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        x = 0.3 + 2.0 * stats.tukeylambda.rvs(lam, size=200_000, random_state=rng)
        read, location = censored_read_noise(np.rint(np.maximum(x, 0.0)), 0.0, max_samples=None)
        lams.append(read.lam), scales.append(read.sigma_tl), locations.append(location)
    assert np.all(np.abs(np.array(lams) - lam) < 0.03), lams
    assert np.all(np.abs(np.array(scales) / 2.0 - 1) < 0.02), scales
    assert np.all(np.abs(np.array(locations) - 0.3) < 0.05), locations
    with pytest.raises(ValueError, match="above the clip"):
        censored_read_noise(np.zeros(1000), 0.0)


def test_clipped_share_counts_the_noise_below_the_clip():
    rng = np.random.default_rng(0)
    x = rng.normal(0.0, 2.5, 1_000_000)
    # the clip's own code holds the upper half of its cell, not clipped, extrapolated from the next
    # codes: at 2.5 DN within 0.005 (the parabola's error; the counts' is 0.0005), a 1 % error of
    # the row noise it scales
    for floor in (0.0, -2.0, -4.0):
        share = clipped_share(np.rint(np.maximum(x, floor)), np.rint(floor))
        assert abs(share - stats.norm.cdf(floor, scale=2.5)) < 0.005, (floor, share)


def test_a_clipped_bias_frame_gives_the_noise_an_unclipped_one_gives():
    # the same frames with and without a clip at 0 DN (half of them there): read noise, row noise
    # and channel locations (against the unclipped frame's channel means) agree within 3 %, 10 %
    # and 0.08 DN over 5 seeds (measured: 1 %, 3 %, -0.01 .. +0.06 DN)
    for seed in range(5):
        rng = np.random.default_rng(seed)
        raw = np.rint(0.2 + rng.normal(0.0, 2.5, (4, 256, 256)) + rng.normal(0.0, 0.6, (1, 256, 1)))
        read0, row0, loc0 = bias_frame_noise(raw)
        read, row, loc = bias_frame_noise(np.maximum(raw, 0.0))
        assert loc0 is None and len(loc) == 4
        assert abs(read.sigma_g / read0.sigma_g - 1) < 0.03, (read.sigma_g, read0.sigma_g)
        assert abs(row / row0 - 1) < 0.1, (row, row0)
        assert np.all(np.abs(np.array(loc) - raw.mean(axis=(1, 2))) < 0.08), (loc, raw.mean(axis=(1, 2)))


def test_calibrate_iso_on_clipped_bias_frames_matches_the_unclipped_fit():
    profile = NoiseProfile.load("SonyA7S2")
    codes, flat_codes = synthesize_iso_set(profile, k=1.0, sigma_tl=2.0, lam=0.14, sigma_r=0.5, n_bias=3, shape=(256, 256), seed=3)
    bias = [c - profile.black_level for c in codes]  # whole codes less black: DN
    flats = [(a - profile.black_level, b - profile.black_level) for a, b in flat_codes]
    clipped = [np.maximum(b, 0.0) for b in bias]  # clipped at black
    p0 = calibrate_iso(bias, flats, 800)
    p = calibrate_iso(clipped, flats, 800)
    assert p0.extra["black_floor"] is None and p.extra["black_floor"]["floor_dn"] == 0.0
    assert abs(p.sigma_tl / p0.sigma_tl - 1) < 0.05 and abs(p.lam - p0.lam) < 0.05 and abs(p.sigma_r / p0.sigma_r - 1) < 0.15
    assert np.all(np.abs(np.array(p.color_bias_dn) - np.array(p0.color_bias_dn)) < 0.08), (p.color_bias_dn, p0.color_bias_dn)


def test_code_floor_is_a_clip_at_code_zero_only():
    from rawaug.calibration.censored import code_floor

    assert code_floor([None, -512.0, None], [512.0] * 4) == -512.0  # one ISO clipped at code 0
    assert code_floor([-511.6], [512.0, 512.0, 512.0, 512.0]) == -511.6  # within half a code
    assert code_floor([0.0, 0.0], [512.0] * 4) is None  # clipped at the black level: the loop's `Clip`
    assert code_floor([None, None], [0.0] * 4) is None  # no clip
    assert code_floor([-60.0], [60.0, 64.0, 64.0, 60.0]) == -60.0  # per-channel black levels


def test_calibration_puts_a_clip_at_code_zero_in_the_profile(tmp_path):
    # a black level of 0 (NikonD850's): code 0 cuts the read noise; the recording format's floor
    # is part of the calibrated profile, as the white level is. A clip at a black level of 512 is
    # not (firmware: the loop's to find), and unclipped frames give none.
    from rawaug.calibration.command import calibrate
    from rawaug.calibration.synthetic import write_manifest_camera

    nikon = NoiseProfile.load("NikonD850")
    sony = NoiseProfile.load("SonyA7S2")
    assert nikon.black_level == 0 and sony.black_level == 512
    for name in ("zero", "black", "none"):
        (tmp_path / name).mkdir()
    at_zero = calibrate(write_manifest_camera(tmp_path / "zero", nikon, size=48)).profile
    at_black = calibrate(write_manifest_camera(tmp_path / "black", sony, size=48,
                                               post=lambda dn, rng, **_: np.maximum(dn, 0.0))).profile
    unclipped = calibrate(write_manifest_camera(tmp_path / "none", sony, size=48)).profile
    assert at_zero.effects.get("Clip") == {"floor_dn": 0.0}
    assert "Clip" not in at_black.effects and "Clip" not in unclipped.effects


def test_dead_pixels_stay_out_of_the_censored_fit():
    # 0.2 % of the pixels stuck at +300 DN in every frame are no read noise: the censored fit
    # leaves them out as the unclipped one does (stuck_outliers); before, they set lambda to -0.5
    profile = NoiseProfile.load("SonyA7S2")
    codes, flat_codes = synthesize_iso_set(profile, k=1.0, sigma_tl=2.0, lam=0.14, sigma_r=0.5, n_bias=3, shape=(256, 256), seed=3)
    flats = [(a - profile.black_level, b - profile.black_level) for a, b in flat_codes]
    dead = np.random.default_rng(8).random(codes[0].shape) < 0.002
    clipped = [np.maximum(c - profile.black_level, 0.0) for c in codes]
    with_dead = [np.where(dead, 300.0, b) for b in clipped]
    p0 = calibrate_iso(clipped, flats, 800)
    p = calibrate_iso(with_dead, flats, 800)
    assert p.extra["black_floor"]["floor_dn"] == 0.0
    assert abs(p.lam - p0.lam) < 0.02 and abs(p.sigma_tl / p0.sigma_tl - 1) < 0.03, (p.lam, p0.lam, p.sigma_tl, p0.sigma_tl)


def test_hot_pixels_stay_out_of_the_censored_fit():
    # 0.1 % of the pixels 20-100 DN high in every frame (with their read noise) sit in the upper
    # half the censored fit reads: left out (``hot_under_clip``), the fit is the clean one's
    profile = NoiseProfile.load("SonyA7S2")
    codes, flat_codes = synthesize_iso_set(profile, k=1.0, sigma_tl=2.0, lam=0.14, sigma_r=0.5, n_bias=3, shape=(256, 256), seed=4)
    flats = [(a - profile.black_level, b - profile.black_level) for a, b in flat_codes]
    rng = np.random.default_rng(9)
    hot = (rng.random(codes[0].shape) < 0.001) * rng.uniform(20.0, 100.0, codes[0].shape)
    clipped = [np.maximum(c - profile.black_level, 0.0) for c in codes]
    with_hot = [np.maximum(c - profile.black_level + np.rint(hot), 0.0) for c in codes]
    p0 = calibrate_iso(clipped, flats, 800)
    p = calibrate_iso(with_hot, flats, 800)
    assert abs(p.lam - p0.lam) < 0.02 and abs(p.sigma_tl / p0.sigma_tl - 1) < 0.03, (p.lam, p0.lam, p.sigma_tl, p0.sigma_tl)
    from rawaug.calibration.censored import hot_under_clip

    lowest = np.minimum.reduce(with_hot)
    found = hot_under_clip(lowest, with_hot[0])
    assert found[hot > 0].mean() > 0.9 and found[hot == 0].mean() < 1e-5  # the planted ones, and next to no others
