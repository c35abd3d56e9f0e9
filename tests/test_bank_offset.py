"""BankOffset: fixed offsets of interleaved readout banks, through the real stage, its estimator
and its profile entry."""
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import bank_offset

from base_camera import base_fixed

BASE = NoiseProfile.load("SonyA7S2")


def frames(k, seed, n=4, size=96, entry=None, col=None):
    """(n, 4, size, size) bias frames in DN at gain ``k`` (the base camera's read and row noise),
    with bank offsets ``entry``, plus a fixed random offset per sensor column of ``col`` DN rms
    (a sensor's own column pattern) where given."""
    profile = BASE.with_effect("BankOffset", entry) if entry else BASE
    fixed = base_fixed(BASE, k)
    aug = RawNoiseAugment(profile, model="G+R" + ("+BankOffset" if entry else ""), ratio=1.0, fixed=fixed,
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        out = aug(torch.zeros(n, 4, size, size)).numpy().astype(np.float64) * BASE.span_dn
    if col:
        c = np.random.default_rng(77).normal(0.0, col, 2 * size)
        out += np.stack([c[0::2], c[1::2], c[1::2], c[0::2]])[None, :, None, :]
    return out


ENTRY = {"k": [1.0], "col_period": 3, "col_dn": [[0.6, 0.0, -0.6]], "row_period": 4, "row_dn": [[0.4, 0.0, -0.4, 0.0]]}


def test_the_stage_adds_each_sensor_lines_bank_offset():
    got, plain = frames(1.0, seed=2, entry=ENTRY), frames(1.0, seed=2)
    diff = got - plain  # the same draws: the stage's offsets alone
    X = 2 * np.arange(96)[None, :] + np.array([0, 1, 1, 0])[:, None]  # sensor column of each packed column, R G1 B G2
    Y = 2 * np.arange(96)[None, :] + np.array([0, 0, 1, 1])[:, None]
    want = np.asarray(ENTRY["col_dn"][0])[X % 3][:, None, :] + np.asarray(ENTRY["row_dn"][0])[Y % 4][:, :, None]
    assert np.allclose(diff, want[None], atol=1e-3)


SESSIONS = 10


def test_the_estimate_finds_the_banks_beside_a_random_column_pattern_and_none_where_there_are_none():
    """Over 10 sessions, two stacks at each of two gains: the periods found are the planted ones
    (3 along the columns, 4 along the rows, with a white column pattern of 0.8 DN rms beside
    them), each offset within 5 standard errors (the pooled profile's scatter about its phase
    means over the root of the lines of a phase); without banks, no period in any session (a false period needs
    an F test at family-wise 1e-3)."""
    for session in range(SESSIONS):
        for entry in (ENTRY, None):
            records = []
            for i, k in enumerate((1.0, 1.0, 3.0, 3.0)):
                e = dict(ENTRY, k=[k]) if entry else None
                meas = frames(k, seed=100 * session + i, entry=e, col=0.8 if entry else None)
                synth = [frames(k, seed=100 * session + 50 + 10 * i + j) for j in range(3)]
                records.append(bank_offset.estimate(meas, synth, k, kind="bias"))
            got = bank_offset.combine(records)
            if entry is None:
                assert bank_offset.empty(got), (session, got)
                continue
            assert (got["col_period"], got["row_period"]) == (3, 4), (session, got)
            for key, excess, period in (("col_dn", "col_excess", 3), ("row_dn", "row_excess", 4)):
                for k, rec in zip(got["k"], got[key]):
                    pooled = np.mean([r[excess] for r in records if r["k"][0] == k], axis=0)
                    phase = np.arange(pooled.size) % period
                    resid = bank_offset._parity_free(pooled) - np.asarray(rec)[phase]
                    se = resid.std(ddof=period) / np.sqrt(pooled.size / period)  # a phase mean's standard error
                    want = np.asarray(ENTRY[key][0]) - np.asarray(ENTRY[key][0]).mean()
                    assert np.all(np.abs(np.asarray(rec) - want) < 5 * se), (session, key, rec, se)


def test_a_period_of_two_is_the_colour_bias_and_not_a_bank():
    x = np.tile([1.0, -1.0], 200) + np.random.default_rng(3).normal(0.0, 0.1, 400)
    assert bank_offset.bank_period(x) == (1, [0.0])


@pytest.mark.parametrize("params, match", [
    ({"k": [1.0], "col_period": 3, "col_dn": [[0.1, 0.2]], "row_period": 1, "row_dn": [[0.0]]}, "col_dn record 0 must hold 3"),
    ({"k": [1.0], "col_period": 17, "col_dn": [[0.0] * 17], "row_period": 1, "row_dn": [[0.0]]}, "col_period must be"),
    ({"k": [1.0, 2.0], "col_period": 1, "col_dn": [[0.0]], "row_period": 1, "row_dn": [[0.0]]}, "one value per k"),
])
def test_bad_parameters_name_the_value(params, match):
    with pytest.raises(ValueError, match=match):
        BASE.with_effect("BankOffset", params)
