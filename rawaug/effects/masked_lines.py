"""Masked lines (Masked): sensor rows and columns at the frame's edges that get no light.

Physics: a sensor has optically black lines at its edges, pixels under a metal shield whose
dark signal the camera reads to clamp the black level; many raws keep some of them, or the
edge of the frame is shaded by the sensor's cover glass frame. In bias and dark frames they
look like any other line; in a flat they stay at the black level while the rest of the frame
carries the light and its shot noise. No other effect is a line with no light at all:
``LineGain``'s dim lines are sparse and seeded anywhere, ``RowGain`` is random per row, and
a light's shape (``illumination``) is smooth.

Stage (before shot noise, with ``PRNU``): the photo signal of the sensor rows ``Y < top`` and
``Y >= 2H - bottom`` and of the sensor columns ``X < left`` and ``X >= 2W - right`` is 0; the
dark signal and all noise stay. Only on an input of the measured frame's size (its edges are
the sensor's); a crop of any other size has none.

Profile entry (sensor lines; the measured frame's size in packed pixels)::

    Masked: {top: 8, bottom: 0, left: 0, right: 0, frame_h: H, frame_w: W}

Detected on flat stacks by ``masked_lines`` (the share of edge lines below ``MASK_LEVEL`` of
the median line's level). Estimated by ``estimate``: the runs of such lines from each edge of
a flat stack's mean (``statistics.masked_edges``); ``combine`` takes each edge's median over
the flats.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from ..statistics import masked_edges
from .base import PHOTON, NoiseEffect, register

STATISTICS = ("masked_lines",)
EDGES = ("top", "bottom", "left", "right")


@register
class MaskedLines(NoiseEffect):
    token = "Masked"
    order = PHOTON + 2  # the photo signal, before shot noise
    flag = L.MASKED
    columns = ("mask_top", "mask_bottom", "mask_left", "mask_right")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        same = ctx.shape is not None and tuple(ctx.shape) == (p["frame_h"], p["frame_w"])
        return {f"mask_{edge}": torch.full_like(ctx.k, float(p[edge]) if same else 0.0) for edge in EDGES}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r:.80}")
        known = set(EDGES) | {"frame_h", "frame_w"}
        if set(params) != known:
            raise ValueError(f"effect {cls.token!r} needs exactly the keys {sorted(known)}, got {sorted(params)}")
        for key in known:
            v = params[key]
            if not isinstance(v, int) or isinstance(v, bool) or v < (1 if key.startswith("frame") else 0):
                raise ValueError(f"effect {cls.token!r}: {key} must be a whole number of "
                                 f"{'packed pixels >= 1' if key.startswith('frame') else 'sensor lines >= 0'}, got {v!r}")
        if params["top"] + params["bottom"] > 2 * params["frame_h"] or params["left"] + params["right"] > 2 * params["frame_w"]:
            raise ValueError(f"effect {cls.token!r}: the masked lines ({params['top']} + {params['bottom']} rows, "
                             f"{params['left']} + {params['right']} columns) exceed the frame's sensor lines "
                             f"({2 * params['frame_h']} x {2 * params['frame_w']})")


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """Masked lines of a flat stack (N, 4, h, w; DN): the runs of lines without light from each
    edge of its mean."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "flat" or frames.ndim != 4:
        raise ValueError(f"Masked is measured on flat stacks (N, 4, h, w), got a {kind!r} stack of shape {frames.shape}")
    found = masked_edges(frames.mean(axis=0))
    return {**dict(zip(EDGES, (int(v) for v in found))), "frame_h": int(frames.shape[2]), "frame_w": int(frames.shape[3])}


def combine(records: list[dict]) -> dict:
    """Each edge's median over the flat stacks (every flat sees the same shield)."""
    out = {edge: int(np.median([r[edge] for r in records])) for edge in EDGES}
    return {**out, "frame_h": records[0]["frame_h"], "frame_w": records[0]["frame_w"]}


def empty(params) -> bool:
    """True when no edge has a masked line."""
    return not any(params[edge] for edge in EDGES)
