"""Measured read-noise distribution (ReadDist), a measured fallback: the dark residual's
own quantile function in place of the Tukey-lambda read noise.

Not a named physical effect: a read chain with few distinct levels, a firmware that
re-quantizes or dithers dark pixels, or clipping of dark pixels leave the read noise
outside the Tukey-lambda family, and the model's histogram statistics (``ppcc_r2``,
``tail_mass``, ``hot_fraction``, ``clip_low``) then miss in either direction. The loop
tries this component only when no physical effect explains them; the report lists it as
reproduced by measurement.

Stage (DN, in place of G* / G): ``s -> s + scale * Q_c(z)``, ``z`` the pixel's standard
normal read draw and ``Q_c`` the measured quantile function of channel ``c`` on a uniform
grid of normal scores ``z`` in [-Z_MAX, Z_MAX] (``Q_c(z)`` is the residual's quantile at
probability Phi(z); linear between grid points; the tails as far as the frames reach).
``scale`` carries the table to another gain: the profile's read-noise relation at the
drawn K over its value at the record's K (1 at the measured K).

Profile entry (per-K records)::  ``ReadDist: {k: [K, ...], quantiles_dn: [[[q, ...] x 4] per K]}``
(DN; zero mean per channel).

Estimated by ``estimate``: the quantiles, at the grid's probabilities, of the dark
residual stage 1 fits the Tukey lambda to (each frame's row means and channel mean removed,
defect lines repaired, single-frame events kept, whole codes dequantized: ``dequantized``; the pixels of the hot-pixel
detector left out where the model already places hot pixels), zero mean. The loop's read-noise re-fit does not apply
to it; the colour bias is fitted with it (``rawaug.loop.diagnose.fitted_offsets``).
"""
from __future__ import annotations

import numpy as np
import torch
from scipy import stats

from ..engine import layout as L
from .base import READ, NoiseEffect, log_linear_draw, register
from .k_records import record_index, validate_records, value_at_k

STATISTICS = ("ppcc_r2", "tail_mass", "hot_fraction", "clip_low", "spike_fraction")  # a one-sided or heavy tail makes single-frame events
MEASURED = True
RAW_FRAMES = True  # the residual keeps the single-frame events (``with_impulses``): they are the tail it measures
TWO_SIDED = True  # it replaces the read noise's shape: it can lower a statistic as well as raise it
N_GRID = 257  # normal scores on the grid
Z_MAX = L.READ_TABLE_Z  # grid range; beyond it a draw takes the end value


@register
class ReadDistribution(NoiseEffect):
    token = "ReadDist"
    order = READ + 1
    flag = L.READ_TABLE
    columns = ("readq_record", "readq_scale")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        record = record_index(p, ctx.k)
        relation = self.profile.tukey_scale or self.profile.gaussian_scale
        if relation is None:
            scale = torch.ones_like(ctx.k)
        else:
            zero = torch.zeros_like(ctx.k)
            scale = log_linear_draw(relation, torch.log(ctx.k), zero) / log_linear_draw(relation, torch.log(value_at_k(p, "k", ctx.k)), zero)
        return {"readq_record": record.to(torch.float64), "readq_scale": scale}

    def tables(self):
        q = np.asarray(self.profile.effects[self.token]["quantiles_dn"], dtype=np.float64)
        return {"read_lut": torch.from_numpy(q.reshape(-1, q.shape[-1]).copy())}  # (records * 4, N_GRID)

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("quantiles_dn",))
        try:
            q = np.asarray(params["quantiles_dn"], dtype=np.float64)
        except (TypeError, ValueError):
            q = None
        if q is None or q.shape != (len(params["k"]), 4, N_GRID) or not np.all(np.isfinite(q)) or np.any(np.diff(q, axis=-1) < 0):
            raise ValueError(f"effect 'ReadDist': quantiles_dn must hold, per k, 4 channels x {N_GRID} non-decreasing finite DN, "
                             f"got an array of shape {getattr(q, 'shape', '?')}")


def grid() -> np.ndarray:
    """The normal scores of the table's points."""
    return np.linspace(-Z_MAX, Z_MAX, N_GRID)


