"""Uniform noise of one quantization step (U)."""
from __future__ import annotations

import torch
from numba import njit

from .counter import draw, unit
from .parallel import for_each_row


@njit(nogil=True, cache=True)
def _add_uniform(x, out, step, key, g0):
    for i in range(x.size):
        out[i] = x[i] + (unit(draw(key, g0 + i)) - 0.5) * step


def add_uniform(signal: torch.Tensor, out: torch.Tensor, step: torch.Tensor, key: int) -> torch.Tensor:
    """``signal + U(-step[b]/2, step[b]/2)``; written into ``out`` (which may be the input)."""
    return for_each_row(_add_uniform, signal, out, step, key)
