"""DarkCluster: square patches of sensor pixels that share one dark-current rate, through the
real stage and its estimator."""
import math

import numpy as np
import torch
from scipy import ndimage

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import dark_clusters, dark_hot_pixels

from base_camera import base_fixed

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
T = 4.0  # seconds of the dark frames
PATCHES = {"seed": 61, "density": 3e-4, "size": 3, "median_e_per_s": 40.0, "log_std": 0.3}


def darks(effects, seed, n=4, size=128, sensor=0):
    """(n, 4, size, size) dark frames of T seconds (DN) at gain K with ``effects`` (token: entry)."""
    profile = BASE
    for token, entry in effects.items():
        profile = profile.with_effect(token, entry)
    aug = RawNoiseAugment(profile, model="G+R", ratio=1.0, fixed=base_fixed(BASE, K, sensor=sensor, exposure_s=T),
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.zeros(n, 4, size, size, dtype=torch.float64)).numpy() * BASE.span_dn


def test_patches_are_squares_of_one_rate_at_the_seeded_density():
    """Over 4 sensor instances of 256 x 256 sensor pixels, the patches of the stack mean (> 60
    DN: the rate 160 e- x e^(-3 x 0.3) is 65 DN, the noise of a mean of 16 frames 1 DN) number
    within 5 Poisson sd of density x pixels (less the few that merge); 9 of 10 are 3 x 3
    squares (the rest merged or cut at the top or left edge); inside a patch the pixels agree
    within the shot noise of their mean."""
    counts, square = 0, []
    for sensor in range(4):
        m = darks({"DarkCluster": PATCHES}, 1, n=16, sensor=sensor).mean(axis=0)
        raw = np.zeros((256, 256))
        for c, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 1), (1, 0))):
            raw[dy::2, dx::2] = m[c]
        labels, n = ndimage.label(raw > 30.0, structure=np.ones((3, 3)))
        counts += n
        for i in range(1, n + 1):
            ys, xs = np.nonzero(labels == i)
            square.append(len(ys) == 9 and np.ptp(ys) == 2 and np.ptp(xs) == 2)
            if square[-1]:
                v = raw[ys, xs]
                # a pixel's mean over 16 frames: the patch's rate is one, its shot noise sqrt(rate K t / 16)
                assert v.std(ddof=1) < 3 * math.sqrt(v.mean() * K / 16) + 1.0, v
    expected = PATCHES["density"] * 4 * 256 * 256
    assert abs(counts - expected) < 5 * math.sqrt(expected), (counts, expected)
    assert np.mean(square) > 0.9, np.mean(square)


def test_estimate_finds_the_patches_and_none_in_hot_pixels_or_plain_darks():
    """Six dark stacks of other sensor instances: size 3 in every one, the density within 5
    Poisson sd of its count, the median rate within 5 sd of its log (0.3 / sqrt(count)).
    Darks with isolated hot pixels (DarkHot, 0.2 %) or none: no patch in 10 of 10."""
    base = [darks({}, s) for s in range(1, 4)]
    for sensor in range(1, 7):
        est = dark_clusters.estimate(darks({"DarkCluster": PATCHES}, 10 + sensor, sensor=sensor), base, K, exposure_s=T, kind="dark")
        n = PATCHES["density"] * 4 * 128 * 128
        assert est["size"] == 3, est
        assert abs(est["density"] - PATCHES["density"]) < 5 * math.sqrt(n) / (4 * 128 * 128), est
        assert abs(math.log(est["median_e_per_s"] / 40.0)) < 5 * 0.3 / math.sqrt(n) + 0.05, est
    hot = {"seed": 59, "density": 0.002, "median_e_per_s": 40.0, "log_std": 0.3}
    hot_base = [darks({"DarkHot": hot}, s) for s in range(1, 4)]
    none = [dark_clusters.estimate(darks({"DarkHot": hot}, 20 + s, sensor=s), hot_base, K, exposure_s=T, kind="dark") for s in range(10)]
    none += [dark_clusters.estimate(darks({}, 40 + s, sensor=s), base, K, exposure_s=T, kind="dark") for s in range(10)]
    assert all(dark_clusters.empty(e) for e in none), [e for e in none if not dark_clusters.empty(e)]
    # DarkHot's isolated-pixel estimate takes none of a patch's neighbours in a channel as hot pixels of its own
    est = dark_hot_pixels.estimate(darks({"DarkCluster": {**PATCHES, "size": 4}}, 3), base, K, exposure_s=T, kind="dark")
    assert est["density"] == 0.0, est
