"""Exposure row noise (DarkRowNoise): row noise that grows with the exposure time, new in every
frame.

Physics: the row noise of a CMOS sensor comes from the references its column ADCs share; where a
long exposure warms them, or their low-frequency noise is sampled over a longer interval, the
rows of a dark frame move more than those of a bias frame. The ELD row noise ``R`` is measured on
bias frames and is the same at every exposure; ``DarkNoise`` is the same growth pixel by pixel.

Stage (DN): ``sqrt(rate(K) * exposure_s) * z`` on every pixel of a sensor row, ``z`` standard
normal per sensor row and frame; the exposure is a synthesis setting
(``RawNoiseAugment(fixed={"exposure_s": t})``, default 0: none).

Profile entry (per-K records, DN^2 per second)::  ``DarkRowNoise: {k: [K, ...], rate_dn2_per_s: [...]}``

Detected on dark stacks by ``row_excess``. Estimated by ``estimate``: the variance of the sensor
rows' temporal parts (``temporal_row_variance``) less the model's, over the exposure, kept where
the ratio of the two passes an F test at ``P_VALUE``; ``combine`` averages the stacks at one gain.
"""
from __future__ import annotations

import numpy as np
import torch
from scipy import stats

from ..engine import layout as L
from ..statistics import temporal_row_variance
from .base import BANDING, NoiseEffect, register
from .k_records import all_zero, combine_mean, validate_records, value_at_k

STATISTICS = ("row_excess",)
P_VALUE = 1e-3  # the measured rows' variance over the model's: an F ratio beyond this chance


@register
class DarkRowNoise(NoiseEffect):
    token = "DarkRowNoise"
    order = BANDING
    flag = L.DARK_ROW_NOISE
    columns = ("dark_row_sigma",)
    exposure = True

    def draw(self, ctx):
        rate = value_at_k(self.profile.effects[self.token], "rate_dn2_per_s", ctx.k)
        exposure = torch.as_tensor(ctx.fixed.get("exposure_s", 0.0), dtype=torch.float64, device=ctx.device).expand(ctx.batch)
        return {"dark_row_sigma": torch.sqrt(rate * exposure)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("rate_dn2_per_s",), nonnegative=("rate_dn2_per_s",))


def estimate(frames, synthesized, k: float, kind=None, exposure_s=None, **_) -> dict:
    """DarkRowNoise record at gain ``k`` from a dark stack (N >= 3, 4, h, w; DN) of ``exposure_s``
    seconds against the model's syntheses of it."""
    frames = np.asarray(frames, dtype=np.float64)
    n, _, h, _ = frames.shape
    if kind != "dark" or not exposure_s or n < 3 or not synthesized:
        raise ValueError("DarkRowNoise is measured on dark stacks of >= 3 frames with their exposure_s, against their syntheses")
    measured = temporal_row_variance(frames)
    model = float(np.mean([temporal_row_variance(np.asarray(s, dtype=np.float64)) for s in synthesized]))
    dof = (n - 1) * (2 * h - 1)
    if model > 0 and stats.f.sf(measured / model, dof, dof * len(synthesized)) > P_VALUE:
        return {"k": [float(k)], "rate_dn2_per_s": [0.0]}
    excess = max(measured - model, 0.0) / ((1.0 - 1.0 / n) * (1.0 - 1.0 / (2 * h)))  # the means taken out
    return {"k": [float(k)], "rate_dn2_per_s": [excess / float(exposure_s)]}


def combine(records: list[dict]) -> dict:
    """One rate per gain: its stacks' rates averaged."""
    return combine_mean(records, "rate_dn2_per_s")


def empty(params) -> bool:
    """True when every rate is 0: it would add nothing."""
    return all_zero(params, ("rate_dn2_per_s",))
