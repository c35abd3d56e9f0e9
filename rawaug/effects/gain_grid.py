"""Measured gain grid (GainGrid), a measured fallback: a periodic pattern of pixel gains.

Not one physical effect: phase-detection pixels (every n-th pixel of some rows half masked),
a microlens or colour-filter array whose cells repeat over a few pixels, a binning pattern of
a quad sensor. Each gives a fixed pattern of gains on the photo signal that repeats with a
short period, which ``PRNU`` (white, one spread) and ``ColGain``/``RowGain`` (one gain per
line) do not describe. The pattern is measured from flats by folding their relative fixed
pattern over the period that holds most of its variance.

Stage: ``g = gain[c, (y + oy) % py, (x + ox) % px]`` per packed channel ``c``, packed row ``y``
and column ``x``; ``s -> s * g^(1 - conversion)`` with ``PRNU``, before shot noise (light the
pixel does not get: a phase-detection pixel's mask), and ``s -> s * g^conversion`` with
``ColGain``, after it (a gain of the pixel's conversion: a line-interleaved dual-gain sensor's
rows, which scale the shot noise with the signal). The phase ``(oy, ox)`` is 0 on an input of
the measured frame's size, and drawn per sample (uniform over the period) on any other: a
training crop lies anywhere on the sensor.

Profile entry (gains of mean 1 per channel; period and frame size in packed pixels;
``conversion`` in [0, 1], 0 if absent)::

    GainGrid: {period: [py, px], gain: [[[px values] x py] x 4], conversion: 0.0, frame_h: H, frame_w: W}

Estimated by ``estimate`` from a flat stack: its mean over a smooth version of itself
(``statistics.flat_relative_map``), folded over every period up to ``GRID_MAX_PERIOD``
(``statistics.period_excess``); the period is the smallest whose fold holds
``PERIOD_SHARE`` of the largest excess variance over the noise. The gains are then folded
again, each pixel over its own period block's mean (``period_fold``: a box of another size
holds a varying count of the pattern's pixels, which would copy a ripple of the period into
the gains), and each cell's mean less the model's is kept where it stands above the
syntheses' spread (SureShrink, as ``LineMap``); the conversion share is the slope, less 1, of
the cells' log shot variance on their log mean (``conversion_share``); ``combine`` pools the
flat stacks. Detected
by ``grid_excess`` on flat stacks (the largest such excess over the pattern's variance). The
loop tries it only when no physical effect explains a residual, and the report lists it as
reproduced by measurement.
"""
from __future__ import annotations

import numpy as np
import torch
from scipy.ndimage import uniform_filter

from ..engine import layout as L
from .base import PHOTON, NoiseEffect, register
from ..statistics import GRID_MAX_PERIOD as MAX_PERIOD
from ..statistics import flat_relative_map as relative_map
from ..statistics import period_excess
from .line_profile import sure_threshold

STATISTICS = ("grid_excess",)
MEASURED = True
RAW_FRAMES = True  # a row of phase-detection pixels is what the battery repairs as a defect line
PERIOD_SHARE = 0.9  # the smallest period whose excess is this share of the largest
DECIMALS = 5


@register
class GainGrid(NoiseEffect):
    token = "GainGrid"
    order = PHOTON + 1  # with PRNU: the photo signal, before shot noise
    flag = L.GAIN_GRID
    columns = ("ggrid_record", "ggrid_py", "ggrid_px", "ggrid_oy", "ggrid_ox", "ggrid_conv")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        first, _, _ = ctx.grid_slot(self.token)
        py, px = (int(v) for v in p["period"])
        measured = (p.get("frame_h"), p.get("frame_w"))
        same = ctx.shape is not None and tuple(ctx.shape) == measured
        zero = torch.zeros_like(ctx.k)
        return {"ggrid_record": torch.full_like(ctx.k, float(first)),
                "ggrid_py": torch.full_like(ctx.k, float(py)), "ggrid_px": torch.full_like(ctx.k, float(px)),
                "ggrid_oy": zero if same else torch.floor(ctx.uniform("ggrid_oy") * py).clamp(max=py - 1),
                "ggrid_ox": zero if same else torch.floor(ctx.uniform("ggrid_ox") * px).clamp(max=px - 1),
                "ggrid_conv": torch.full_like(ctx.k, float(p.get("conversion", 0.0)))}

    def tables(self):
        return {"grids": torch.tensor(self.profile.effects[self.token]["gain"], dtype=torch.float64)}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r:.80}")
        unknown = sorted(set(params) - {"period", "gain", "frame_h", "frame_w", "conversion"})
        if unknown:
            raise ValueError(f"effect {cls.token!r}: unknown keys {unknown}; known: ['period', 'gain', 'frame_h', 'frame_w', "
                             "'conversion']")
        conversion = params.get("conversion", 0.0)
        if isinstance(conversion, bool) or not isinstance(conversion, (int, float)) or not 0.0 <= conversion <= 1.0:
            raise ValueError(f"effect {cls.token!r}: conversion (the share of the log gain applied after shot noise) "
                             f"must be a number in [0, 1], got {conversion!r:.80}")
        period = params.get("period")
        if (not isinstance(period, (list, tuple)) or len(period) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_PERIOD for v in period)):
            raise ValueError(f"effect {cls.token!r}: period must be [py, px], whole numbers of packed pixels in "
                             f"[1, {MAX_PERIOD}], got {period!r:.80}")
        try:
            gain = np.asarray(params.get("gain"), dtype=np.float64)
        except (TypeError, ValueError):
            gain = None
        if gain is None or gain.shape != (4, *period) or not np.all(np.isfinite(gain)) or np.any(gain < 0):
            raise ValueError(f"effect {cls.token!r}: gain must be 4 channels x {period[0]} x {period[1]} finite "
                             f"gains >= 0, got {params.get('gain')!r:.80}")
        for name in ("frame_h", "frame_w"):
            v = params.get(name)
            if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < 1):
                raise ValueError(f"effect {cls.token!r}: {name} must be a whole number of packed pixels >= 1, got {v!r}")


