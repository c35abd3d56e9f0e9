"""Uniform noise of one quantization step (U)."""
from __future__ import annotations

import torch
from numba import njit

from .counter import U64, draw, unit
from .parallel import rows_of, run


@njit(nogil=True, cache=True)
def _add_uniform(x, out, step, key, g0):
    for i in range(x.size):
        out[i] = x[i] + (unit(draw(key, g0 + i)) - 0.5) * step


def add_uniform(signal: torch.Tensor, out: torch.Tensor, step: torch.Tensor, key: int) -> torch.Tensor:
    """``signal + U(-step[b]/2, step[b]/2)``; written into ``out`` (which may be the input)."""
    x, o = rows_of(signal, out)
    s = step.detach().to("cpu", torch.float64).numpy()
    n, k = x.shape[1], U64(key)
    run(lambda b, lo, hi: _add_uniform(x[b, lo:hi], o[b, lo:hi], s[b], k, b * n + lo), x.shape[0], n)
    return out
