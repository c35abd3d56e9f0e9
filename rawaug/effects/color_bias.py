"""Colour bias: the per-channel black-level error (mean of a bias frame), in DN."""
from __future__ import annotations

import torch

from .base import OFFSET, NoiseEffect, add_noise, per_sample, register


@register
class ColorBias(NoiseEffect):
    """C: adds the (R, G1, B, G2) bias recorded at the calibration frame nearest the drawn K."""

    token = "C"
    order = OFFSET
    param_keys = ("color_bias.dn",)

    def draw(self, ctx):
        fixed = ctx.fixed.get("color_bias_dn")
        if fixed is not None:
            bias = torch.as_tensor(fixed, dtype=torch.float64, device=ctx.device).reshape(-1, 4).expand(ctx.batch, 4)
        else:
            bias = ctx.nearest(self.profile.color_bias)
        return {"color_bias.dn": bias}

    def forward(self, signal_dn, clean_dn, params, generator):
        return add_noise(signal_dn, clean_dn, per_sample(params["color_bias.dn"]).to(signal_dn.dtype))
