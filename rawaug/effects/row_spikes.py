"""Row glitches (RowSpikes): a few sensor rows of a frame, new ones each frame, offset far up or down.

Physics: an error in the row decoder or the column readout's reference while one row is
converted (an electrostatic discharge, a supply glitch, a missed reset of the column
amplifiers' sample) shifts the whole row by far more than the row noise, in that frame only.
Unlike ``RowTail`` (heavy-tailed row noise: every row, more often large), ``RowRTS`` (rows
of their own that jump between two levels), ``Lines`` (rows offset in every frame) or
``RowBurst`` (rows read with extra white noise, their mean unmoved), the row's pixels move
together, once.

Stage (DN, with the row noise): in frame ``b``, sensor row ``Y`` is offset where a U(0, 1)
of ``(b, Y)`` falls below ``density``, by ``median_dn(K) * exp(log_std * z)``, ``z`` a
standard normal of ``(b, Y)``, negative where a second U(0, 1) falls below ``negative``.

Profile entry (per-K records)::

    RowSpikes: {density: 0.002, log_std: 0.4, negative: 0.5, k: [K, ...], median_dn: [...]}

Detected on bias and dark stacks of >= 3 frames by ``row_spike_fraction`` (rows offset
``ROW_SPIKE_Z`` robust sigmas from the same row in the other frames, in one frame only; on
the frames as measured, since the line repair takes such a row out) and ``defect_lines``.
Estimated by ``estimate``: the events beyond the model's count (kept where the count has a
chance under 1e-3 under the model's: ``row_burst.beyond_model``), their sizes by a log-normal truncated at the
detection threshold (``impulses.truncated_log_normal``), the density as that excess over the
share the threshold lets through; ``combine`` pools the stacks (an event in time: one density
and one spread for the camera, the size per gain).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import ROW_SPIKE_Z, row_spike_events
from .base import READ, NoiseEffect, register
from .impulses import truncated_log_normal
from .row_burst import beyond_model
from .k_records import _number, validate_records, value_at_k

STATISTICS = ("row_spike_fraction", "defect_lines")  # a row far off in one frame raises its stack mean's line
RAW_FRAMES = True  # the events are what the line repair takes out
MAX_DENSITY = 0.1


@register
class RowSpikes(NoiseEffect):
    token = "RowSpikes"
    order = READ + 2
    flag = L.ROW_SPIKES
    columns = ("rspike_density", "rspike_median", "rspike_log_std", "rspike_negative")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        full = lambda key: ctx.k.new_full(ctx.k.shape, float(p.get(key, 0.0)))  # noqa: E731
        return {"rspike_density": full("density"), "rspike_median": value_at_k(p, "median_dn", ctx.k),
                "rspike_log_std": full("log_std"), "rspike_negative": full("negative")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("median_dn",), nonnegative=("median_dn",))
        density = _number(params.get("density"), f"{cls.token}.density")
        if not 0.0 <= density <= MAX_DENSITY:
            raise ValueError(f"effect {cls.token!r}: density (share of a frame's sensor rows) must be in [0, {MAX_DENSITY}], "
                             f"got {density}")
        if _number(params.get("log_std"), f"{cls.token}.log_std") < 0:
            raise ValueError(f"effect {cls.token!r}: log_std must be >= 0, got {params.get('log_std')}")
        if not 0.0 <= _number(params.get("negative", 0.0), f"{cls.token}.negative") <= 1.0:
            raise ValueError(f"effect {cls.token!r}: negative (the share of rows offset down) must be in [0, 1], "
                             f"got {params.get('negative')}")


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """RowSpikes record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w) in DN, against
    stacks of the same shape synthesized by the model."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3:
        raise ValueError("RowSpikes are measured on bias or dark stacks of >= 3 frames")
    d, hit, scale = row_spike_events(frames)
    base = float(np.mean([row_spike_events(s)[1].sum() for s in synthesized])) if synthesized else 0.0
    count = int(hit.sum())
    record = {"density": 0.0, "log_std": 0.0, "negative": 0.0, "k": [float(k)], "median_dn": [0.0], "rows": [int(hit.size)],
              "events": [0.0]}
    if not beyond_model(count, base):
        return record
    size = np.abs(d[hit])
    mu, s = truncated_log_normal(np.log(size), np.full(size.size, math.log(ROW_SPIKE_Z * scale)))
    seen = float(stats.norm.sf((math.log(ROW_SPIKE_Z * scale) - mu) / max(s, 1e-6)))
    density = (count - base) / hit.size / max(seen, 0.1)
    return record | {"density": min(density, MAX_DENSITY), "log_std": s, "negative": float(np.mean(d[hit] < 0)),
                     "median_dn": [float(math.exp(mu))], "events": [float(count)]}


def combine(records: list[dict]) -> dict:
    """The camera's row glitches: the density of the stacks that found any, weighed by their
    rows (where the row noise is larger it hides the small ones, and a stack that sees none
    does not vote); the log spread and the share offset down weighed by the events; the size
    per gain, the log-mean over its stacks that found any."""
    found = [r for r in records if r["density"] > 0]
    if not found:
        return {"density": 0.0, "log_std": 0.0, "negative": 0.0, "k": [float(records[0]["k"][0])], "median_dn": [0.0]}
    events = [r["events"][0] for r in found]
    by_k: dict = {}
    for r in found:
        by_k.setdefault(float(r["k"][0]), []).append(math.log(r["median_dn"][0]))
    ks = sorted(by_k)
    return {"density": float(np.average([r["density"] for r in found], weights=[r["rows"][0] for r in found])),
            "log_std": float(np.average([r["log_std"] for r in found], weights=events)),
            "negative": float(np.average([r["negative"] for r in found], weights=events)),
            "k": ks, "median_dn": [float(math.exp(np.mean(by_k[k]))) for k in ks]}


def empty(params) -> bool:
    """True when no row glitches (density 0 or no size)."""
    return float(params["density"]) == 0.0 or not any(float(m) > 0 for m in params["median_dn"])
