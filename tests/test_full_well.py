"""FullWell: a pixel holds at most its own full well of electrons, through the real stage and its
estimator."""
import math

import numpy as np
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import full_well
from rawaug.statistics import quiet_fraction

from base_camera import base_fixed

BASE = NoiseProfile.load("SonyA7S2")
K = 0.375
WELL = {"seed": 5, "well_e": 17000.0, "spread": 0.03}


def flat_stack(effects, seed, level_dn, n=2, size=96, sensor=0, k=K):
    """(n, 4, size, size) flat frames (DN) at ``level_dn`` and gain ``k`` with ``effects``."""
    profile = BASE
    for token, entry in effects.items():
        profile = profile.with_effect(token, entry)
    aug = RawNoiseAugment(profile, model="G*+P*+R", ratio=1.0, fixed=base_fixed(profile, k, sensor=sensor),
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        clean = torch.full((n, 4, size, size), level_dn / profile.span_dn, dtype=torch.float64)
        return aug(clean).numpy() * profile.span_dn


def test_a_flat_far_above_the_well_reads_the_wells_and_one_below_is_untouched():
    """At twice the well every pixel reads K x its own well plus read noise: the mean over
    36864 pixels within 5 sd of K x 17000 DN, the pixels' spread (of their 4-frame means) within
    5 sd of 3 % of it, each pixel's temporal variance the read noise's (not the shot noise's
    ~4800 DN^2). At a gain whose well lies above the flat the frames are those without it."""
    f = flat_stack({"FullWell": WELL}, 1, 2 * K * 17000.0, n=4)
    mean = f.mean(axis=0)
    well, spread = K * 17000.0, 0.03 * K * 17000.0
    n = mean.size
    assert abs(mean.mean() - well) < 5 * spread / math.sqrt(n), mean.mean()
    assert abs(mean.std() - spread) < 5 * spread / math.sqrt(2 * n) + 0.5, mean.std()
    assert np.median(f.var(axis=0, ddof=1)) < 30.0
    below = flat_stack({"FullWell": WELL}, 2, 0.4 * 15871, k=3.0)  # K x well = 51000 DN: above the white level
    assert np.array_equal(below, flat_stack({}, 2, 0.4 * 15871, k=3.0))


def test_estimate_finds_the_well_and_none_without():
    """Five sessions of a flat pair (128 x 128 per channel) at 6350 DN, K 0.375 (half the pixels
    at their well): the well within 1 % of 17000 e- and its spread within 25 % of 3 % in each;
    ten sessions without a full well and five with it above the flat: none (a binomial test at
    1e-3 per stack)."""
    level = 6350.0
    base = [flat_stack({}, 100 + s, level, size=128, sensor=1) for s in range(4)]
    for session in range(5):
        est = full_well.estimate(flat_stack({"FullWell": WELL}, 10 + session, level, size=128), base, K, kind="flat")
        assert abs(est["well_e"] - 17000.0) < 0.01 * 17000.0, est
        assert abs(est["spread"] - 0.03) < 0.25 * 0.03, est
    none = [full_well.estimate(flat_stack({}, 30 + s, level, size=128), base, K, kind="flat") for s in range(10)]
    high = {**WELL, "well_e": 20000.0}  # 7500 DN: 23 sd of the shot noise above the flat
    none += [full_well.estimate(flat_stack({"FullWell": high}, 50 + s, level, size=128), base, K, kind="flat") for s in range(5)]
    assert all(full_well.empty(full_well.combine([e])) for e in none), none


def test_the_quiet_fraction_of_gaussian_pairs_is_fixed():
    """For a pair of Gaussian frames the mean of exp(-v / (m / 16)) over the pixels, v = chi2(1)
    sigma^2 and m the mean of v below its 99.5 % quantile (0.956 sigma^2): 0.1703, within 5 of
    its standard errors (0.304 per pixel) over 65536 pixels."""
    f = flat_stack({}, 7, 2000.0, size=128)
    assert abs(quiet_fraction(f) - 0.1703) < 5 * 0.304 / math.sqrt(f[0].size), quiet_fraction(f)


def test_the_quiet_fraction_does_not_jump_with_the_codes():
    """Pairs of normals rounded to whole codes, std 10 to 24 DN: the same value within 5 of its
    standard errors at every scale (the share below 1/16 of the median, before, read 0.116 to
    0.141 on these, 30 of its standard errors apart)."""
    rng = np.random.default_rng(3)
    for sigma in (10.0, 12.0, 14.0, 17.0, 20.0, 24.0):
        f = np.rint(rng.normal(0.0, sigma, (2, 4, 128, 128)))
        assert abs(quiet_fraction(f) - 0.1703) < 5 * 0.304 / math.sqrt(f[0].size), (sigma, quiet_fraction(f))


def test_photon_transfer_leaves_out_pairs_held_at_their_wells():
    """Flat pairs at 300 .. 6350 DN, K 0.375, the top one half held at the wells: the photon
    transfer leaves that pair out with a warning that names the wells, and K comes out within
    3 % of 0.375 (it bent to 0.57 with the pair in); without a full well no tile of 5 sessions
    x 5 levels x 64 tiles is taken for held."""
    import warnings

    from rawaug.calibration.kernels import pair_tile_stats
    from rawaug.calibration.stage1 import estimate_gain, held_tiles

    levels = (300.0, 800.0, 1600.0, 3200.0, 6350.0)
    read_var = float(flat_stack({}, 3, 0.0, n=4, size=128).var(axis=0, ddof=1).mean())
    pairs = [tuple(flat_stack({"FullWell": WELL}, 20 + j, level, size=128)) for j, level in enumerate(levels)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gain = estimate_gain(pairs, read_variance_dn2=read_var)
    assert any("full wells" in str(w.message) for w in caught), [str(w.message) for w in caught]
    assert abs(gain.k - K) < 0.03 * K, gain.k
    held = 0
    for session in range(5):
        for level in levels:
            a, b = flat_stack({}, 40 + session, level, size=128)
            held += int(held_tiles(a, b, 32, pair_tile_stats(a, b, 32)[2], read_var).sum())
    assert held == 0
