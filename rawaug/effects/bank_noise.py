"""Readout bank noise (BankNoise): interleaved column readout banks, each with a temporal noise
of its own, so the pixels' noise repeats with the banks' period across the sensor.

Physics: a column-parallel readout shares its ADCs or amplifiers among interleaved columns:
sensor column ``X`` is converted by bank ``X mod P``. A bank with a noisier comparator, input
pair or reference adds white noise of its own to every pixel it converts, new at each
conversion: the pixels' temporal variance rises in every ``P``-th column while the column
means do not move (``BankOffset`` is the banks' fixed offsets, ``NoisyCol`` a few noisy
columns at random places, ``ReadMap`` blocks of columns).

Stage (DN, with the read noise): ``s -> s + sigma[X mod period] * n``, ``n`` a standard normal
new at every pixel and frame.

Profile entry (per-K records, DN; the period in sensor columns, 3 to ``BANK_PERIOD_MAX``)::

    BankNoise: {k: [K, ...], col_period: 3, sigma_dn: [[s_0, s_1, s_2], ...]}

Detected by ``noisy_col_fraction`` and ``read_noise_spread``. Estimated by ``estimate`` from
bias stacks of >= 2 frames: each sensor column's pixel noise (``column_pixel_noise``: the median
of its pixels' temporal variance) less the model's, in variance (the median of a chi-square
of N - 1 degrees of freedom over its mean); ``combine`` pools a gain's stacks and folds the
profile at the period of least BIC (``bank_offset.bank_period``: each parity's mean removed,
an F test against none at family-wise 1e-3); each bank's extra variance is its phase's mean
over the quietest phase's. Judged with the read noise re-fitted (calibration gave the base
read noise the banks' mean variance).
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import column_pixel_noise
from .bank_offset import _phase_means, bank_period
from .base import READ, NoiseEffect, register
from .k_records import validate_records, value_at_k

STATISTICS = ("noisy_col_fraction", "read_noise_spread")
SHARES_READ_NOISE = True  # calibration's read noise holds the banks' mean extra variance
PERIOD_MAX = L.BANK_PERIOD_MAX


@register
class BankNoise(NoiseEffect):
    token = "BankNoise"
    order = READ + 1
    flag = L.BANK_NOISE
    columns = ("bnoise_cp", *(f"bnoise_c{i}" for i in range(PERIOD_MAX)))

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        period = int(p["col_period"])
        out = {"bnoise_cp": ctx.k.new_full(ctx.k.shape, float(period))}
        for j in range(PERIOD_MAX):
            phase = {"k": p["k"], "v": [rec[j] for rec in p["sigma_dn"]]} if j < period else None
            out[f"bnoise_c{j}"] = value_at_k(phase, "v", ctx.k) if phase else ctx.k.new_zeros(ctx.k.shape)
        return out

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",))
        period = params.get("col_period")
        if isinstance(period, bool) or not isinstance(period, (int, float)) or period != int(period) or not 3 <= period <= PERIOD_MAX:
            raise ValueError(f"effect {cls.token!r}: col_period must be a whole number of sensor columns in [3, {PERIOD_MAX}], "
                             f"got {period!r}")
        for r, rec in enumerate(params["sigma_dn"]):
            arr = np.asarray(rec, dtype=np.float64) if isinstance(rec, (list, tuple)) else None
            if arr is None or arr.shape != (int(period),) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ValueError(f"effect {cls.token!r}: sigma_dn record {r} must hold {int(period)} values >= 0 (DN, one per "
                                 f"bank), got {rec!r:.80}")


def _variance_profile(frames) -> np.ndarray:
    """(2w,) each sensor column's pixel temporal variance (DN^2): ``column_pixel_noise``'s
    median over its pixels, over the median of a chi-square of N - 1 degrees of freedom."""
    n = np.shape(frames)[0]
    return column_pixel_noise(frames) / (stats.chi2.median(n - 1) / (n - 1))


def estimate(frames, synthesized, k: float, kind: str = "bias", **_) -> dict:
    """One record from a bias stack against its syntheses: its sensor columns' pixel variance
    less the model's (``combine`` finds the period)."""
    if kind != "bias" or not len(synthesized) or np.shape(frames)[0] < 2:
        raise ValueError("BankNoise is measured on bias stacks of >= 2 frames, against syntheses")
    excess = _variance_profile(frames) - np.mean([_variance_profile(s) for s in synthesized], axis=0)
    return {"k": [float(k)], "excess_dn2": excess.tolist()}


def combine(records: list[dict]) -> dict:
    """Per gain: the stacks' profiles averaged; the period of the camera is the one most gains
    find (``bank_period``), each bank's extra variance its phase's mean over the quietest's."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(np.asarray(r["excess_dn2"]))
    ks = sorted(by_k)
    pooled = {k: np.mean([p for p in by_k[k] if p.size == by_k[k][0].size], axis=0) for k in ks}
    found = [p for p in (bank_period(pooled[k])[0] for k in ks) if p > 1]
    if not found:
        return {"k": ks, "col_period": 1, "sigma_dn": [[0.0] for _ in ks]}
    period = max(set(found), key=found.count)
    sigma = []
    for k in ks:
        phases = _phase_means(pooled[k], period)
        sigma.append([round(float(np.sqrt(max(v - phases.min(), 0.0))), 4) for v in phases])
    return {"k": ks, "col_period": int(period), "sigma_dn": sigma}


def empty(params) -> bool:
    """True where no period was found (nothing to add)."""
    return int(params["col_period"]) < 3
