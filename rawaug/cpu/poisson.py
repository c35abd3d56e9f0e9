"""Exact Poisson sampling for shot noise (P*), counter-based.

lambda = L + d with L on a grid of step 1/4 below 64 electrons: Poisson(lambda) =
Poisson(L) + Poisson(d). Poisson(L) is the inversion of its CDF table (scipy's, in
float64, over every count whose tail mass exceeds 2**-60, so no 53-bit uniform can reach
outside it) through a guide table of power-of-two size whose cells mostly map to a single
count; Poisson(d) is 0 whenever the second uniform is below 1 - d <= exp(-d), else exact
sequential inversion. Above the grid: Hormann's PTRS (1993), as NumPy does.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import torch
from numba import njit

from .counter import GOLDEN, U64, derived_key, draw, mix64, unit
from .parallel import rows_of, run

GRID_STEP = 0.25
TABLE_MAX = 64.0  # electrons; PTRS above
_TAIL = 2.0**-60


@functools.lru_cache(maxsize=1)
def tables():
    """(cdf, cdf_offset, guide, guide_offset, guide_size, k_min) for L = 0, 1/4, ..., 63.75."""
    from scipy import stats

    cdfs, guides, k_mins = [], [], []
    for i in range(int(TABLE_MAX / GRID_STEP)):
        lam = i * GRID_STEP
        if lam == 0.0:
            k_min, cdf = 0, np.ones(1)
        else:
            spread = int(12 * math.sqrt(lam)) + 12
            counts = np.arange(max(0, int(lam) - spread), int(lam) + spread + 1)
            cdf = stats.poisson.cdf(counts, lam)
            inside = np.nonzero(cdf >= _TAIL)[0][0]
            last = np.nonzero(stats.poisson.sf(counts, lam) < _TAIL)[0][0]
            if inside == 0 and counts[0] > 0:
                raise AssertionError(f"Poisson table for {lam} starts inside its lower tail")
            k_min, cdf = int(counts[inside]), cdf[inside : last + 1].copy()
            cdf[-1] = 1.0
        size = 1 << int(math.ceil(math.log2(4 * len(cdf))))
        lo = np.searchsorted(cdf, np.arange(size) / size, side="left")
        hi = np.searchsorted(cdf, np.arange(1, size + 1) / size, side="left")
        cdfs.append(cdf)
        guides.append(np.where(lo == hi, lo, -lo - 1).astype(np.int32))  # >= 0: the cell's only count
        k_mins.append(k_min)
    offsets = lambda parts: np.cumsum([0] + [len(p) for p in parts[:-1]]).astype(np.int64)  # noqa: E731
    return (np.concatenate(cdfs), offsets(cdfs), np.concatenate(guides), offsets(guides),
            np.array([float(len(g)) for g in guides]), np.array(k_mins, dtype=np.int64))


@njit(inline="always")
def _ptrs(lam, state):
    slam = math.sqrt(lam)
    loglam = math.log(lam)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    invalpha = 1.1239 + 1.1328 / (b - 3.4)
    vr = 0.9277 - 3.6224 / (b - 2.0)
    while True:
        state += GOLDEN
        u = unit(mix64(state)) - 0.5
        state += GOLDEN
        v = unit(mix64(state))
        us = 0.5 - abs(u)
        k = math.floor((2.0 * a / us + b) * u + lam + 0.43)
        if us >= 0.07 and v <= vr:
            return k
        if k < 0.0 or (us < 0.013 and v > us):
            continue
        if math.log(v) + math.log(invalpha) - math.log(a / (us * us) + b) <= -lam + k * loglam - math.lgamma(k + 1.0):
            return k


@njit(nogil=True, cache=True)
def _poisson(x, out, gain, key, key2, g0, cdf, cdf_off, guide, guide_off, guide_size, k_min):
    inv_gain = 1.0 / gain
    inv_step = 1.0 / GRID_STEP
    for i in range(x.size):
        lam = x[i] * inv_gain
        if not lam > 0.0:
            out[i] = 0.0
            continue
        g = g0 + i
        if lam < TABLE_MAX:
            j = int(lam * inv_step)
            rest = lam - j * GRID_STEP
            u = unit(draw(key, g))
            c = guide[guide_off[j] + int(u * guide_size[j])]
            if c < 0:
                c = -c - 1
                o = cdf_off[j]
                while cdf[o + c] < u:
                    c += 1
            count = c + k_min[j]
            if rest > 0.0:
                v = unit(draw(key2, g))
                if v >= 1.0 - rest:  # else Poisson(rest) = 0, as exp(-rest) >= 1 - rest
                    p = math.exp(-rest)
                    f = p
                    n = 0
                    while v > f and n < 64:
                        n += 1
                        p *= rest / n
                        f += p
                    count += n
            out[i] = count * gain
        else:
            out[i] = _ptrs(lam, mix64(key2 + U64(g) * GOLDEN)) * gain


def poisson_dn(signal_dn: torch.Tensor, out: torch.Tensor, gain: torch.Tensor, key: int) -> torch.Tensor:
    """``gain[b] * Poisson(signal_dn / gain[b])`` (DN in, DN out); negative signal counts 0 electrons."""
    x, o = rows_of(signal_dn, out)
    k = gain.detach().to("cpu", torch.float64).numpy()
    n, key1, key2, t = x.shape[1], U64(key), U64(derived_key(key, 1)), tables()
    run(lambda b, lo, hi: _poisson(x[b, lo:hi], o[b, lo:hi], k[b], key1, key2, b * n + lo, *t), x.shape[0], n)
    return out
