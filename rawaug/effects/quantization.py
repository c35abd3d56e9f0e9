"""Quantization noise of the ADC: ``N_q ~ U(-q/2, q/2)``, q in DN (the profile's step)."""
from __future__ import annotations

import torch

from .. import cpu
from .base import ADC, NoiseEffect, add_noise, as_sample, key_from, per_sample, register, writable


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
        if cpu.handles(signal_dn):
            from ..cpu.uniform import add_uniform

            return add_uniform(signal_dn, writable(signal_dn, clean_dn), params["quantization.step_dn"], key_from(generator))
        u = torch.rand(signal_dn.shape, device=signal_dn.device, generator=generator, dtype=signal_dn.dtype)
        noise = (u - 0.5) * per_sample(params["quantization.step_dn"]).to(signal_dn.dtype)
        return add_noise(signal_dn, clean_dn, noise)
