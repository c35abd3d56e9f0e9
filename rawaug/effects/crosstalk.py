"""Correlated read noise (Xtalk): neighbouring pixels share part of their read noise.

Physics: pixels that share a readout path (the amplifier of a 2x2 shared-pixel cell, a
column bus) or are coupled through the capacitance between neighbouring lines do not read
independently: part of one pixel's read noise is also in its neighbours'. A linear readout
does that as a filter: the noise read is a white field through a small kernel. The ELD read
noise is white, so it cannot make this; calibration counts the shared part as read noise.

Synthesis: one standard-normal field ``g`` over the raw mosaic, new in every frame; the pixel
at raw ``(Y, X)`` gets ``sum_t h_t g(Y - dy_t, X - dx_t)`` over the taps ``t = (dy, dx)`` of
``rawaug.engine.layout.XTALK_TAPS`` (the pixel itself and the six lags behind it in raster
order). Pixels ``l`` apart then share ``sum_t h_t h_{t+l}`` DN^2 of covariance, and each gains
``sum_t h_t^2`` of variance (the loop's read-noise re-fit takes that out of the read noise).

Profile entry (per-K records, taps in DN, one key per tap)::

    Xtalk: {k: [K, ...], tap_0_0_dn: [...], tap_0_1_dn: [...], tap_1_0_dn: [...], tap_1_1_dn: [...],
            tap_1_-1_dn: [...], tap_0_2_dn: [...], tap_2_0_dn: [...]}

Detected by ``neighbour_corr`` (the correlation of the temporal residual at the lags of
``XTALK_LAGS``, row/column means and smooth fields taken out). Estimated by ``estimate``: the
covariance at each lag over the current model's, from bias and dark stacks, of pixel pairs
in different 2x2 tiles (coupling is the same everywhere; what pairs within one tile share
beyond it is a shared-pixel readout, ``Shared``), lags whose excess lies within 3 sd of the
model's spread left at 0; then the kernel of least variance that has those covariances
(``kernel_for``). A kernel of one field holds a coupling of several neighbours with less
variance than a field per lag: read noise of 1.5 DN plus 0.6 of the left and 0.4 of the upper
neighbour's is 3.4 DN^2, which a field per lag could only make with 5.6 DN^2.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from ..engine import layout as L
from ..statistics import lag_covariances
from .base import READ, NoiseEffect, register
from .k_records import all_zero, validate_records, value_at_k

STATISTICS = ("neighbour_corr",)
KEYS = tuple(f"tap_{dy}_{dx}_dn" for dy, dx in L.XTALK_TAPS)
SHARES_READ_NOISE = True  # its variance is read noise that calibration counted as white: judged with the read noise re-fitted
SIGNIFICANT = 3.0  # a lag's excess covariance counts beyond this many sd of the model's


@register
class Crosstalk(NoiseEffect):
    token = "Xtalk"
    order = READ
    flag = L.XTALK
    columns = tuple(f"xt_{i}" for i in range(len(L.XTALK_TAPS)))

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {col: value_at_k(p, key, ctx.k) if key in p else ctx.k * 0.0 for col, key in zip(self.columns, KEYS)}

    @classmethod
    def validate_params(cls, params):
        present = tuple(key for key in KEYS if isinstance(params, dict) and key in params)
        if isinstance(params, dict) and not present:
            old = " (its entry holds the taps of a readout kernel since 2026-11-26, no longer an amplitude per lag: " \
                  "run rawaug loop again)" if any(str(key).startswith("lag_") for key in params) else ""
            raise ValueError(f"effect 'Xtalk' needs at least one of {list(KEYS)} (a kernel tap per K, DN){old}")
        validate_records(cls.token, params, present)
        unknown = sorted(set(params) - set(KEYS) - {"k"})
        if unknown:
            raise ValueError(f"effect 'Xtalk': unknown keys {unknown}; known: {['k', *KEYS]}")


def autocovariance(taps) -> np.ndarray:
    """Covariance (DN^2) at each lag of ``XTALK_LAGS`` of the noise a kernel with ``taps``
    (one per ``XTALK_TAPS``, DN) makes: ``sum_t h_t h_{t+l}``."""
    h = dict(zip(L.XTALK_TAPS, np.asarray(taps, dtype=np.float64)))
    return np.array([sum(v * h.get((t[0] + dy, t[1] + dx), 0.0) for t, v in h.items()) for dy, dx in L.XTALK_LAGS])


def kernel_for(covariances) -> np.ndarray:
    """Taps (DN, one per ``XTALK_TAPS``) of the kernel of least variance whose noise has
    ``covariances`` (DN^2, one per ``XTALK_LAGS``): least squares on the covariances with a
    penalty of 1e-3 x the largest of them on the variance (sum of squared taps), from the
    start of one tap per lag on a common centre."""
    c = np.asarray(covariances, dtype=np.float64)
    if not np.any(c):
        return np.zeros(len(L.XTALK_TAPS))
    mu = 1e-3 * float(np.max(np.abs(c)))
    centre = math.sqrt(float(np.sum(np.abs(c))))
    start = np.concatenate([[centre], c / centre])
    fit = optimize.least_squares(lambda h: np.concatenate([autocovariance(h) - c, math.sqrt(mu) * h]), start,
                                 method="lm", xtol=1e-12, ftol=1e-12)
    h = fit.x
    return -h if h[0] < 0 else h  # h and -h make the same noise: the centre tap positive


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
    return {"k": [float(k)], **{key: [float(h)] for key, h in zip(KEYS, kernel_for(excess))}}


def combine(records: list[dict]) -> dict:
    """One record per gain: the stacks at one K (bias, darks) averaged in covariance, and the
    kernel of least variance for the average."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(autocovariance([r.get(key, [0.0])[0] for key in KEYS]))
    out: dict = {"k": sorted(by_k)}
    kernels = [kernel_for(np.mean(by_k[k], axis=0)) for k in out["k"]]
    for i, key in enumerate(KEYS):
        out[key] = [float(h[i]) for h in kernels]
    return out


def empty(params) -> bool:
    """True when every tap is 0: it would add nothing."""
    return all_zero(params, KEYS)
