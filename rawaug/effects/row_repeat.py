"""Repeated rows (RowRepeat): sensor rows that read out as the same colour's row above them.

Physics: a rolling readout passes each row through a line buffer; when a transfer is missed
(a timing glitch, a dropped row address), the buffer still holds the previous line of that
colour and sends it again. The frame then has a row that equals, code for code, the same
colour's row two sensor lines above it, at new places in every frame. No noise process makes
two rows of many pixels equal.

Stage (first, on the coordinates): where sensor row ``Y`` of a frame is a repeat (a uniform
per frame and sensor row below ``density``), the row's whole chain runs as row ``Y - 2``'s
(its clean value, its noise, its fixed patterns), so its output is that row's; a repeated row
above it is followed back, over at most ``REPEAT_CHAIN`` rows.

Profile entry (one for the camera: its readout's)::

    RowRepeat: {density: 0.005}

Detected by ``repeated_rows``. Estimated by ``estimate`` from every stack, on raw codes: the
measured count of repeated rows over the model's (clipped frames can repeat a row by chance),
kept where a Poisson count of the model's mean (at least ``FLOOR``) exceeds it with
probability under ``P_VALUE``; ``combine`` pools the stacks' counts.
"""
from __future__ import annotations

import numpy as np
import torch
from scipy import stats

from ..engine import layout as L
from ..statistics import repeated_row_mask
from .base import PHOTON, NoiseEffect, register

STATISTICS = ("repeated_rows",)
RAW_FRAMES = True  # rows as written: repairs (defect lines) write values of their own
P_VALUE = 1e-3  # a stack's count is kept where chance gives as many with this probability
FLOOR = 0.5  # the model's mean count is taken as at least this (the syntheses rarely show one)


@register
class RowRepeat(NoiseEffect):
    token = "RowRepeat"
    order = PHOTON - 1  # on the coordinates, before every stage: the whole row is another's
    flag = L.ROW_REPEAT
    columns = ("repeat_density",)

    def draw(self, ctx):
        density = float(self.profile.effects[self.token]["density"])
        return {"repeat_density": torch.full((ctx.batch,), density, dtype=torch.float64, device=ctx.device)}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict) or set(params) != {"density"}:
            raise ValueError(f"effect {cls.token!r} parameters must be {{density: share of the sensor rows}}, got {params!r:.80}")
        d = params["density"]
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not 0.0 <= d < 1.0:
            raise ValueError(f"effect {cls.token!r}: density must be a share of the sensor rows in [0, 1), got {d!r}")


def estimate(frames, synthesized, k: float, **_) -> dict:
    """One stack's count: ``{repeated, rows, model}`` (repeated rows, rows checked, the
    syntheses' mean count); ValueError where the count is within chance."""
    if not len(synthesized):
        raise ValueError("RowRepeat is measured against syntheses of the stack")
    mask = repeated_row_mask(frames)
    repeated, rows = int(mask.sum()), int(mask.size)
    model = float(np.mean([repeated_row_mask(s).sum() for s in synthesized]))
    if stats.poisson.sf(repeated - 1, max(model, FLOOR)) >= P_VALUE:
        raise ValueError(f"{repeated} repeated rows of {rows} against the model's {model:.2f}: within chance")
    return {"repeated": repeated, "rows": rows, "model": model}


def combine(records: list[dict]) -> dict:
    """The camera's share of repeated rows: the stacks' counts over the model's, pooled. A row
    that repeats a repeat is counted once per step, so the share is the per-row rate."""
    excess = sum(r["repeated"] - r["model"] for r in records)
    rows = sum(r["rows"] for r in records)
    return {"density": float(min(max(excess / rows, 0.0), 0.5))}


def empty(params) -> bool:
    return float(params["density"]) <= 0.0
