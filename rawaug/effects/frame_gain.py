"""Frame-to-frame gain (FrameGain): the photo signal of a whole frame is scaled by a factor of
its own, new in every frame.

Physics: the analog gain (a programmable amplifier's setting, its reference voltage) jitters
between the frames of a burst by a fraction of a per cent, so a flat's mean moves in
proportion to its level, bias frames not at all. A light that flickers between frames does
the same to flats: the frames cannot tell the two apart, and the model reproduces either.
``BLE`` is an offset (the same DN at every level); ``PRNU`` and ``ColGain`` are fixed patterns.

Stage: ``s -> s (1 + sigma z)`` after shot noise (the photo signal and its shot noise), ``z``
a standard normal per frame.

Profile entry::  ``FrameGain: {sigma: 0.003}``

Detected on flat stacks of >= 2 frames by ``flat_gain_spread`` (the spread over frames of the
frame means over the level; resolved to the light's stability, 0.1 %), judged pooled over
every flat stack of the camera (``Statistic.pooled``: a pair holds one degree of freedom, so
0.3 % shows in 20 pairs and not in one). Estimated by ``estimate``: its square in excess of
the model's syntheses'; ``combine`` pools the flat stacks the same way.
"""
from __future__ import annotations

import math

import numpy as np

from ..engine import layout as L
from ..statistics import flat_gain_spread
from .base import SHOT, NoiseEffect, register
from .k_records import _number

STATISTICS = ("flat_gain_spread",)
MAX_SIGMA = 0.1


@register
class FrameGain(NoiseEffect):
    token = "FrameGain"
    order = SHOT + 3
    flag = L.FRAME_GAIN
    columns = ("frame_gain",)

    def draw(self, ctx):
        sigma = float(self.profile.effects[self.token]["sigma"])
        return {"frame_gain": 1.0 + sigma * ctx.normal("frame_gain").to(ctx.k.dtype)}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r}")
        value = _number(params.get("sigma"), f"{cls.token}.sigma")
        if not 0.0 <= value <= MAX_SIGMA:
            raise ValueError(f"effect {cls.token!r}: sigma (fraction of the signal, per frame) must be in [0, {MAX_SIGMA:g}], got {value}")


def estimate(frames, synthesized, k: float, kind=None, level_dn=None, **_) -> dict:
    """One record from a flat stack (N >= 2, 4, h, w) in DN at ``level_dn``, against stacks of
    the same shape synthesized by the model: the excess variance of its frame means over the
    level (kept for ``combine``) and its square root."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "flat" or frames.shape[0] < 2 or not synthesized:
        raise ValueError("FrameGain is measured on flat stacks of >= 2 frames")
    excess = flat_gain_spread(frames, level_dn) ** 2 - float(np.mean([flat_gain_spread(s, level_dn) ** 2 for s in synthesized]))
    return {"sigma": min(math.sqrt(max(excess, 0.0)), MAX_SIGMA), "_excess": excess}


def combine(records: list[dict]) -> dict:
    """One sigma for the camera: the flat stacks' excess variances averaged (negative ones
    too: each is unbiased), its square root."""
    return {"sigma": min(math.sqrt(max(float(np.mean([r["_excess"] for r in records])), 0.0)), MAX_SIGMA)}


def empty(params) -> bool:
    """True when sigma is 0: it would add nothing."""
    return float(params["sigma"]) == 0.0
