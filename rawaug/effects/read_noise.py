"""Read noise (thermal, source-follower, dark current lumped): Tukey lambda (G*) or Gaussian (G).

Stage (DN): ``s -> s + sigma_TL * TL(lambda)`` (G*) or ``s -> s + sigma_G * z`` (G), one
draw per pixel, by the inverse CDF (``rawaug.distributions``).
"""
from __future__ import annotations

from ..distributions import tukey_lambda_icdf, tukey_lambda_variance  # noqa: F401
from ..engine import layout as L
from .base import READ, NoiseEffect, as_sample, register


@register
class TukeyLambdaReadNoise(NoiseEffect):
    """G*: ``N_read ~ TL(lambda; 0, sigma_TL)``."""

    token = "G*"
    order = READ
    flag = L.READ_TUKEY
    columns = ("sigma_tl", "lambda")

    @classmethod
    def check(cls, profile, fixed):
        if profile.tukey_scale is None and not {"sigma_tl", "lambda"} <= set(fixed):
            raise ValueError(f"profile {profile.camera!r} has no Tukey-lambda read-noise fit (read_noise.tukey_scale): "
                             f"use a model with G instead of G* (e.g. {profile.richest_model!r}) or fix sigma_tl and lambda")

    def draw(self, ctx):
        sigma = ctx.scale(self.profile.tukey_scale, "sigma_tl")
        lam = ctx.fixed.get("lambda")
        lam = as_sample(lam, ctx.batch, ctx.device) if lam is not None else ctx.nearest(self.profile.tukey_shape, "lambda")
        return {"sigma_tl": sigma, "lambda": lam}


@register
class GaussianReadNoise(NoiseEffect):
    """G: ``N_read ~ N(0, sigma_G^2)``, the homoscedastic baseline."""

    token = "G"
    order = READ
    flag = L.READ_GAUSS
    columns = ("sigma_g",)

    def draw(self, ctx):
        return {"sigma_g": ctx.scale(self.profile.gaussian_scale, "sigma_g")}
