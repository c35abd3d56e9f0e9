"""DarkRowNoise: row noise that grows with the exposure, through the real stage and its
estimator."""
import math

import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import dark_row_noise
from rawaug.statistics import temporal_row_variance

from base_camera import base_fixed

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
ROWS = {"k": [K], "rate_dn2_per_s": [0.25]}  # 1 DN rms in a 4 s dark


def dark_stack(effects, seed, exposure_s, n=4, size=96, sensor=0):
    """(n, 4, size, size) dark frames (DN) of ``exposure_s`` at gain K with ``effects``, model G+R."""
    profile = BASE
    for token, entry in effects.items():
        profile = profile.with_effect(token, entry)
    aug = RawNoiseAugment(profile, model="G+R", ratio=1.0, fixed=base_fixed(profile, K, sensor=sensor, exposure_s=exposure_s),
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.zeros(n, 4, size, size, dtype=torch.float64)).numpy() * profile.span_dn


def test_the_rows_of_long_exposures_move_more():
    """64 frames of 192 sensor rows: at 4 s the rows' temporal variance exceeds the model's by
    1 DN^2 x (63/64) (191/192) within 5 sd of a variance over 63 x 191 degrees of freedom; bias
    frames (0 s) are those without it."""
    with_, without = dark_stack({"DarkRowNoise": ROWS}, 1, 4.0, n=64), dark_stack({}, 1, 4.0, n=64)
    excess = temporal_row_variance(with_) - temporal_row_variance(without)
    want = (63 / 64) * (191 / 192)
    total = temporal_row_variance(with_)
    assert abs(excess - want) < 5 * total * math.sqrt(2.0 / (63 * 191)), excess
    assert (dark_stack({"DarkRowNoise": ROWS}, 2, 0.0) == dark_stack({}, 2, 0.0)).all()


def test_estimate_finds_the_rate_and_none_without():
    """Ten sessions of 4 darks of 4 s (256 sensor rows) at 0.25 DN^2/s: the rate within 30 % in
    each; twenty sessions without: none (an F test at 1e-3)."""
    base = [dark_stack({}, s, 4.0, size=128, sensor=1) for s in range(100, 108)]
    for session in range(10):
        est = dark_row_noise.estimate(dark_stack({"DarkRowNoise": ROWS}, 10 + session, 4.0, size=128), base, K, kind="dark", exposure_s=4.0)
        assert abs(est["rate_dn2_per_s"][0] - 0.25) < 0.3 * 0.25, est
    none = [dark_row_noise.estimate(dark_stack({}, 30 + s, 4.0, size=128), base, K, kind="dark", exposure_s=4.0) for s in range(20)]
    assert all(dark_row_noise.empty(dark_row_noise.combine([e])) for e in none), none
