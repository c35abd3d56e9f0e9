"""Row (banding) noise: one Gaussian offset per sensor row, shared by the two packed
channels read out from that row (R with G1, B with G2)."""
from __future__ import annotations

import torch

from .base import BANDING, NoiseEffect, add_noise, per_sample, register


@register
class RowNoise(NoiseEffect):
    """R: ``N_r ~ N(0, sigma_r^2)`` added to every pixel of a sensor row."""

    token = "R"
    order = BANDING
    param_keys = ("row_noise.sigma_r",)

    def draw(self, ctx):
        return {"row_noise.sigma_r": ctx.scale(self.profile.row_scale, "sigma_r")}

    def forward(self, signal_dn, clean_dn, params, generator):
        b, _, h, _ = signal_dn.shape
        # (B, 2, H, 1): sensor rows 2i (R, G1) and 2i+1 (B, G2).
        rows = torch.randn((b, 2, h, 1), device=signal_dn.device, generator=generator, dtype=signal_dn.dtype)
        rows = rows * per_sample(params["row_noise.sigma_r"]).to(signal_dn.dtype)
        return add_noise(signal_dn, clean_dn, rows[:, (0, 0, 1, 1)])
