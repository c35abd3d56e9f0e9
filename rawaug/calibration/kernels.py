"""Calibration's passes over whole frames, one pass each (numba): at 12 MP, NumPy's
reductions over a tiled view and its masked updates took 40 % of a calibration."""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True, nogil=True)
def _pair_tiles(a, b, tile):
    c, h, w = a.shape
    th, tw = h // tile, w // tile
    n = tile * tile
    out = np.empty((8, c, th, tw))
    for job in prange(c * th):
        ch, ty = job // th, job % th
        for tx in range(tw):
            y0, x0 = ty * tile, tx * tile
            sa = sb = sd = 0.0
            for y in range(y0, y0 + tile):
                for x in range(x0, x0 + tile):
                    va, vb = np.float64(a[ch, y, x]), np.float64(b[ch, y, x])  # float32 frames: as float64's
                    sa += va
                    sb += vb
                    sd += va - vb
            md = sd / n
            ss = 0.0
            lo, hi, lo_same, hi_same = math.inf, -math.inf, math.inf, -math.inf
            n_lo = n_hi = 0
            for y in range(y0, y0 + tile):
                for x in range(x0, x0 + tile):
                    va, vb = np.float64(a[ch, y, x]), np.float64(b[ch, y, x])
                    d = va - vb
                    ss += (d - md) * (d - md)
                    if d != 0.0:
                        lo = min(lo, va, vb)
                        hi = max(hi, va, vb)
                        continue
                    if va < lo_same:
                        lo_same, n_lo = va, 1
                    elif va == lo_same:
                        n_lo += 1
                    if va > hi_same:
                        hi_same, n_hi = va, 1
                    elif va == hi_same:
                        n_hi += 1
            out[0, ch, ty, tx] = 0.5 * (sa / n + sb / n)
            out[1, ch, ty, tx] = ss / (n - 1) / 2.0  # var(a - b) = 2 var(one frame)
            out[2, ch, ty, tx] = lo
            out[3, ch, ty, tx] = hi
            out[4, ch, ty, tx] = lo_same
            out[5, ch, ty, tx] = n_lo / n
            out[6, ch, ty, tx] = hi_same
            out[7, ch, ty, tx] = n_hi / n
    return out


def pair_tile_stats(a, b, tile: int):
    """Per ``tile x tile`` tile of each channel of a flat pair (packed (c, h, w), DN): mean of
    the pair, half the variance of the pair difference (the single-frame variance), the lowest
    and highest value of the pixels that differ between the two frames, and the lowest and
    highest value with the fraction of the tile's pixels equal in both frames at them. Flat
    (channel, mean, var, min, max, (min, fraction), (max, fraction)) arrays over tiles; a pixel
    equal in both frames may be a dead pixel, which does not make a tile clipped."""
    c, h, w = a.shape
    if h // tile == 0 or w // tile == 0:
        raise ValueError(f"flat frames of packed size {h}x{w} are smaller than one {tile}x{tile} tile")
    dtype = np.float32 if a.dtype == b.dtype == np.float32 else np.float64  # float32 read as is: no 12 MP copies
    s = _pair_tiles(np.ascontiguousarray(a, dtype=dtype), np.ascontiguousarray(b, dtype=dtype), int(tile))
    mean, var, lo, hi, lo_same, frac_lo, hi_same, frac_hi = (x.ravel() for x in s)
    chan = np.broadcast_to(np.arange(c)[:, None, None], s.shape[1:]).ravel()
    return chan, mean, var, lo, hi, (lo_same, frac_lo), (hi_same, frac_hi)


@njit(parallel=True, cache=True, nogil=True)
def _update_extremes(top, second, frame, r, sign, i):
    for j in prange(r.size):
        v = np.float32(sign * r[j])
        t = top[j]
        if math.isnan(v) or math.isnan(t):  # a defect line: NaN from then on, as NumPy's maximum
            top[j] = second[j] = np.nan
            continue
        if v > t:
            frame[j] = i
            second[j] = t
            top[j] = v
        elif v > second[j]:
            second[j] = v


def pixel_extremes(state, r, i: int, sign: float = 1.0):
    """(highest, second highest, frame of the highest) of each pixel of ``sign * r`` over the
    frames so far (float32, flat), updated in place with frame ``i``'s values ``r`` (a new
    state when ``state`` is None); NaN (a defect line) stays NaN."""
    r = np.ascontiguousarray(r, dtype=np.float64).ravel()
    if state is None:
        return (sign * r).astype(np.float32), np.full(r.size, -np.inf, np.float32), np.full(r.size, i, np.int32)
    _update_extremes(*state, r, float(sign), int(i))
    return state
