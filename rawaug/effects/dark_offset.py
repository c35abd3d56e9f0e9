"""Exposure-dependent black level (DarkOffset): the black level of a frame moves with its
exposure time by more than, or against, what its dark electrons explain, without shot noise.

Physics: the black clamp (optical-black reference, ADC offset) sags or drifts while the sensor
integrates: supply droop, amplifier warm-up, a clamp capacitor's leakage. EMVA 1288 measures
dark current twice, from the dark signal's mean and from its temporal variance; electrons give
both in the ratio K, so a mean that moves without the variance, or downwards, is an offset and
not dark current (``Dark``).

Stage (DN, with the black level): ``s -> s + dn_per_s(K) * t``, ``t`` the synthesis setting
``fixed={"exposure_s": t}`` (default 0: none). Linear in ``t``: frames at one dark exposure
cannot show more, several are fitted by one slope through the bias frames' level.

Profile entry (per-K records, nearest record in log K; signed)::

    DarkOffset: {k: [K, ...], dn_per_s: [...]}

Detected on dark stacks by ``mean_dn`` (either sign: ``SIGNED``). Estimated by ``estimate``:
the mean excess over the model less the mean of the electrons its temporal-variance excess
shows (variance / K), per second.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from .base import OFFSET, NoiseEffect, register
from .k_records import all_zero, validate_records, value_at_k

STATISTICS = ("mean_dn",)
SIGNED = True  # a black level can move down: suggested by a mean below the model's too


@register
class DarkOffset(NoiseEffect):
    token = "DarkOffset"
    order = OFFSET + 1
    flag = L.DARK_OFFSET
    columns = ("dark_offset",)
    exposure = True

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        exposure = torch.as_tensor(ctx.fixed.get("exposure_s", 0.0), dtype=torch.float64, device=ctx.device).expand(ctx.batch)
        return {"dark_offset": value_at_k(p, "dn_per_s", ctx.k) * exposure}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("dn_per_s",))


def offset_excess(frames, synthesized, k: float) -> float:
    """DN of a stack's mean excess over the model's syntheses that its temporal-variance excess
    does not explain as electrons (excess variance / K, DN; a variance excess within 3 sd of
    the syntheses' spread explains none)."""
    frames = np.asarray(frames, dtype=np.float64)
    base = [np.asarray(s, dtype=np.float64) for s in synthesized]
    mean = float(frames.mean() - np.mean([s.mean() for s in base]))
    model_var = [s.var(axis=0, ddof=1).mean() for s in base]
    var = float(frames.var(axis=0, ddof=1).mean() - np.mean(model_var))
    if len(base) >= 2 and var < 3.0 * float(np.std(model_var, ddof=1)):
        var = 0.0  # within the syntheses' spread: no electrons shown, only noise
    return mean - max(var, 0.0) / float(k)


def estimate(frames, synthesized, k: float, exposure_s=None, kind=None, **_) -> dict:
    """DarkOffset record at gain ``k`` from a dark stack (N >= 2, 4, h, w) in DN of
    ``exposure_s`` seconds, against stacks of the same shape synthesized by the model."""
    if kind != "dark" or not exposure_s or np.shape(frames)[0] < 2 or not synthesized:
        raise ValueError("DarkOffset is measured on dark stacks of >= 2 frames with their exposure_s")
    return {"k": [float(k)], "dn_per_s": [offset_excess(frames, synthesized, k) / float(exposure_s)],
            "exposure_s": [float(exposure_s)]}


def combine(records: list[dict]) -> dict:
    """One slope per gain through the bias level: least squares over the exposures at that K
    (sum o t / sum t^2, o the offset at exposure t)."""
    by_k: dict = {}
    for r in records:
        t = r["exposure_s"][0]
        by_k.setdefault(r["k"][0], []).append((r["dn_per_s"][0] * t, t))
    ks = sorted(by_k)
    slope = [sum(o * t for o, t in by_k[k]) / sum(t * t for _, t in by_k[k]) for k in ks]
    return {"k": ks, "dn_per_s": [float(v) for v in slope]}


def empty(params) -> bool:
    """True when every slope is 0: it would add nothing."""
    return all_zero(params, ("dn_per_s",))
