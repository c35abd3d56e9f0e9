"""Pooled statistics: a frame-to-frame spread judged over every stack that has it.

A flat pair holds one degree of freedom of the spread of its frame means; a gain jitter of a
few times the light's stability (0.1 %) is not significant on one pair, and is on the pairs
of every level and ISO together (``rawaug.loop.diagnose.pool_residuals``).
"""
from __future__ import annotations

import math

import numpy as np

from rawaug.loop.diagnose import Residual, _joint, pool_residuals
from rawaug.statistics import LIGHT_STABILITY, STATISTICS

F = LIGHT_STABILITY
NAME = "flat_gain_spread"


def _stack(rng, sigma, synth_sigma=0.2 * F, n_synth=8, dof=1):
    """One stack's own figures: the measured spread of its dof + 1 frame means (a jitter of
    ``sigma``, or the light's F) and the model's over ``n_synth`` syntheses (shot noise)."""
    measured = sigma * math.sqrt(rng.chisquare(dof) / dof)
    synth = synth_sigma * np.sqrt(rng.chisquare(dof, n_synth) / dof)
    return {"measured": measured, "synth_mean": float(synth.mean()), "synth_std": float(synth.std(ddof=1)),
            "z": 0.0, "rel_error": 0.0, "resolution": F, "dof": dof, "n_synth": n_synth}


def _joint_z(rng, sigma, n_stacks, dof=1):
    return _joint(NAME, [_stack(rng, sigma, dof=dof) for _ in range(n_stacks)], 6.0, 0.1)


def test_flat_gain_spread_is_pooled():
    assert STATISTICS[NAME].pooled and STATISTICS[NAME].floor == F


def test_pooled_z_is_standard_normal_above_the_light_and_below_the_model():
    # a light that wanders by F (the most the model allows) over 20 pairs: above the model's
    # variance plus F^2 the pooled z is a chi-square of 20 degrees of freedom through its tail
    # probability (N(0, 1) there, but for the syntheses' share of the variance, 4 % of F^2,
    # estimated from 8 x 20 values), and never negative
    rng = np.random.default_rng(11)
    n = 2000
    sigma = math.sqrt(F**2 + (0.2 * F) ** 2)
    z = np.array([_joint_z(rng, sigma, 20).z for _ in range(n)])
    for q, p in ((1.0, 0.1587), (2.0, 0.02275), (3.0, 0.00135)):
        assert abs(np.mean(z > q) - p) < 5 * math.sqrt(p * (1 - p) / n) + 1 / n, (q, np.mean(z > q))
    assert z.min() >= 0.0 and np.sum(z > 6.0) == 0  # P = 1e-9 each
    # a perfectly stable light: below the model's own variance the z is that chi-square's,
    # and it never reaches the upper side (26 x its degrees of freedom)
    z0 = np.array([_joint_z(rng, 0.2 * F, 20).z for _ in range(n)])
    for q, p in ((-1.0, 0.1587), (-2.0, 0.02275)):
        assert abs(np.mean(z0 < q) - p) < 5 * math.sqrt(p * (1 - p) / n) + 1 / n, (q, np.mean(z0 < q))
    assert z0.max() <= 0.0 and np.sum(z0 < -6.0) == 0
    # and so for stacks of 8 frames (7 degrees of freedom each)
    z8 = np.array([_joint_z(rng, sigma, 6, dof=7).z for _ in range(n)])
    assert abs(np.mean(z8 > 2.0) - 0.02275) < 5 * math.sqrt(0.02275 * 0.97725 / n) + 1 / n, np.mean(z8 > 2.0)


def test_a_model_above_the_measured_spread_is_significant_only_beyond_the_light():
    # frames of a stable light (the spread of shot noise, 0.1 F) against a model that makes
    # frame means wander by 0.8 F (a row drift with a frame mean, say) and by 3 F (a gain
    # jitter nobody has): both overshoot far beyond chance, but only the second by more than
    # the light's resolution
    rng = np.random.default_rng(16)
    small = [_joint(NAME, [_stack(rng, 0.1 * F, synth_sigma=0.8 * F) for _ in range(20)], 6.0, 0.1) for _ in range(100)]
    large = [_joint(NAME, [_stack(rng, 0.1 * F, synth_sigma=3 * F) for _ in range(20)], 6.0, 0.1) for _ in range(100)]
    assert all(r.z < -6.0 for r in small + large)
    assert not any(r.significant for r in small)
    assert all(r.significant for r in large)


def test_three_times_the_light_is_found_over_twenty_pairs_and_not_on_one():
    rng = np.random.default_rng(12)
    n = 500
    pooled = np.array([_joint_z(rng, 3 * F, 20) for _ in range(n)])
    single = np.array([_joint_z(rng, 3 * F, 1) for _ in range(n)])
    found = np.mean([r.significant for r in pooled])
    alone = np.mean([r.significant for r in single])
    # expected: P(chi2_20 > 77 / 8.7) = 0.98 pooled; P(chi2_1 > 37 / 8.7) = 0.04 on one pair (9 F^2 over the
    # model's 1.04 F^2; measured over these 500: 0.97 and 0.042)
    assert found >= 0.95, found
    assert alone <= 0.04 + 5 * math.sqrt(0.04 * 0.96 / n), alone
    # the pooled error figure: measured 3 F against a model of 0.2 F
    assert np.median([r.rel_error for r in pooled]) > 0.8


