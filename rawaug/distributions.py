"""The distributions of the noise stages, as plain maths (torch, any device).

The CPU kernel tabulates these quantiles (``rawaug.cpu.quantile_table``), the Triton
kernel evaluates the same formulas in registers, and the effects use the variances.
"""
from __future__ import annotations

import math

import numpy as np
import torch

LAMBDA_ZERO = 1e-6  # |lambda| below this: the logistic limit


def tukey_lambda_upper_quantile(tail: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """Quantile of the standard Tukey lambda at ``1 - tail``, for ``tail`` in (0, 1/2]: ``>= 0``.
    Computed from the tail with ``log1p``/``expm1``, so it keeps full precision as
    ``tail -> 0``; the lambda -> 0 limit is the logistic ``log((1 - tail) / tail)``."""
    log_tail = torch.log(tail)
    log_body = torch.log1p(-tail)
    small = lam.abs() < LAMBDA_ZERO
    safe = torch.where(small, torch.ones_like(lam), lam)
    q = (torch.expm1(safe * log_body) - torch.expm1(safe * log_tail)) / safe
    return torch.where(small, log_body - log_tail, q)


def tukey_lambda_icdf(u: torch.Tensor, lam: torch.Tensor, tail_floor: float = 2.0**-26) -> torch.Tensor:
    """Tukey lambda quantile ``(u^l - (1-u)^l) / l`` (unit scale), with the l -> 0 logistic
    limit ``log(u / (1-u))``, evaluated on the smaller tail (finite at u = 0 and 1)."""
    upper = u >= 0.5
    tail = torch.clamp(torch.where(upper, 1.0 - u, u), min=tail_floor)
    q = tukey_lambda_upper_quantile(tail, lam)
    return torch.where(upper, q, -q)


def tukey_lambda_variance(lam: float) -> float:
    """Variance of the standard Tukey lambda distribution (infinite for lam <= -0.5)."""
    if lam <= -0.5:
        return math.inf
    if abs(lam) < LAMBDA_ZERO:
        return math.pi**2 / 3.0
    return (2.0 / lam**2) * (1.0 / (1.0 + 2.0 * lam) - math.gamma(lam + 1.0) ** 2 / math.gamma(2.0 * lam + 2.0))


def normal_upper_quantile(tail: torch.Tensor) -> torch.Tensor:
    """Quantile of the standard normal at ``1 - tail``."""
    return -torch.special.ndtri(tail)


_TAILS = np.geomspace(1e-15, 0.5, 4000)  # tail probabilities tabulated by tukey_lambda_survival


def tukey_lambda_survival(y, lam: float):
    """P(T > y) of the standard Tukey lambda distribution (numpy, y >= 0), by inverting its
    quantile on a table of tail probabilities from 1e-15 to 0.5 (relative error ~1e-3)."""
    lam = float(lam)
    p = _TAILS[::-1]  # ascending quantiles: upper tail 0.5 .. 1e-15
    if abs(lam) < LAMBDA_ZERO:
        q = np.log1p(-p) - np.log(p)
    else:
        q = ((1.0 - p) ** lam - p**lam) / lam
    y = np.abs(np.asarray(y, dtype=np.float64))
    return np.exp(np.interp(y, q, np.log(p), left=math.log(0.5), right=math.log(_TAILS[0])))