def dequantized(codes, seed: int = 0) -> np.ndarray:
    """Whole-DN ``codes`` spread uniformly over the values the ADC writes them for: each
    written code over half-way to its written neighbours (one DN where every code is
    written; a comb's wider cells where the camera skips codes), so that the table holds
    the noise before the ADC and row offsets, clipping and the code map act on it as on a
    sensor (a table of the codes themselves would round row noise away)."""
    from ..statistics import written_codes

    v = np.asarray(codes, dtype=np.float64)
    lo = v.min()
    written = lo + np.flatnonzero(written_codes(v.ravel()))
    below = np.concatenate([[written[0] - 1.0], written[:-1]])
    above = np.concatenate([written[1:], [written[-1] + 1.0]])
    i = np.searchsorted(written, v)
    low, high = (below[i] + written[i]) / 2.0, (above[i] + written[i]) / 2.0
    return low + (high - low) * np.random.default_rng(seed).random(v.shape)


def residual(frames, seed: int = 0) -> np.ndarray:
    """(N, 4, h, w) DN: the frames' dark residual, stage 1's (row means and channel mean of
    each frame removed) with dead pixels and defect lines repaired first, single-frame events
    kept (``with_impulses``: a read noise's own tail), whole codes dequantized."""
    from ..statistics import with_impulses

    c = np.array(with_impulses(np.asarray(frames, dtype=np.float64)))
    if np.all(c == np.rint(c)):
        c = dequantized(c, seed)
    c -= c.mean(axis=3, keepdims=True)
    return c - c.mean(axis=(2, 3), keepdims=True)


def estimate(frames, synthesized, k: float, *, level_dn=None, exposure_s=None, seed: int = 0, **_) -> dict:
    """Quantile tables (DN, per channel) of the dark residual of a bias or dark stack at
    gain ``k``."""
    if level_dn:
        raise ValueError("ReadDist is measured on bias or dark frames, not on flats")
    r = residual(frames, seed)
    if r.shape[2] * r.shape[3] * r.shape[0] < 1000:
        raise ValueError(f"ReadDist needs >= 1000 pixels per channel, got {r.shape[0]} x {r.shape[2]} x {r.shape[3]}")
    keep = np.ones(r.shape[1:], dtype=bool)
    if synthesized is not None and len(synthesized) and _model_has_hot_pixels(synthesized):
        from .hot_pixels import detect  # the model places hot pixels: they are not read noise here

        keep = ~detect(frames)[0].reshape(keep.shape)
    q = np.stack([np.quantile(r[:, c][:, keep[c]].ravel(), stats.norm.cdf(grid())) for c in range(4)])
    q -= table_mean(q)[:, None]  # zero mean (linear interpolation moves it a little): the offsets are the colour bias's
    return {"k": [float(k)], "quantiles_dn": [q.tolist()], "exposure_s": [float(exposure_s or 0.0)]}


def _model_has_hot_pixels(synthesized) -> bool:
    from .hot_pixels import detect

    return any(detect(np.asarray(s, dtype=np.float64))[0].any() for s in synthesized[:2])


def table_mean(q) -> np.ndarray:
    """Mean (DN) of the stage's values per table row: E[Q(Z)], Z standard normal."""
    z = np.linspace(-Z_MAX - 2.0, Z_MAX + 2.0, 8001)
    w = stats.norm.pdf(z)
    w /= w.sum()
    return np.array([np.interp(z, grid(), row) @ w for row in np.atleast_2d(q)])


def combine(records: list[dict]) -> dict:
    """One table per gain: of several stacks at one K, the shortest exposure's (bias frames
    hold the read noise alone; a long dark adds dark-current shot noise)."""
    by_k: dict = {}
    for r in records:
        t = r.get("exposure_s", [0.0])[0]
        if r["k"][0] not in by_k or t < by_k[r["k"][0]][0]:
            by_k[r["k"][0]] = (t, r["quantiles_dn"][0])
    ks = sorted(by_k)
    return {"k": ks, "quantiles_dn": [by_k[k][1] for k in ks]}
