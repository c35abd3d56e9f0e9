"""BankNoise: a temporal noise of its own per interleaved column readout bank, through the real
stage and its estimator."""
import math

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import bank_noise

from base_camera import base_fixed

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
BANKS = {"k": [K], "col_period": 3, "sigma_dn": [[1.5, 0.0, 0.5]]}


def stack(effects, seed, n=8, size=64):
    """(n, 4, size, size) bias frames (DN) at gain K with ``effects`` (token: entry)."""
    profile = BASE
    for token, entry in effects.items():
        profile = profile.with_effect(token, entry)
    aug = RawNoiseAugment(profile, model="G+R", ratio=1.0, fixed=base_fixed(BASE, K),
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.zeros(n, 4, size, size, dtype=torch.float64)).numpy() * BASE.span_dn


def test_each_bank_adds_its_variance_to_its_columns_pixels():
    f = stack({"BankNoise": BANKS}, 1, n=16)
    base = stack({}, 1, n=16)
    var = lambda x: x.var(axis=0, ddof=1)  # noqa: E731  (N, 4, h, w) -> (4, h, w)
    extra = var(f) - var(base)
    sensor_col = np.empty((4, 64), dtype=int)
    for c, col_set in enumerate((0, 1, 1, 0)):
        sensor_col[c] = 2 * np.arange(64) + col_set
    for phase, sigma in enumerate(BANKS["sigma_dn"][0]):
        cells = extra[np.broadcast_to((sensor_col % 3 == phase)[:, None, :], extra.shape)]
        # a pixel's variance over 16 frames has 15 degrees of freedom: the difference's sd is at most
        # sqrt(2 / 15) (its bank's variance + both frames' read variance), over ~5500 pixels a phase
        se = math.sqrt(2 / 15) * (sigma**2 + 2 * base_fixed(BASE, K)["sigma_g"] ** 2) / math.sqrt(cells.size)
        assert abs(cells.mean() - sigma**2) < 5 * se + 0.02, (phase, cells.mean(), sigma**2)


def test_the_estimate_finds_the_banks_over_sessions_and_none_without():
    base = [stack({}, s) for s in range(1, 4)]
    found, periods, sigmas, false = 0, [], [], 0
    for session in range(10):
        rec = bank_noise.combine([bank_noise.estimate(stack({"BankNoise": BANKS}, 100 + session), base, K)])
        if not bank_noise.empty(rec):
            found += 1
            periods.append(rec["col_period"])
            sigmas.append(rec["sigma_dn"][0])
        if not bank_noise.empty(bank_noise.combine([bank_noise.estimate(stack({}, 300 + session), base, K)])):
            false += 1
    assert found == 10 and set(periods) == {3} and false == 0, (found, periods, false)
    got = np.mean(sigmas, axis=0)
    assert np.all(np.abs(got - BANKS["sigma_dn"][0]) < 0.3), got  # the quietest bank is the reference: 0 by construction


def test_bad_parameters_name_the_value():
    with pytest.raises(ValueError, match="col_period must be a whole number"):
        BASE.with_effect("BankNoise", {**BANKS, "col_period": 2})
    with pytest.raises(ValueError, match="sigma_dn record 0 must hold 3 values"):
        BASE.with_effect("BankNoise", {**BANKS, "sigma_dn": [[1.0, 0.0]]})
