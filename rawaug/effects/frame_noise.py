"""Frame-to-frame read-noise level (FrameNoise): the read noise of a whole frame is scaled by a
factor of its own, new in every frame.

Physics: the analog chain's noise depends on its supply and its temperature, which drift
between the frames of a burst (a switching regulator's ripple, a warming amplifier); so does
the level of the read noise, the same for every pixel of one frame. The ELD model draws the
read noise's scale per training sample around its line on K (``residual_std``), but a
calibrated camera's frames at one setting all have the same; this effect gives them the
measured frame-to-frame spread.

Stage: the base read noise (G*, G or the measured table) of every pixel of a frame times
``exp(log_std * z - log_std^2)``, ``z`` a standard normal per frame (the mean variance stays
the calibrated one).

Profile entry (per-K records: an additive supply noise is a larger share of the read noise
at low gain)::  ``FrameNoise: {k: [K, ...], log_std: [...]}``

Detected on bias and dark stacks of >= 3 frames by ``frame_noise_spread`` (the spread over
frames of the log of each frame's robust white-noise variance). Estimated by ``estimate``:
the spread in excess of the model's syntheses', halved (variance, not scale), the read noise
taken as the whole of a frame's white noise; ``combine`` pools the stacks (a spread of 4 to 6
frames is itself uncertain by a third).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..engine import layout as L
from ..statistics import frame_noise_spread
from .base import READ, NoiseEffect, register
from .k_records import all_zero, combine_sigma, validate_records, value_at_k

STATISTICS = ("frame_noise_spread",)
MAX_LOG_STD = 1.0


@register
class FrameNoise(NoiseEffect):
    token = "FrameNoise"
    order = READ + 1
    flag = L.FRAME_NOISE
    columns = ("read_gain",)

    def draw(self, ctx):
        s = value_at_k(self.profile.effects[self.token], "log_std", ctx.k)
        return {"read_gain": torch.exp(s * ctx.normal("frame_noise").to(torch.float64) - s * s)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("log_std",), nonnegative=("log_std",))
        for value in params["log_std"]:
            if value > MAX_LOG_STD:
                raise ValueError(f"effect {cls.token!r}: log_std (spread of the log read-noise scale over frames) "
                                 f"must be in [0, {MAX_LOG_STD:g}], got {value}")


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """FrameNoise from a bias or dark stack (N >= 3, 4, h, w) in DN against stacks of the same
    shape synthesized by the model."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3 or not synthesized:
        raise ValueError("FrameNoise is measured on bias and dark stacks of >= 3 frames")
    model = float(np.mean([frame_noise_spread(s) ** 2 for s in synthesized]))
    excess = frame_noise_spread(frames) ** 2 - model
    return {"k": [float(k)], "log_std": [min(0.5 * math.sqrt(max(excess, 0.0)), MAX_LOG_STD)]}


def combine(records: list[dict]) -> dict:
    """One spread per gain: its stacks' spreads averaged in variance."""
    return combine_sigma(records, "log_std")


def empty(params) -> bool:
    """True when every spread is 0: it would add nothing."""
    return all_zero(params, ("log_std",))
