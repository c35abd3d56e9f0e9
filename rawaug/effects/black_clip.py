"""Black-level clipping (Clip): the camera stores no code below a floor, so the negative
half of the read noise of dark pixels piles up there.

Physics/firmware: many raw pipelines clip at code 0 (DN = -black level) or even at the
black level itself; dark pixels then lose their negative noise and their mean is biased
upwards.

Synthesis: ``max(signal, floor_dn)`` in DN at the sensor (after quantization and offsets).

Profile entry::  ``Clip: {floor_dn: -512.0}``  (DN relative to black; a raw code of
black + floor_dn).

Detected by ``clip_low`` (fraction of pixels at the lowest code). Estimated by
``estimate``: a stack's lowest measured code; ``combine``: the lowest over every stack (a
bright flat never reaches the floor, so no one stack's code stands for the camera's).
"""
from __future__ import annotations

import numpy as np
from ..engine import layout as L
from .base import CLIP, NoiseEffect, register
from .k_records import _number

STATISTICS = ("clip_low",)


@register
class BlackClip(NoiseEffect):
    token = "Clip"
    order = CLIP
    flag = L.CLIP
    columns = ("clip_floor",)

    def draw(self, ctx):
        return {"clip_floor": ctx.k.new_full((ctx.k.shape[0],), float(self.profile.effects[self.token]["floor_dn"]))}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict) or "floor_dn" not in params:
            raise ValueError(f"effect 'Clip' needs {{floor_dn: DN}} (lowest stored value, relative to black), got {params!r}")
        _number(params["floor_dn"], "Clip.floor_dn")


def estimate(frames, synthesized, k: float, **_) -> dict:
    """Clip floor (DN) from measured frames: their lowest code."""
    return {"floor_dn": float(np.rint(np.asarray(frames)).min())}


def combine(records: list[dict]) -> dict:
    """One floor (DN) from the stacks' records: the lowest of their lowest codes."""
    if not records:
        raise ValueError("Clip.combine needs at least one stack's record")
    return {"floor_dn": min(float(r["floor_dn"]) for r in records)}
