"""Exact Poisson sampling for shot noise (P*), counter-based, with few unpredictable branches.

lambda = C + L + d with C on a coarse grid (step 64, below 4096 electrons), L on a fine grid
(step 1/8, below 64) and d < 1/8: Poisson(lambda) = Poisson(C) + Poisson(L) + Poisson(d).
Poisson(C) and Poisson(L) invert their CDF tables (scipy's, float64, over every count whose
tail mass exceeds 2**-60, so no 53-bit uniform reaches outside them) through a guide table
of 8x as many cells, most of which hold a single count: one lookup, and a short search in
the others. Poisson(d) is 0 without a second draw in all but about d of the draws (see
``_small_poisson``), else exact inversion. Above 4096 electrons: Hormann's PTRS (1993), as
NumPy does.

A mispredicted branch costs more than arithmetic here: it discards the overlapped work of
the following elements. Hence tables and rare branches rather than rejection loops.
"""
from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from .counter import GOLDEN, U64, draw, mix64, unit

GRID_STEP = 0.125  # a power of two, so lambda / GRID_STEP is exact
TABLE_MAX = 64.0  # electrons: the fine grid's range and the coarse grid's step (a power of two)
COARSE_MAX = 4096.0  # electrons; PTRS above
_TAIL = 2.0**-60
SPARE_BITS = U64(2047)  # the low 11 bits of a draw, which unit() leaves unused
_STREAM2, _STREAM3 = U64(0xD1B54A32D192ED03), U64(0xABC98388FB8FAC03)  # keys of the other uniforms


def _table_set(lams):
    """(cdf, cdf_offset, guide, guide_offset, guide_size, k_min) for Poisson(L), L in ``lams``."""
    from scipy import stats

    cdfs, guides, k_mins = [], [], []
    for lam in lams:
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
        size = 1 << int(math.ceil(math.log2(8 * len(cdf))))
        lo = np.searchsorted(cdf, np.arange(size) / size, side="left")
        hi = np.searchsorted(cdf, np.arange(1, size + 1) / size, side="left")
        cdfs.append(cdf)
        guides.append(np.where(lo == hi, lo, -lo - 1).astype(np.int32))  # >= 0: the cell's only count
        k_mins.append(k_min)
    offsets = lambda parts: np.cumsum([0] + [len(p) for p in parts[:-1]]).astype(np.int64)  # noqa: E731
    return (np.concatenate(cdfs), offsets(cdfs), np.concatenate(guides), offsets(guides),
            np.array([float(len(g)) for g in guides]), np.array(k_mins, dtype=np.int64))


@functools.lru_cache(maxsize=1)
def tables():
    """The fine tables (L = 0, 1/8, ..., 63.875) and the coarse ones (C = 0, 64, ..., 4032)."""
    fine = _table_set([i * GRID_STEP for i in range(int(TABLE_MAX / GRID_STEP))])
    coarse = _table_set([i * TABLE_MAX for i in range(int(COARSE_MAX / TABLE_MAX))])
    return fine, coarse


@njit(inline="always")
def _table_count(z, j, t):
    """Poisson count of table ``j`` of the set ``t`` for the uniform in the top 53 bits of ``z``."""
    cdf, cdf_off, guide, guide_off, guide_size, k_min = t
    u = unit(z)
    o = cdf_off[j]
    c = guide[guide_off[j] + int(u * guide_size[j])]
    if c < 0:  # a cell holding a step of the CDF: search from its first count
        c = -c - 1
        while cdf[o + c] < u:
            c += 1
    return c + k_min[j]


@njit(inline="always")
def _small_poisson(d, spare, key_rest, g):
    """Poisson(d), d < GRID_STEP, by inversion of V = (c + w) / 2**11, c the 11 bits of the
    fine-table draw that its uniform leaves unused. Below c = (1 - d) 2**11, V < 1 - d <=
    exp(-d): the count is 0 and w (a second draw) is not needed; that is all but ~d of draws."""
    c = float(spare)
    if c < math.floor((1.0 - d) * 2048.0):
        return 0
    v = (c + unit(draw(key_rest, g))) * (1.0 / 2048.0)
    p = math.exp(-d)
    f = p
    n = 0
    while v > f and n < 64:
        n += 1
        p *= d / n
        f += p
    return n


@njit(inline="always")
def log_factorial(k):
    """log(k!) by Stirling's series (float64; exact to ~1e-8 at k = 1, 1e-15 from k = 10): the
    same formula on every backend, so PTRS accepts the same counts on the CPU and the GPU."""
    if k < 1.0:
        return 0.0
    n = k + 1.0
    r = 1.0 / n
    r2 = r * r
    return (n - 0.5) * math.log(n) - n + 0.9189385332046728 + r * (1.0 / 12.0 - r2 * (1.0 / 360.0 - r2 * (1.0 / 1260.0 - r2 / 1680.0)))


@njit(inline="always")
def _ptrs(lam, state):
    slam = math.sqrt(lam)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
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
        invalpha = 1.1239 + 1.1328 / (b - 3.4)
        if math.log(v) + math.log(invalpha) - math.log(a / (us * us) + b) <= -lam + k * math.log(lam) - log_factorial(k):
            return k


def stream_keys(key: int) -> tuple[int, int, int]:
    """(fine, rest, coarse) stream keys of the shot-noise draws, from one 63-bit key."""
    from ..rng import MASK63, mix64 as host_mix

    return key, host_mix(key ^ int(_STREAM2)) & MASK63, host_mix(key ^ int(_STREAM3)) & MASK63
