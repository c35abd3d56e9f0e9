"""Row (banding) noise: one Gaussian offset per sensor row, shared by the two packed
channels read out from that row (R with G1, B with G2).

Stage (DN): ``s -> s + sigma_r * z[b, sensor row]``, z drawn at counter
``(b * 2 + row set) * H + y`` of the row stream.
"""
from __future__ import annotations

from ..engine import layout as L
from .base import BANDING, NoiseEffect, register


@register
class RowNoise(NoiseEffect):
    """R: ``N_r ~ N(0, sigma_r^2)`` added to every pixel of a sensor row."""

    token = "R"
    order = BANDING
    flag = L.ROW
    columns = ("sigma_r",)

    @classmethod
    def check(cls, profile, fixed):
        if profile.row_scale is None and "sigma_r" not in fixed:
            raise ValueError(f"profile {profile.camera!r} has no row-noise fit (row_noise.scale): use a model "
                             f"without R (e.g. {profile.richest_model!r}) or fix sigma_r")

    def draw(self, ctx):
        return {"sigma_r": ctx.scale(self.profile.row_scale, "sigma_r")}
