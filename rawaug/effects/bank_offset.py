"""Readout bank offsets (BankOffset): interleaved column (or row) readout banks, each with a
black offset of its own, so the offsets repeat with the banks' period across the sensor.

Physics: a column-parallel readout shares its ADCs, amplifiers or reference lines among
interleaved columns: sensor column ``X`` is converted by bank ``X mod P``, and each bank's
offset is matched to the others only to a fraction of a DN. Bias frames then show a fixed
column pattern that repeats every ``P`` columns (tones at multiples of ``1 / P`` cycles per
column); rows read by interleaved row drivers or by a readout that alternates between
several banks per line do the same along the rows. ``Col`` is a white random offset per
column and ``TapBlack`` contiguous regions; a period of 2 is each colour channel's own offset
(the colour bias).

Stage (DN, with the other offsets): ``s -> s + col_dn[X mod col_period] + row_dn[Y mod row_period]``
on sensor column ``X`` and row ``Y`` of the input (a period of 1: nothing along that axis).

Profile entry (per-K records, DN; periods in sensor lines, 1 to ``BANK_PERIOD_MAX``)::

    BankOffset: {k: [K, ...], col_period: 4, col_dn: [[o_0, ..., o_3], ...], row_period: 1, row_dn: [[0.0], ...]}

Detected by ``col_tone``, ``row_tone``, ``fixed_col_excess`` and ``fixed_row_excess``.
Estimated by ``estimate`` from bias and dark stacks: the stack mean's sensor-line profiles
(each channel's mean removed) less the model's (the mean over its syntheses); ``combine``
pools a gain's stacks and picks, per axis, the period of least BIC among 1 (none) and 3 ..
``BANK_PERIOD_MAX`` for the folded means (each phase's mean, against the scatter of the
lines about them: a sensor's random line offsets), kept only where its F test against no
period passes at family-wise ``ALPHA``.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..engine import layout as L
from .base import OFFSET, NoiseEffect, register
from .k_records import validate_records, value_at_k

STATISTICS = ("col_tone", "row_tone", "fixed_col_excess", "fixed_row_excess")
SIGNED = True  # offsets of either sign
PERIOD_MAX = L.BANK_PERIOD_MAX
ALPHA = 1e-3  # family-wise false period per axis and gain
AXES = (("col_period", "col_dn", "col_excess"), ("row_period", "row_dn", "row_excess"))


@register
class BankOffset(NoiseEffect):
    token = "BankOffset"
    order = OFFSET + 1
    flag = L.BANK_OFFSET
    columns = ("bank_cp", "bank_rp", *(f"bank_c{i}" for i in range(PERIOD_MAX)), *(f"bank_r{i}" for i in range(PERIOD_MAX)))

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        out = {"bank_cp": ctx.k.new_full(ctx.k.shape, float(p["col_period"])),
               "bank_rp": ctx.k.new_full(ctx.k.shape, float(p["row_period"]))}
        for axis, key, prefix in (("col_period", "col_dn", "bank_c"), ("row_period", "row_dn", "bank_r")):
            for j in range(PERIOD_MAX):
                if j < int(p[axis]):
                    phase = {"k": p["k"], "v": [rec[j] for rec in p[key]]}
                    out[f"{prefix}{j}"] = value_at_k(phase, "v", ctx.k)
                else:
                    out[f"{prefix}{j}"] = ctx.k.new_zeros(ctx.k.shape)
        return out

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("col_dn", "row_dn"))
        for axis, key, _ in AXES:
            period = params.get(axis)
            if isinstance(period, bool) or not isinstance(period, (int, float)) or period != int(period) \
                    or not 1 <= period <= PERIOD_MAX:
                raise ValueError(f"effect {cls.token!r}: {axis} must be a whole number of sensor lines in [1, {PERIOD_MAX}], got {period!r}")
            for r, rec in enumerate(params[key]):
                arr = np.asarray(rec, dtype=np.float64) if isinstance(rec, (list, tuple)) else None
                if arr is None or arr.shape != (int(period),) or not np.all(np.isfinite(arr)):
                    raise ValueError(f"effect {cls.token!r}: {key} record {r} must hold {int(period)} offsets (DN, one per bank), "
                                     f"got {rec!r:.80}")


def sensor_profiles(frames) -> tuple[np.ndarray, np.ndarray]:
    """((2w,) sensor-column, (2h,) sensor-row) profiles of a stack's mean (N, 4, h, w; DN),
    each channel's mean removed (R, G1 on even sensor rows; R, G2 on even sensor columns)."""
    m = np.asarray(frames, dtype=np.float64).mean(axis=0)
    m = m - m.mean(axis=(1, 2), keepdims=True)
    cols, rows = m.mean(axis=1), m.mean(axis=2)
    col = np.empty(2 * cols.shape[1])
    col[0::2], col[1::2] = (cols[0] + cols[3]) / 2.0, (cols[1] + cols[2]) / 2.0
    row = np.empty(2 * rows.shape[1])
    row[0::2], row[1::2] = (rows[0] + rows[1]) / 2.0, (rows[2] + rows[3]) / 2.0
    return col, row


