"""Colour bias: the per-channel black-level error (mean of a bias frame), in DN.

Stage (DN): ``s -> s + bias[channel]``.
"""
from __future__ import annotations

import torch

from ..engine import layout as L
from .base import OFFSET, NoiseEffect, register


@register
class ColorBias(NoiseEffect):
    """C: adds the (R, G1, B, G2) bias recorded at the calibration frame nearest the drawn K."""

    token = "C"
    order = OFFSET
    flag = L.BIAS
    columns = ("bias_r", "bias_g1", "bias_b", "bias_g2")

    def draw(self, ctx):
        fixed = ctx.fixed.get("color_bias_dn")
        if fixed is not None:
            bias = torch.as_tensor(fixed, dtype=torch.float64, device=ctx.device).reshape(-1, 4).expand(ctx.batch, 4)
        else:
            bias = ctx.nearest(self.profile.color_bias, "color_bias")
        return dict(zip(self.columns, bias.unbind(dim=1)))