def grid_period(rel) -> tuple[int, int]:
    """The period of a map's periodic pattern: of the periods whose excess (``period_excess``)
    is at least ``PERIOD_SHARE`` of the largest, the smallest (py px, then py)."""
    excess = period_excess(rel)
    top = max(excess.values())
    return min((p for p, e in excess.items() if e >= PERIOD_SHARE * top), key=lambda p: (p[0] * p[1], p[0]))


def period_fold(frames, py: int, px: int) -> np.ndarray:
    """(4, py, px) gains of a flat stack's mean (N, 4, h, w; DN) over a period, less 1: each
    pixel over the mean of its whole period's block (3 x 3 blocks: a light's shape does not
    count, and the pattern itself is in every block's mean alike), averaged over the blocks.
    The rows and columns past the last whole block are left out."""
    m = np.asarray(frames, dtype=np.float64).mean(axis=0)
    ny, nx = m.shape[1] // py, m.shape[2] // px
    if ny < 1 or nx < 1:
        raise ValueError(f"a period of {py} x {px} needs frames at least that large, got {m.shape[1:]}")
    blocks = m[:, :ny * py, :nx * px].reshape(4, ny, py, nx, px)
    local = uniform_filter(blocks.mean(axis=(2, 4)), size=(1, 3, 3), mode="nearest")
    rel = blocks / np.where(np.abs(local) > 1e-12, local, 1e-12)[:, :, None, :, None] - 1.0
    return rel.mean(axis=(1, 3))


