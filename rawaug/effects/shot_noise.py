"""Photon shot noise: electrons collected ~ Poisson(I). Tokens P* (Poisson) and P (Gaussian approx).

Stage (DN at the sensor, K in DN per electron):
  P*: ``s -> K * Poisson(max(s, 0) / K)``, exact (table inversion below 4096 e-, PTRS above);
  P:  ``s -> s + sqrt(K * max(s, 0)) * z``.
"""
from __future__ import annotations

from ..engine import layout as L
from .base import SHOT, NoiseEffect, register


@register
class PoissonShotNoise(NoiseEffect):
    """P*: ``D = K * Poisson(D_clean / K)``; negative clean values count as 0 electrons."""

    token = "P*"
    order = SHOT
    flag = L.SHOT_POISSON


@register
class GaussianShotNoise(NoiseEffect):
    """P: the heteroscedastic Gaussian approximation, ``D + sqrt(K * D) * N(0, 1)``."""

    token = "P"
    order = SHOT
    flag = L.SHOT_GAUSS