def test_a_model_with_the_jitter_leaves_nothing_significant():
    # the same 20 pairs against a model that has the jitter: z within the null's spread
    rng = np.random.default_rng(13)
    n = 500
    out = [_joint(NAME, [_stack(rng, 3 * F, synth_sigma=3 * F) for _ in range(20)], 6.0, 0.1) for _ in range(n)]
    assert not any(r.significant for r in out)
    assert np.median([r.rel_error for r in out]) < 0.3


def _residual(name, z, significant=False, own=None):
    return Residual(name, 1.0, 0.5, 0.1, z, 0.5, significant, ["X"], "", {"stack": own} if own else {})


def test_pool_residuals_one_carrier_the_others_point_to_it_and_idempotent():
    rng = np.random.default_rng(14)
    labels = [f"flat {i}" for i in range(10)]
    diags = {"bias": ([_residual("pixel_std", 7.0, True)], None)}
    for label in labels:
        own = _stack(rng, 10 * F)  # 10 pairs: significant unless chi2_10 < 0.7 (P = 1e-5)
        diags[label] = ([_residual(NAME, 1.0, False, own), _residual("pixel_std", 0.5)], None)
    pooled = pool_residuals(diags)
    assert list(pooled) == list(diags)
    first = next(r for r in pooled[labels[0]][0] if r.statistic == NAME)
    assert first.pooled["over"] == labels and first.significant and first.z > 6.0
    for label in labels[1:]:
        r = next(r for r in pooled[label][0] if r.statistic == NAME)
        assert r.pooled["into"] == labels[0] and not r.significant
        assert r.measured == r.pooled["stack"]["measured"]  # its own figures, for the report
    assert pooled["bias"][0][0] is diags["bias"][0][0]  # other statistics untouched
    again = pool_residuals(pooled)
    assert [[r.to_dict() for r in res] for res, _ in again.values()] == [[r.to_dict() for r in res] for res, _ in pooled.values()]
    # a subset pools over its own stacks only
    part = pool_residuals({label: diags[label] for label in labels[2:]})
    assert next(r for r in part[labels[2]][0] if r.statistic == NAME).pooled["over"] == labels[2:]


def test_pooled_signature_puts_the_pairs_end_to_end():
    # 20 flat pairs with a 0.3 % gain jitter against syntheses without it and with it: 40 frame
    # means over their level; the model with the jitter is the nearer (distance after over
    # before about 0.6, 0.44-0.80 over seeds 0-4 of this set-up: the model's curve is the
    # mean over 8 syntheses of each pair's sorted means, the measured one a single pair's)
    from rawaug.loop.signatures import pooled_signature

    rng = np.random.default_rng(15)

    def pair(level, jitter):
        gains = 1.0 + rng.normal(0.0, jitter, (2, 1, 1, 1))
        return level * gains + rng.normal(0.0, 1.0, (2, 4, 16, 16))

    levels = np.repeat([300.0, 800.0, 1600.0, 3200.0, 6400.0], 4)
    parts = [(pair(lv, 0.003), np.stack([pair(lv, 0.0) for _ in range(8)]), np.stack([pair(lv, 0.003) for _ in range(8)]))
             for lv in levels]
    sig = pooled_signature(NAME, parts)
    assert sig["kind"] == "frame_means_relative" and sig["pooled_over"] == 20
    assert len(sig["x"]) == len(sig["measured"]) == len(sig["before"]) == len(sig["after_std"]) == 40
    assert sig["distance_after"] < sig["distance_before"], (sig["distance_before"], sig["distance_after"])
    assert 0.001 < sig["distance_before"] < 0.003  # half a pair's |difference|: 0.3 % x E|N| / sqrt(2) = 0.0017


def _flats(rng, levels, jitter, per_level=2, exposures=True):
    """{(ISO, exposure, light): [(packed, headroom)]} of flats at ``levels`` (DN), a relative
    gain ``jitter`` per frame: at an exposure each (as a manifest lists a series), or all at
    one exposure (under lights the manifest does not list)."""
    frame = lambda lv: (np.full((4, 8, 8), lv * (1.0 + rng.normal(0.0, jitter))), None)  # noqa: E731
    if exposures:
        return {(iso, lv / 1e4, None): [frame(lv) for _ in range(per_level)] for iso in (800, 3200) for lv in levels}
    return {(iso, 0.5, None): [frame(lv) for lv in levels for _ in range(per_level)] for iso in (800, 3200)}


def test_a_jittering_pair_stays_one_level_and_unlisted_lights_still_split(capsys):
    # 1 % gain jitter, pairs at five exposures and two ISOs: a pair's frames differ by more than
    # the 2 % that splits a setting 16 % of the time, so most cameras had a pair split into two
    # frames of no level; against 10 x the camera's jitter (the median of its 10 gaps) one
    # camera in 440 has (simulated), so at most 4 of these 200 (Poisson, P = 1e-4 at 0.45)
    from rawaug.loop.command import _split_levels

    rng = np.random.default_rng(17)
    levels = (300.0, 1500.0, 4500.0, 7500.0, 12000.0)
    split = sum(len(_split_levels(_flats(rng, levels, 0.01))) != 10 for _ in range(200))
    assert split <= 4, split
    # one exposure under five unlisted lights, two frames (or one) each: five levels per ISO
    for per_level in (2, 1):
        out = _split_levels(_flats(rng, levels, 0.001, per_level=per_level, exposures=False))
        assert len(out) == 10 and all(len(v) == per_level for v in out.values()), (per_level, [len(v) for v in out.values()])
    assert "fall at 5 levels" in capsys.readouterr().out
