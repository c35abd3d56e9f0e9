"""Photon shot noise: electrons collected ~ Poisson(I). Tokens P* (Poisson) and P (Gaussian approx)."""
from __future__ import annotations

import torch

from .. import cpu
from .base import SHOT, NoiseEffect, add_noise, key_from, per_sample, register, writable


@register
class PoissonShotNoise(NoiseEffect):
    """P*: ``D = K * Poisson(D_clean / K)``, K in DN per electron. Negative clean values count as 0 electrons."""

    token = "P*"
    order = SHOT

    def forward(self, signal_dn, clean_dn, params, generator):
        if cpu.handles(signal_dn):
            from ..cpu.poisson import poisson_dn

            return poisson_dn(signal_dn, writable(signal_dn, clean_dn), params["k"], key_from(generator))
        k = per_sample(params["k"])
        electrons = torch.clamp(signal_dn / k, min=0.0)
        return torch.poisson(electrons, generator=generator).mul_(k)


@register
class GaussianShotNoise(NoiseEffect):
    """P: the heteroscedastic Gaussian approximation, ``D + sqrt(K * D) * N(0, 1)``."""

    token = "P"
    order = SHOT

    def forward(self, signal_dn, clean_dn, params, generator):
        if cpu.handles(signal_dn):
            from ..cpu.quantile_table import add_signal_scaled

            return add_signal_scaled(signal_dn, writable(signal_dn, clean_dn), params["k"], key_from(generator))
        k = per_sample(params["k"])
        z = torch.randn(signal_dn.shape, device=signal_dn.device, generator=generator, dtype=signal_dn.dtype)
        return add_noise(signal_dn, clean_dn, torch.sqrt(k * torch.clamp(signal_dn, min=0.0)) * z)
