"""Photon shot noise: electrons collected ~ Poisson(I). Tokens P* (Poisson) and P (Gaussian approx)."""
from __future__ import annotations

import torch

from .base import SHOT, NoiseEffect, per_sample, register


@register
class PoissonShotNoise(NoiseEffect):
    """P*: ``D = K * Poisson(D_clean / K)``, K in DN per electron. Negative clean values count as 0 electrons."""

    token = "P*"
    order = SHOT

    def forward(self, signal_dn, clean_dn, params, generator):
        k = per_sample(params["k"])
        electrons = torch.clamp(signal_dn / k, min=0.0)
        return torch.poisson(electrons, generator=generator) * k


@register
class GaussianShotNoise(NoiseEffect):
    """P: the heteroscedastic Gaussian approximation, ``D + sqrt(K * D) * N(0, 1)``."""

    token = "P"
    order = SHOT

    def forward(self, signal_dn, clean_dn, params, generator):
        k = per_sample(params["k"])
        z = torch.randn(signal_dn.shape, device=signal_dn.device, generator=generator, dtype=signal_dn.dtype)
        return signal_dn + torch.sqrt(k * torch.clamp(signal_dn, min=0.0)) * z