def estimate(frames, synthesized, k: float, kind: str = "bias", **_) -> dict:
    """One record from a bias or dark stack against its syntheses: its sensor-line profiles
    less the model's (``combine`` finds the periods)."""
    if kind == "flat" or not synthesized:
        raise ValueError("BankOffset is measured on bias and dark stacks, against syntheses")
    col, row = sensor_profiles(frames)
    model = [sensor_profiles(s) for s in synthesized]
    return {"k": [float(k)], "col_excess": (col - np.mean([m[0] for m in model], axis=0)).tolist(),
            "row_excess": (row - np.mean([m[1] for m in model], axis=0)).tolist()}


def _phase_means(x, period: int) -> np.ndarray:
    """(period,) means of ``x`` over its lines of each phase (index mod ``period``)."""
    phase = np.arange(x.size) % period
    return np.bincount(phase, weights=x, minlength=period) / np.bincount(phase, minlength=period)


def _parity_free(x) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64).copy()
    x[0::2] -= x[0::2].mean()
    x[1::2] -= x[1::2].mean()
    return x


def bank_period(profile) -> tuple[int, list[float]]:
    """(period, offsets per phase) of a sensor-line profile: the period of least BIC among 1
    and 3 .. PERIOD_MAX (each parity's mean removed first: those are the channels' own
    offsets), where its F test against none passes at ALPHA over the periods tried; else (1, [0])."""
    x = _parity_free(profile)
    n = x.size
    rss0 = float(np.sum(x**2))
    if n < 3 * 3 or rss0 <= 0:
        return 1, [0.0]
    best = (n * math.log(rss0 / n), 1, [0.0])
    tried = [p for p in range(3, PERIOD_MAX + 1) if n >= 3 * p]
    for p in tried:
        means = _phase_means(x, p)
        rss = float(np.sum((x - means[np.arange(n) % p]) ** 2))
        dof = p - 2 if p % 2 == 0 else p - 1  # free phase means: an even period's phases hold one parity each
        if rss <= 0 or n - dof - 2 <= 0:
            continue
        f = ((rss0 - rss) / dof) / (rss / (n - dof - 2))
        if stats.f.sf(f, dof, n - dof - 2) * len(tried) >= ALPHA:
            continue
        bic = n * math.log(rss / n) + dof * math.log(n)
        if bic < best[0]:
            best = (bic, p, [float(v) for v in means])
    return best[1], best[2]


def combine(records: list[dict]) -> dict:
    """Per gain: the stacks' profiles averaged (those of the first's length), then per axis the
    period and offsets of ``bank_period``; the period of the camera is the one most gains
    found (banks do not change with the gain), offsets re-folded at it."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    ks = sorted(by_k)
    out: dict = {"k": ks}
    for axis, key, excess in AXES:
        pooled = {}
        for k in ks:
            profiles = [np.asarray(r[excess]) for r in by_k[k]]
            pooled[k] = np.mean([p for p in profiles if p.size == profiles[0].size], axis=0)
        periods = [bank_period(pooled[k])[0] for k in ks]
        found = [p for p in periods if p > 1]
        period = max(set(found), key=found.count) if found else 1
        out[axis] = int(period)
        out[key] = [_fold(pooled[k], period) for k in ks]
    return out


def _fold(profile, period: int) -> list[float]:
    if period == 1:
        return [0.0]
    return [round(float(v), 4) for v in _phase_means(_parity_free(profile), period)]


def empty(params) -> bool:
    """True when neither axis has a period (nothing to add)."""
    return int(params["col_period"]) == 1 and int(params["row_period"]) == 1