def estimate(frames, synthesized, k: float, level_dn=None, kind: str = "flat", **_) -> dict:
    """GainGrid from a flat stack (N >= 1, 4, h, w; DN), against stacks of the same shape
    synthesized by the current model: the period of the measured relative pattern, each
    cell's mean less the syntheses' mean, kept where it stands above their spread."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "flat":
        raise ValueError(f"GainGrid is measured on flat stacks, got a {kind!r} stack")
    if frames.ndim != 4 or frames.shape[1] != 4 or not synthesized:
        raise ValueError(f"GainGrid needs a flat stack (N, 4, h, w) and its syntheses, got {frames.shape} and "
                         f"{len(synthesized or [])} syntheses")
    rel = relative_map(frames)
    py, px = grid_period(rel)
    model = np.stack([period_fold(s, py, px) for s in synthesized])  # (S, 4, py, px)
    dev = period_fold(frames, py, px) - model.mean(axis=0)
    # the cell means' noise: their spread over the syntheses, pooled over the cells of a channel
    sigma = np.sqrt(model.var(axis=0, ddof=1).mean(axis=(1, 2)) if len(synthesized) > 1
                    else rel.var(axis=(1, 2)) * py * px / rel[0].size)
    kept = np.stack([sure_threshold(dev[c].ravel(), sigma[c]).reshape(py, px) for c in range(4)])
    gain = 1.0 + kept
    gain /= gain.mean(axis=(1, 2), keepdims=True)
    share, share_weight = conversion_share(frames, synthesized, py, px, k)
    return {"period": [py, px], "gain": np.round(gain, DECIMALS).tolist(), "frame_h": int(frames.shape[2]),
            "frame_w": int(frames.shape[3]), "weight": (1.0 / np.maximum(sigma, 1e-12) ** 2).tolist(),
            "conversion": round(share, 3), "conversion_weight": share_weight}


def _fold(m, py: int, px: int) -> np.ndarray:
    """(4, py, px) means of a map (4, h, w) over the cells of a period (whole blocks only)."""
    ny, nx = m.shape[1] // py, m.shape[2] // px
    return m[:, :ny * py, :nx * px].reshape(4, ny, py, nx, px).mean(axis=(1, 3))


def conversion_share(frames, synthesized, py: int, px: int, k: float) -> tuple[float, float]:
    """(share of the grid's log gain applied after shot noise, its weight) from a flat stack
    (N >= 2, 4, h, w; DN). A gain before shot noise (light a pixel does not get) scales a
    cell's shot variance as its mean, g; one after it (a conversion gain) as g^2: the slope of
    the cells' log shot variance on their log mean is 1 + share. The shot variance is the
    cells' temporal variance less the read noise's, the syntheses' temporal variance less K
    times their level; the weight is the slope's precision (0 where the stack cannot tell)."""
    if frames.shape[0] < 2 or not synthesized:
        return 0.0, 0.0
    n = frames.shape[0]
    mean, var = frames.mean(axis=0), frames.var(axis=0, ddof=1)
    synth = np.asarray(synthesized, dtype=np.float64)
    read = (synth.var(axis=1, ddof=1).mean(axis=(0, 2, 3)) - k * synth.mean(axis=(0, 1, 3, 4)))[:, None, None]
    m, v = _fold(mean, py, px), _fold(var, py, px) - read
    ok = (m > 0.05 * m.mean(axis=(1, 2), keepdims=True)) & (v > 0.0)
    if not np.all(ok.sum(axis=(1, 2)) >= 2):
        return 0.0, 0.0
    x = np.where(ok, np.log(np.where(ok, m, 1.0)), 0.0)
    y = np.where(ok, np.log(np.where(ok, v, 1.0)), 0.0)
    cnt = ok.sum(axis=(1, 2), keepdims=True)
    x = np.where(ok, x - x.sum(axis=(1, 2), keepdims=True) / cnt, 0.0)
    y = np.where(ok, y - y.sum(axis=(1, 2), keepdims=True) / cnt, 0.0)
    sxx = float(np.sum(x * x))
    if sxx <= 0.0:
        return 0.0, 0.0
    # a cell's mean temporal variance is uncertain by sqrt(2 / ((N - 1) pixels)) of itself, its
    # shot part by that times total / shot
    pixels = (frames.shape[2] // py) * (frames.shape[3] // px)
    rel_var = 2.0 / ((n - 1) * pixels) * np.where(ok, (v + read) / np.where(ok, v, 1.0), 0.0) ** 2
    slope = float(np.sum(x * y)) / sxx
    slope_var = float(np.sum(x * x * rel_var)) / sxx**2
    return float(np.clip(slope - 1.0, 0.0, 1.0)), 1.0 / max(slope_var, 1e-12)


def combine(records: list[dict]) -> dict:
    """One grid from the flat stacks (every ISO and level: the same pixels): the period the
    stacks of most weight found, their gains averaged per channel with weights 1 / noise^2."""
    by_period: dict = {}
    for r in records:
        by_period.setdefault(tuple(r["period"]), []).append(r)
    period, chosen = max(by_period.items(), key=lambda item: sum(float(np.sum(r.get("weight", [1.0] * 4))) for r in item[1]))
    w = np.array([r.get("weight", [1.0] * 4) for r in chosen], dtype=np.float64)[:, :, None, None]
    gain = np.sum(w * np.array([r["gain"] for r in chosen], dtype=np.float64), axis=0) / w.sum(axis=0)
    gain /= gain.mean(axis=(1, 2), keepdims=True)
    out = {"period": list(period), "gain": np.round(gain, DECIMALS).tolist()}
    shares = np.array([[r.get("conversion", 0.0), r.get("conversion_weight", 0.0)] for r in chosen], dtype=np.float64)
    if shares[:, 1].sum() > 0.0:  # the stacks' shares by their precision
        out["conversion"] = round(float(np.sum(shares[:, 0] * shares[:, 1]) / shares[:, 1].sum()), 3)
    out.update({key: chosen[0][key] for key in ("frame_h", "frame_w") if key in chosen[0]})
    return out


def empty(params) -> bool:
    """True when every gain is 1: the grid would change nothing."""
    return bool(np.all(np.asarray(params["gain"], dtype=np.float64) == 1.0))
