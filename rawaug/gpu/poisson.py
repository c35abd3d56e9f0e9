"""Exact Poisson shot noise in Triton: the CPU kernel's tables, remainder draw and PTRS
(``rawaug.cpu.poisson``), vectorized with masked loops, so the counts are the same."""
from __future__ import annotations

import triton
import triton.language as tl

from .counter import draw, mix64, unit


@triton.jit
def _any(mask):
    return tl.max(mask.to(tl.int32), axis=0) > 0


@triton.jit
def table_count(z, j, active, cdf, cdf_off, guide, guide_off, guide_size, k_min):
    """Count of table ``j`` for the uniform in the top 53 bits of ``z`` (where ``active``)."""
    u = unit(z)
    o = tl.load(cdf_off + j, mask=active, other=0)
    cell = (u * tl.load(guide_size + j, mask=active, other=1.0)).to(tl.int64)
    c = tl.load(guide + tl.load(guide_off + j, mask=active, other=0) + cell, mask=active, other=0).to(tl.int64)
    search = active & (c < 0)
    c = tl.where(search, -c - 1, c)
    pending = search & (tl.load(cdf + o + c, mask=search, other=1.0) < u)
    while _any(pending):
        c += pending.to(tl.int64)
        pending = pending & (tl.load(cdf + o + c, mask=pending, other=1.0) < u)
    return c + tl.load(k_min + j, mask=active, other=0)


@triton.jit
def small_poisson(d, spare, key_rest, g, active):
    """Poisson(d), d < 1/8, from the 11 spare bits of the fine draw (see the CPU kernel)."""
    c = spare.to(tl.float64)
    need = active & (c >= tl.floor((1.0 - d) * 2048.0))
    v = (c + unit(draw(key_rest, g))) * (1.0 / 2048.0)
    p = tl.exp(-d)
    f = p
    n = tl.zeros_like(d)
    pending = need & (v > f)
    while _any(pending):
        n = tl.where(pending, n + 1.0, n)
        p = tl.where(pending, p * d / tl.maximum(n, 1.0), p)
        f = tl.where(pending, f + p, f)
        pending = pending & (v > f) & (n < 64.0)
    return tl.where(need, n, 0.0)


@triton.jit
def log_factorial(k):
    n = tl.maximum(k, 0.0) + 1.0
    r = 1.0 / n
    r2 = r * r
    s = (n - 0.5) * tl.log(n) - n + 0.9189385332046728 + r * (1.0 / 12.0 - r2 * (1.0 / 360.0 - r2 * (1.0 / 1260.0 - r2 / 1680.0)))
    return tl.where(k < 1.0, 0.0, s)


@triton.jit
def ptrs(lam, state, active):
    """Hormann's PTRS for lam >= 4096, each lane from its own counter state."""
    lam = tl.where(active, lam, 5000.0)
    slam = tl.sqrt(lam)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    vr = 0.9277 - 3.6224 / (b - 2.0)
    invalpha = 1.1239 + 1.1328 / (b - 3.4)
    out = tl.zeros_like(lam)
    done = ~active
    while _any(~done):
        state += 0x9E3779B97F4A7C15
        u = unit(mix64(state)) - 0.5
        state += 0x9E3779B97F4A7C15
        v = unit(mix64(state))
        us = tl.maximum(0.5 - tl.abs(u), 1e-300)
        k = tl.floor((2.0 * a / us + b) * u + lam + 0.43)
        quick = (us >= 0.07) & (v <= vr)
        reject = (k < 0.0) | ((us < 0.013) & (v > us))
        full = tl.log(v) + tl.log(invalpha) - tl.log(a / (us * us) + b) <= -lam + k * tl.log(lam) - log_factorial(k)
        accept = (~done) & (quick | ((~reject) & full))
        out = tl.where(accept, k, out)
        done = done | accept
    return out


@triton.jit
def poisson_count(lam, key_fine, key_rest, key_coarse, g,
                  f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin,
                  c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin, live):
    """Exact Poisson(lam) (float64 counts), 0 where lam <= 0; tables below 4096, PTRS above."""
    positive = live & (lam > 0.0) & (lam < float("inf"))
    big = positive & (lam >= 4096.0)
    mid = positive & (lam < 4096.0)
    coarse = mid & (lam >= 64.0)
    jc = tl.where(coarse, lam * (1.0 / 64.0), 0.0).to(tl.int32)
    count = table_count(draw(key_coarse, g), jc, coarse, c_cdf, c_cdf_off, c_guide, c_guide_off, c_guide_size, c_kmin)
    count = tl.where(coarse, count, 0)
    rest = tl.where(coarse, lam - jc.to(tl.float64) * 64.0, lam)
    jf = tl.where(mid, rest * 8.0, 0.0).to(tl.int32)
    z = draw(key_fine, g)
    fine = table_count(z, jf, mid, f_cdf, f_cdf_off, f_guide, f_guide_off, f_guide_size, f_kmin)
    d = tl.where(mid, rest - jf.to(tl.float64) * 0.125, 0.0)
    small = small_poisson(d, z & 2047, key_rest, g, mid)
    total = tl.where(mid, (count + fine).to(tl.float64) + small, 0.0)
    return tl.where(big, ptrs(lam, draw(key_rest, g), big), total)
