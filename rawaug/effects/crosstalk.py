"""Correlated read noise (Xtalk): neighbouring pixels share part of their read noise.

Physics: pixels that share a readout path (the amplifier of a 2x2 shared-pixel cell, a
column bus) or are coupled through the capacitance between neighbouring lines do not read
independently: part of one pixel's read noise is also in its neighbours'. The ELD read
noise is white, so it cannot make this; calibration counts the shared part as read noise.

Synthesis: for each raw lag ``l = (dy, dx)`` of ``rawaug.engine.layout.XTALK_LAGS`` a
standard-normal field ``g_l`` over the raw mosaic, new in every frame; the pixel at raw
``(Y, X)`` gets ``|a_l| g_l(Y, X) + a_l g_l(Y - dy, X - dx)``, so pixels ``l`` apart share
``a_l |a_l|`` DN^2 of covariance (negative for ``a_l < 0``) and each gains ``2 a_l^2`` of
variance (the read-noise re-fit of the loop takes that out of the read noise).

Profile entry (per-K records, signed amplitudes in DN, one key per lag)::

    Xtalk: {k: [K, ...], lag_0_1_dn: [...], lag_1_0_dn: [...], lag_1_1_dn: [...],
            lag_1_-1_dn: [...], lag_0_2_dn: [...], lag_2_0_dn: [...]}

Detected by ``neighbour_corr`` (the correlation of the temporal residual at those lags,
row/column means and smooth fields taken out). Estimated by ``estimate``: the covariance at
each lag over the current model's, from bias and dark stacks, of pixel pairs in different
2x2 tiles (coupling is the same everywhere; what pairs within one tile share beyond it is a
shared-pixel readout, ``Shared``); lags whose excess lies within 3 sd of the model's spread
are left at 0.
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import lag_covariances
from .base import READ, NoiseEffect, register
from .k_records import all_zero, validate_records, value_at_k

STATISTICS = ("neighbour_corr",)
KEYS = tuple(f"lag_{dy}_{dx}_dn" for dy, dx in L.XTALK_LAGS)
SHARES_READ_NOISE = True  # its variance is read noise that calibration counted as white: judged with the read noise re-fitted
SIGNIFICANT = 3.0  # a lag's excess covariance counts beyond this many sd of the model's


@register
class Crosstalk(NoiseEffect):
    token = "Xtalk"
    order = READ
    flag = L.XTALK
    columns = tuple(f"xt_{i}" for i in range(len(L.XTALK_LAGS)))

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {col: value_at_k(p, key, ctx.k) if key in p else ctx.k * 0.0 for col, key in zip(self.columns, KEYS)}

    @classmethod
    def validate_params(cls, params):
        present = tuple(key for key in KEYS if isinstance(params, dict) and key in params)
        if isinstance(params, dict) and not present:
            raise ValueError(f"effect 'Xtalk' needs at least one of {list(KEYS)} (signed amplitude per K, DN)")
        validate_records(cls.token, params, present)
        unknown = sorted(set(params) - set(KEYS) - {"k"})
        if unknown:
            raise ValueError(f"effect 'Xtalk': unknown keys {unknown}; known: {['k', *KEYS]}")


def estimate(frames, synthesized, k: float, level_dn=None, **_) -> dict:
    """Xtalk record at gain ``k`` from a bias or dark stack (N >= 2, 4, h, w) in DN."""
    frames = np.asarray(frames, dtype=np.float64)
    if level_dn is not None or frames.shape[0] < 2:
        raise ValueError("Xtalk is measured on bias and dark stacks of >= 2 frames")
    measured = lag_covariances(frames, across_tiles=True)[1]
    model = np.array([lag_covariances(np.asarray(s, dtype=np.float64), across_tiles=True)[1] for s in synthesized])
    excess = measured - model.mean(axis=0)
    spread = model.std(axis=0, ddof=1) * np.sqrt(1.0 + 1.0 / len(model)) if len(model) > 1 else np.zeros_like(excess)
    excess = np.where(np.abs(excess) > SIGNIFICANT * spread, excess, 0.0)
    amplitude = np.sign(excess) * np.sqrt(np.abs(excess))
    return {"k": [float(k)], **{key: [float(a)] for key, a in zip(KEYS, amplitude)}}


def combine(records: list[dict]) -> dict:
    """One record per gain: the stacks at one K (bias, darks) averaged in covariance."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    out: dict = {"k": sorted(by_k)}
    for key in KEYS:
        cov = [np.mean([np.sign(r[key][0]) * r[key][0] ** 2 for r in by_k[k]]) for k in out["k"]]
        out[key] = [float(np.sign(c) * np.sqrt(abs(c))) for c in cov]
    return out


def empty(params) -> bool:
    """True when every amplitude is 0: it would add nothing."""
    return all_zero(params, KEYS)
