"""Charge sharing (ChargeShare): part of a pixel's photo charge lands in its raw neighbours.

Physics: carriers generated deep in the silicon diffuse sideways before a photodiode collects
them, and inter-pixel capacitance couples a pixel's collected charge into its neighbours'
sense nodes. Either mixes each pixel's shot-noise count with its four raw neighbours': a flat
field's noise is then correlated between neighbours (and lower than Poisson per pixel), bias
frames show nothing. Light reaching the silicon at an angle crosses into a diagonal
neighbour (optical crosstalk), and charge left behind in a transfer lands in the next pixel
of the line (CTI): one direction only, but a pixel's noise keeps the same correlations with
half its share each way. Read noise, added after, is not shared (that is ``Xtalk``).

Stage (DN, after shot noise, before ``NonLin`` and the readout gains): the pixel's shot-noise
deviation ``d = count K - s`` is replaced by
``c d(Y, X) + a_x (d(Y, X-1) + d(Y, X+1)) + a_y (d(Y-1, X) + d(Y+1, X))
+ a_d1 (d(Y-1, X-1) + d(Y+1, X+1)) + a_d2 (d(Y-1, X+1) + d(Y+1, X-1))``
at raw position ``(Y, X)``, with ``c = 1 - 2 (a_x + a_y + a_d1 + a_d2)`` and all divided by
``sqrt(c^2 + 2 (a_x^2 + a_y^2 + a_d1^2 + a_d2^2))`` (the diagonals a stage of their own,
``CHARGE_SHARE_DIAG``, only where one is shared). A neighbour's deviation is its own shot draw (the same
counter-based count its own element draws), from the neighbour's clean value taken through
this pixel's gains and dark signal; a neighbour outside the frame contributes nothing.
The mean is left as it is (a clean image of the camera holds its blur already), and so is each
pixel's variance: the profile's K is the photon-transfer gain, measured on shared charge
(the conversion gain proper is K over that sum of squares).

Profile entry::  ``ChargeShare: {share_x: 0.03, share_y: 0.03, share_d1: 0.0, share_d2: 0.0}``
(fraction of a pixel's charge going to each horizontal / vertical / diagonal neighbour, along
(1, 1) and along (1, -1); the diagonals optional; no ISO dependence)

Detected by ``neighbour_corr`` on flat stacks. Estimated by ``estimate``: the covariance of the
temporal residual at the raw lags of ``XTALK_LAGS`` in excess of the model's, over the shot
variance ``K x level``, lags within 3 sd of the model's spread left at 0; ``combine`` pools the
flats weighted by their shot variance's share and fits ``a_x``, ``a_y`` to the correlations
(``correlations``), the diagonals where a diagonal lag shows any.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from ..engine import layout as L
from ..statistics import lag_covariances
from .base import SHOT, NoiseEffect, register
from .k_records import _number

STATISTICS = ("neighbour_corr",)
KEYS = ("share_x", "share_y", "share_d1", "share_d2")
MAX_SHARE = 1.0 / 6.0  # beyond it a neighbour's weight passes the pixel's own
SIGNIFICANT = 3.0  # a lag's excess counts beyond this many sd of the model's


def weights(share_x: float, share_y: float, share_d1: float = 0.0, share_d2: float = 0.0) -> tuple[float, ...]:
    """(centre, horizontal, vertical, diagonal (1, 1), diagonal (1, -1)) weights of the shot
    deviations, of unit sum of squares."""
    shares = (share_x, share_y, share_d1, share_d2)
    centre = 1.0 - 2.0 * sum(shares)
    norm = math.sqrt(centre**2 + 2.0 * sum(a * a for a in shares))
    return (centre / norm,) + tuple(a / norm for a in shares)


def correlations(share_x: float, share_y: float, share_d1: float = 0.0, share_d2: float = 0.0) -> np.ndarray:
    """Correlation of the shared shot noise at each raw lag of ``XTALK_LAGS``: the kernel's
    autocorrelation (a flat of one level)."""
    c, hx, hy, d1, d2 = weights(share_x, share_y, share_d1, share_d2)
    kernel = {(0, 0): c, (0, -1): hx, (0, 1): hx, (-1, 0): hy, (1, 0): hy, (-1, -1): d1, (1, 1): d1, (-1, 1): d2, (1, -1): d2}
    return np.array([sum(w * kernel.get((dy + ly, dx + lx), 0.0) for (dy, dx), w in kernel.items())
                     for ly, lx in L.XTALK_LAGS])


@register
class ChargeShare(NoiseEffect):
    token = "ChargeShare"
    order = SHOT + 1  # on the shot draws, before the gains that act on the signal read
    flag = L.CHARGE_SHARE | L.CHARGE_SHARE_DIAG  # every stage it may run; an instance's: the diagonals where shared
    columns = ("share_c", "share_x", "share_y", "share_d1", "share_d2")

    def __init__(self, profile):
        super().__init__(profile)
        p = profile.effects[self.token]
        diagonal = any(float(p.get(key, 0.0)) > 0.0 for key in ("share_d1", "share_d2"))
        self.flag = L.CHARGE_SHARE | (L.CHARGE_SHARE_DIAG if diagonal else 0)

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        w = weights(*(float(p.get(key, 0.0)) for key in KEYS))
        return {col: ctx.k.new_full((ctx.k.shape[0],), value) for col, value in zip(self.columns, w)}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r}")
        unknown = sorted(set(params) - set(KEYS))
        if unknown:
            raise ValueError(f"effect {cls.token!r}: unknown keys {unknown}; known: {list(KEYS)}")
        if not any(key in params for key in KEYS):
            raise ValueError(f"effect {cls.token!r} needs at least one of {list(KEYS)} (fraction of the charge per neighbour)")
        for key in KEYS:
            if key in params:
                value = _number(params[key], f"{cls.token}.{key}")
                if not 0.0 <= value <= MAX_SHARE:
                    raise ValueError(f"effect {cls.token!r}: {key} (fraction of a pixel's charge per neighbour) must be "
                                     f"in [0, {MAX_SHARE:.4f}], got {value}")
        shares = [float(params.get(key, 0.0)) for key in KEYS]
        if 1.0 - 2.0 * sum(shares) < max(shares):
            raise ValueError(f"effect {cls.token!r}: the pixel keeps 1 - 2 x the sum of its shares {sum(shares):.4f}, less "
                             f"than it gives one neighbour ({max(shares):.4f}); got {params!r}")


def estimate(frames, synthesized, k: float, level_dn=None, kind=None, **_) -> dict:
    """One record from a flat stack (N >= 2, 4, h, w) in DN at clean level ``level_dn`` (DN):
    the excess correlation at each lag over the shot variance, and that variance's share of
    the temporal variance (the record's weight)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in (None, "flat") or level_dn is None or frames.shape[0] < 2 or not synthesized:
        raise ValueError("ChargeShare is measured on flat stacks of >= 2 frames at a known level, against syntheses")
    shot_var = float(k) * float(np.mean(level_dn))
    if not shot_var > 0.0:
        raise ValueError(f"ChargeShare needs a flat above black, got level {float(np.mean(level_dn))} DN")
    temporal, measured = lag_covariances(frames)
    measured = measured / shot_var
    model = np.array([lag_covariances(np.asarray(s, dtype=np.float64))[1] / shot_var for s in synthesized])
    excess = measured - model.mean(axis=0)
    spread = model.std(axis=0, ddof=1) * np.sqrt(1.0 + 1.0 / len(model)) if len(model) > 1 else np.zeros_like(excess)
    excess = np.where(np.abs(excess) > SIGNIFICANT * spread, excess, 0.0)
    return {"corr": excess.tolist(), "weight": float(min(shot_var / max(temporal, 1e-12), 1.0))}


def fit(corr) -> dict:
    """``share_x``, ``share_y`` (and, where a diagonal lag's correlation is above 0, ``share_d1``,
    ``share_d2``) whose correlations (``correlations``) come nearest ``corr`` (one per lag of
    ``XTALK_LAGS``), in least squares within [0, MAX_SHARE]."""
    corr = np.asarray(corr, dtype=np.float64)
    if not np.any(corr > 0.0):
        return {"share_x": 0.0, "share_y": 0.0}
    at = {lag: i for i, lag in enumerate(L.XTALK_LAGS)}
    diagonal = corr[at[(1, 1)]] > 0.0 or corr[at[(1, -1)]] > 0.0
    lags = [(0, 1), (1, 0)] + ([(1, 1), (1, -1)] if diagonal else [])
    start = [min(max(corr[at[lag]] / 2.0, 0.0), MAX_SHARE) for lag in lags]
    got = optimize.least_squares(lambda a: correlations(*a) - corr, start,
                                 bounds=([0.0] * len(lags), [MAX_SHARE] * len(lags)), xtol=1e-12, ftol=1e-12)
    return {key: float(v) for key, v in zip(KEYS, got.x)}


def combine(records: list[dict]) -> dict:
    """One sharing for the sensor from its flat stacks (every ISO and level: the same pixels):
    their excess correlations averaged, weighted by the shot noise's share of each stack's
    temporal variance squared (read noise dilutes a dim flat's), then fitted."""
    w = np.array([r["weight"] for r in records], dtype=np.float64) ** 2
    if not w.sum() > 0.0:
        return {"share_x": 0.0, "share_y": 0.0}
    corr = np.sum(w[:, None] * np.array([r["corr"] for r in records]), axis=0) / w.sum()
    return fit(corr)


def empty(params) -> bool:
    """True when no charge is shared: it would add nothing."""
    return all(float(params.get(key, 0.0)) == 0.0 for key in KEYS)
