"""Read noise (thermal, source-follower, dark current lumped): Tukey lambda (G*) or Gaussian (G)."""
from __future__ import annotations

import math

import torch

from .. import cpu
from .base import READ, NoiseEffect, add_noise, as_sample, key_from, per_sample, register, writable

# Smallest tail probability drawn: float32 uniforms come in steps of 2**-24, so u == 0 is
# replaced by 2**-26; this keeps every sample finite for lambda < 0 at a bias below 1e-7.
_TAIL_FLOOR = 2.0**-26
_LAMBDA_ZERO = 1e-6


def tukey_lambda_upper_quantile(tail: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """Quantile of the standard Tukey lambda at ``1 - tail``, for ``tail`` in (0, 1/2]: ``>= 0``.
    Computed from the tail with ``log1p``/``expm1``, so it keeps full precision as ``tail -> 0``;
    the l -> 0 limit is the logistic ``log((1 - tail) / tail)``. ``lam`` broadcasts."""
    log_tail = torch.log(tail)
    log_body = torch.log1p(-tail)
    small = lam.abs() < _LAMBDA_ZERO
    safe = torch.where(small, torch.ones_like(lam), lam)
    q = (torch.expm1(safe * log_body) - torch.expm1(safe * log_tail)) / safe
    return torch.where(small, log_body - log_tail, q)


def tukey_lambda_icdf(u: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """Tukey lambda quantile ``(u^l - (1-u)^l) / l`` (unit scale), with the l -> 0 logistic limit
    ``log(u / (1-u))``. Evaluated on the smaller tail, so both tails keep full float32 precision
    and u = 0 or 1 give finite values. ``lam`` broadcasts against ``u``."""
    upper = u >= 0.5
    tail = torch.clamp(torch.where(upper, 1.0 - u, u), min=_TAIL_FLOOR)  # in (0, 0.5]
    q = tukey_lambda_upper_quantile(tail, lam)
    return torch.where(upper, q, -q)


def tukey_lambda_variance(lam: float) -> float:
    """Variance of the standard Tukey lambda distribution (infinite for lam <= -0.5)."""
    if lam <= -0.5:
        return math.inf
    if abs(lam) < _LAMBDA_ZERO:
        return math.pi**2 / 3.0
    return (2.0 / lam**2) * (1.0 / (1.0 + 2.0 * lam) - math.gamma(lam + 1.0) ** 2 / math.gamma(2.0 * lam + 2.0))


@register
class TukeyLambdaReadNoise(NoiseEffect):
    """G*: ``N_read ~ TL(lambda; 0, sigma_TL)``, drawn by the inverse CDF on the device."""

    token = "G*"
    order = READ
    param_keys = ("read_noise.sigma_tl", "read_noise.lambda")

    def draw(self, ctx):
        sigma = ctx.scale(self.profile.tukey_scale, "sigma_tl")
        lam = ctx.fixed.get("lambda")
        lam = as_sample(lam, ctx.batch, ctx.device) if lam is not None else ctx.nearest(self.profile.tukey_shape)
        return {"read_noise.sigma_tl": sigma, "read_noise.lambda": lam}

    def forward(self, signal_dn, clean_dn, params, generator):
        if cpu.handles(signal_dn):
            from ..cpu.quantile_table import add_scaled, tukey_lambda_table

            tables = [tukey_lambda_table(float(lam)) for lam in params["read_noise.lambda"].tolist()]
            return add_scaled(signal_dn, writable(signal_dn, clean_dn), params["read_noise.sigma_tl"], tables, key_from(generator))
        u = torch.rand(signal_dn.shape, device=signal_dn.device, generator=generator, dtype=torch.float32)
        noise = tukey_lambda_icdf(u, per_sample(params["read_noise.lambda"]))
        noise = noise.to(signal_dn.dtype) * per_sample(params["read_noise.sigma_tl"]).to(signal_dn.dtype)
        return add_noise(signal_dn, clean_dn, noise)


@register
class GaussianReadNoise(NoiseEffect):
    """G: ``N_read ~ N(0, sigma_G^2)``, the homoscedastic baseline."""

    token = "G"
    order = READ
    param_keys = ("read_noise.sigma_g",)

    def draw(self, ctx):
        return {"read_noise.sigma_g": ctx.scale(self.profile.gaussian_scale, "sigma_g")}

    def forward(self, signal_dn, clean_dn, params, generator):
        if cpu.handles(signal_dn):
            from ..cpu.quantile_table import add_scaled, normal_table

            sigma = params["read_noise.sigma_g"]
            return add_scaled(signal_dn, writable(signal_dn, clean_dn), sigma, [normal_table()] * sigma.shape[0], key_from(generator))
        z = torch.randn(signal_dn.shape, device=signal_dn.device, generator=generator, dtype=signal_dn.dtype)
        return add_noise(signal_dn, clean_dn, z * per_sample(params["read_noise.sigma_g"]).to(signal_dn.dtype))
