"""Quantization noise of the ADC: ``N_q ~ U(-q/2, q/2)``, q in DN (the profile's step).

Stage (DN): ``s -> s + (u - 1/2) * q``.
"""
from __future__ import annotations

from ..engine import layout as L
from .base import ADC, NoiseEffect, as_sample, register


@register
class QuantizationNoise(NoiseEffect):
    """U: uniform noise of one quantization step q (DN)."""

    token = "U"
    order = ADC
    flag = L.QUANT
    columns = ("step_dn",)

    def draw(self, ctx):
        step = ctx.fixed.get("step_dn", self.profile.quantization_step_dn)
        return {"step_dn": as_sample(step, ctx.batch, ctx.device)}
