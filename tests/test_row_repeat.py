"""RowRepeat: sensor rows read out as the same colour's row above, and the estimate of their share."""
import math

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import row_repeat
from rawaug.statistics import STATISTICS, repeated_row_mask, repeated_rows

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0


def codes(effects, batch=8, size=64, seed=0, level_dn=0.0):
    """A stack of whole DN (``U`` and rounding: raw codes less black) of one camera."""
    prof = BASE
    for token, params in effects.items():
        prof = prof.with_effect(token, params)
    aug = RawNoiseAugment(prof, model="G+U", ratio=1.0, fixed={"k": K, "sigma_g": 2.0, "sensor": 0},
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    x = torch.full((batch, 4, size, size), level_dn / prof.span_dn, dtype=torch.float64)
    return np.rint((aug(x) * prof.span_dn).numpy())


def test_a_repeated_row_is_the_row_above_code_for_code_at_the_planted_rate():
    f = codes({"RowRepeat": {"density": 0.03}}, batch=16, size=64, level_dn=200.0)
    mask = repeated_row_mask(f)  # (16, 2, 63): sensor rows below the first of each colour
    n = mask.size
    # a row is a repeat with probability 0.03 (its draw); binomial sd over 2016 rows
    assert abs(mask.mean() - 0.03) < 5 * math.sqrt(0.03 * 0.97 / n), mask.mean()
    # both packed channels of a repeated sensor row equal the row above, every column
    b, rs, y = np.argwhere(mask)[0]
    for c in (0, 1) if rs == 0 else (2, 3):
        assert np.array_equal(f[b, c, y + 1], f[b, c, y])
    # new places in every frame: the frames' repeated rows are not the same rows
    assert not np.all(mask == mask[:1])
    # without the effect no row repeats (each of 128 values has its own noise of 2 DN)
    assert repeated_rows(codes({}, batch=16, size=64, level_dn=200.0)) == 0.0


def test_the_statistic_counts_sensor_rows():
    assert STATISTICS["repeated_rows"].view == "raw" and STATISTICS["repeated_rows"].row_fraction
    f = np.random.default_rng(0).normal(size=(2, 4, 16, 16))
    f[1, 2, 5] = f[1, 2, 4]  # one channel of sensor row 11 only: not the whole row
    assert repeated_rows(f) == 0.0
    f[1, 3, 5] = f[1, 3, 4]  # now both channels of sensor row 11 (B and G2)
    assert repeated_rows(f) == 1 / (2 * 2 * 15)


@pytest.mark.parametrize("density", [0.01, 0.03])
def test_the_estimate_finds_the_planted_share_over_sessions_and_nothing_without(density):
    base = [codes({}, seed=s) for s in range(1, 4)]
    found, estimates, false = 0, [], 0
    for session in range(10):
        # 8 frames of 64 packed rows: 1008 rows checked, 10 or 30 repeats expected (5 are needed)
        stacks = [codes({"RowRepeat": {"density": density}}, seed=100 + 10 * session + i) for i in range(2)]
        records = []
        for stack in stacks:
            try:
                records.append(row_repeat.estimate(stack, base, K))
            except ValueError:
                pass
        if records:
            found += 1
            estimates.append(row_repeat.combine(records)["density"])
        try:
            row_repeat.estimate(codes({}, seed=300 + session), base, K)
            false += 1
        except ValueError as e:
            assert "within chance" in str(e)
    assert found == 10 and false == 0, (found, false)
    # pooled over 10 sessions (about 20 000 rows where a stack shows it): the binomial sd of the share
    rows = 10 * 2 * 1008
    assert abs(np.mean(estimates) - density) < 5 * math.sqrt(density / rows) + 1 / rows, (estimates, density)


def test_validation_names_the_value():
    with pytest.raises(ValueError, match="density must be a share"):
        BASE.with_effect("RowRepeat", {"density": 1.5})
    with pytest.raises(ValueError, match="parameters must be"):
        BASE.with_effect("RowRepeat", {"density": 0.1, "lag": 2})
