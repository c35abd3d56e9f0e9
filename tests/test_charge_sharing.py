"""ChargeShare: photo charge shared with the four raw neighbours, through the real stage (both
shot-noise models), its statistic and its estimator."""
import functools

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import charge_sharing as cs
from rawaug.engine import layout as L
from rawaug.statistics import neighbour_corr

K = 2.0  # DN per electron
LEVEL = 0.1  # of the span: ~800 electrons, shot noise far above the read noise


@functools.lru_cache(maxsize=None)
def share_profile(share):
    profile = NoiseProfile.load("SonyA7S2")
    return profile if share is None else profile.with_effect("ChargeShare", {"share_x": share[0], "share_y": share[1]})


def flats(n, share=None, seed=0, model="P*", level=LEVEL, shape=(32, 32), read_dn=0.0):
    """(n, 4, h, w) flat frames in DN (read noise ``read_dn``), with ``share`` (share_x, share_y)."""
    profile = share_profile(share)
    if read_dn:
        model += "+G"
    aug = RawNoiseAugment(profile, model=model, ratio=1.0, fixed={"k": K, "sigma_g": read_dn},
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.full((n, 4, *shape), level)).numpy().astype(np.float64) * profile.span_dn


def mosaic_residual(frames):
    """Each frame less the stack mean (scaled to the frames' variance), as raw mosaics."""
    n, _, h, w = frames.shape
    r = (frames - frames.mean(axis=0)) * np.sqrt(n / (n - 1))
    raw = np.empty((n, 2 * h, 2 * w))
    for c in range(4):
        raw[:, L.ROW_SET[c]::2, L.COLUMN_SET[c]::2] = r[:, c]
    return raw


def lag_corr(raw, dy, dx):
    a = raw[:, : raw.shape[1] - dy, max(0, -dx): raw.shape[2] - max(0, dx)]
    b = raw[:, dy:, max(0, dx): raw.shape[2] - max(0, -dx)]
    return float(np.mean(a * b) / np.mean(raw * raw)), a.size


@pytest.mark.parametrize("model", ["P*", "P"])
def test_neighbours_share_the_shot_noise_as_the_kernel_says_and_each_pixel_keeps_its_variance(model):
    share = (0.04, 0.015)
    f = flats(24, share, seed=1, model=model)
    level = LEVEL * NoiseProfile.load("SonyA7S2").span_dn
    raw = mosaic_residual(f)
    expected = dict(zip(L.XTALK_LAGS, cs.correlations(*share)))
    for lag in [(0, 1), (1, 0), (1, 1), (0, 2), (2, 0)]:
        got, pairs = lag_corr(raw, *lag)
        assert abs(got - expected[lag]) < 5 / np.sqrt(pairs), (lag, got, expected[lag])  # sd of a correlation ~ 1/sqrt(pairs)
    # the mean stays the clean level, each pixel's variance the Poisson K x level (sd of a variance: sqrt(2 / n) relative)
    assert abs(f.mean() / level - 1.0) < 5 * np.sqrt(K * level / f.size) / level
    assert abs(np.mean(raw * raw) / (K * level) - 1.0) < 5 * np.sqrt(2.0 / raw.size) * 1.2  # x1.2: pairs are correlated


def test_bias_frames_are_untouched():
    a = flats(3, (0.05, 0.05), seed=2, level=0.0, read_dn=1.5)
    b = flats(3, None, seed=2, level=0.0, read_dn=1.5)
    assert np.array_equal(a, b)


def test_neighbour_corr_sees_it_in_flats():
    # 20 stacks of 4 x 64 x 64 each way: the rms over its six lags is ~0.03 without (the high-pass's
    # bias at the same-colour lags, spread ~0.002 here), 3 % per neighbour adds 0.07 at (0, 1) and (1, 0)
    plain = [neighbour_corr(flats(4, None, seed=10 + s, shape=(64, 64))) for s in range(20)]
    shared = [neighbour_corr(flats(4, (0.03, 0.03), seed=40 + s, shape=(64, 64))) for s in range(20)]
    assert max(plain) + 0.01 < min(shared)


def camera(share, seed):
    """ChargeShare measured back from four flat stacks (two levels x two gains, 4 frames each)
    against 6 syntheses of the model without it."""
    records = []
    for j, level in enumerate((0.05, 0.2)):
        measured = flats(4, share, seed=seed * 10 + j, level=level, read_dn=2.0)
        base = [flats(4, None, seed=10_000 + seed * 10 + 6 * j + i, level=level, read_dn=2.0) for i in range(6)]
        level_dn = level * share_profile(None).span_dn
        records.append(cs.estimate(measured, base, K, level_dn=level_dn, kind="flat"))
    return cs.combine(records)


def test_the_estimate_finds_the_sharing_over_cameras():
    # 10 cameras each: isotropic 3 %, anisotropic 4 % / 1 %; medians within 0.005 and every one within 0.015
    for share in [(0.03, 0.03), (0.04, 0.01)]:
        got = np.array([[camera(share, s)[key] for key in cs.KEYS] for s in range(10)])
        assert np.all(np.abs(np.median(got, axis=0) - share) < 0.005), got
        assert np.all(np.abs(got - share) < 0.015), got


def test_no_sharing_is_measured_as_none_in_most_cameras():
    # the 3-sd rule per lag leaves a lag's chance excess in about 6 x 0.3 % of stacks; over 20
    # cameras (4 stacks each) a small share may come back, never a large one. Measured: 16 of
    # these 20 empty and 34 of 40 others (seeds 500-539), the largest share 0.0086
    got = [camera(None, 100 + s) for s in range(20)]
    assert sum(cs.empty(g) for g in got) >= 12
    assert max(max(g.values()) for g in got) < 0.01


def test_the_estimate_refuses_what_cannot_show_it():
    f = flats(4, None, seed=3)
    with pytest.raises(ValueError, match="flat"):
        cs.estimate(f, [f], K, level_dn=None, kind="bias")
    with pytest.raises(ValueError, match="flat"):
        cs.estimate(f, [f], K, level_dn=800.0, kind="dark")


@pytest.mark.parametrize("params, match", [
    ({}, "needs at least one"), ({"share_x": 0.3}, r"\[0, 0.1667\]"), ({"share_y": -0.01}, "share_y"),
    ({"share_x": 0.01, "sigma": 1.0}, "unknown keys"), ([0.03], "mapping"),
])
def test_bad_entries_are_refused(params, match):
    with pytest.raises(ValueError, match=match):
        NoiseProfile.load("SonyA7S2").with_effect("ChargeShare", params)
