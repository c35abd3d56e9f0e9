"""Quantization noise of the ADC: ``N_q ~ U(-q/2, q/2)``, q in DN (the profile's step).

Stage (DN): ``s -> s + (u - 1/2) * q``. A profile with an explicit converter (``DNL``,
``CodeMap``) writes whole codes itself: its rounding is the quantization, and the dither
that stands for it is left out (q = 0), so that the codes are not quantized twice.
"""
from __future__ import annotations

from ..engine import layout as L
from .base import ADC, NoiseEffect, as_sample, register


EXPLICIT_ADC = ("DNL", "CodeMap")  # effects that write whole codes


@register
class QuantizationNoise(NoiseEffect):
    """U: uniform noise of one quantization step q (DN)."""

    token = "U"
    order = ADC
    flag = L.QUANT
    columns = ("step_dn",)

    def draw(self, ctx):
        if any(token in self.profile.effects for token in EXPLICIT_ADC):
            return {"step_dn": as_sample(0.0, ctx.batch, ctx.device)}
        step = ctx.fixed.get("step_dn", self.profile.quantization_step_dn)
        return {"step_dn": as_sample(step, ctx.batch, ctx.device)}
