"""Quantization noise of the ADC: ``N_q ~ U(-q/2, q/2)``, q in DN (the profile's step)."""
from __future__ import annotations

import torch

from .base import ADC, NoiseEffect, as_sample, per_sample, register


@register
class QuantizationNoise(NoiseEffect):
    """U: uniform noise of one quantization step q (DN)."""

    token = "U"
    order = ADC
    param_keys = ("quantization.step_dn",)

    def draw(self, ctx):
        step = ctx.fixed.get("step_dn", self.profile.quantization_step_dn)
        return {"quantization.step_dn": as_sample(step, ctx.batch, ctx.device)}

    def forward(self, signal_dn, clean_dn, params, generator):
        u = torch.rand(signal_dn.shape, device=signal_dn.device, generator=generator, dtype=signal_dn.dtype)
        return signal_dn + (u - 0.5) * per_sample(params["quantization.step_dn"]).to(signal_dn.dtype)
