"""``rawaug.rng``'s counter hash and the quantiles it feeds, as Triton device functions."""
from __future__ import annotations

import triton
import triton.language as tl


@triton.jit
def mix64(z):
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9
    z = (z ^ (z >> 27)) * 0x94D049BB133111EB
    return z ^ (z >> 31)


@triton.jit
def draw(key, g):
    """64 random bits (uint64) of element ``g`` of stream ``key`` (both uint64)."""
    return mix64(key + g * 0x9E3779B97F4A7C15)


@triton.jit
def unit(z):
    """Uniform in (0, 1), float64, from the top 53 bits."""
    return ((z >> 11).to(tl.float64) + 0.5) * 1.1102230246251565e-16


@triton.jit
def tail_of(z):
    """(tail probability in (0, 1/2) as float32, sign +1/-1) of 64 random bits."""
    r = (z & 0x7FFFFFFFFFFFFFFF) | 1
    t = (r.to(tl.float64) * 5.421010862427522e-20).to(tl.float32)
    sign = 1.0 - 2.0 * (z >> 63).to(tl.float32)
    return t, sign


@triton.jit
def _log1p_neg(t):
    """log(1 - t), accurate for small t (Kahan)."""
    w = 1.0 - t
    return tl.where(w == 1.0, -t, tl.log(w) * (-t) / (w - 1.0))


@triton.jit
def _expm1(x):
    """exp(x) - 1, accurate for small x (Kahan)."""
    u = tl.exp(x)
    um1 = u - 1.0
    safe = tl.where((u == 1.0) | (um1 == -1.0), 1.0, u)
    return tl.where(u == 1.0, x, tl.where(um1 == -1.0, -1.0, um1 * x / tl.log(safe)))


@triton.jit
def tukey_upper(t, lam):
    """Standard Tukey-lambda quantile at 1 - t (float32); logistic limit for |lam| < 1e-6."""
    log_t = tl.log(t)
    log_body = _log1p_neg(t)
    small = tl.abs(lam) < 1e-6
    safe = tl.where(small, 1.0, lam)
    q = (_expm1(safe * log_body) - _expm1(safe * log_t)) / safe
    return tl.where(small, log_body - log_t, q)


@triton.jit
def normal_upper(t):
    """Standard normal quantile at 1 - t, t in (0, 1/2] (Wichura's AS241, float32)."""
    q = 0.5 - t
    r = 0.180625 - q * q
    central = q * (((((((2509.0809287301226727 * r + 33430.575583588128105) * r + 67265.770927008700853) * r
                        + 45921.953931549871457) * r + 13731.693765509461125) * r + 1971.5909503065514427) * r
                     + 133.14166789178437745) * r + 3.387132872796366608) / (
        ((((((5226.495278852545925 * r + 28729.085735721942674) * r + 39307.89580009271061) * r
            + 21213.794301586595867) * r + 5394.1960214247511077) * r + 687.1870074920579083) * r
         + 42.313330701600911252) * r + 1.0)
    s = tl.sqrt(-tl.log(tl.maximum(t, 1e-38)))
    a = s - 1.6
    mid = (((((((7.7454501427834140764e-4 * a + 0.0227238449892691845833) * a + 0.24178072517745061177) * a
               + 1.27045825245236838258) * a + 3.64784832476320460504) * a + 5.7694972214606914055) * a
            + 4.6303378461565452959) * a + 1.42343711074968357734) / (
        ((((((1.05075007164441684324e-9 * a + 5.475938084995344946e-4) * a + 0.0151986665636164571966) * a
            + 0.14810397642748007459) * a + 0.68976733498510000455) * a + 1.6763848301838038494) * a
         + 2.05319162663775882187) * a + 1.0)
    e = s - 5.0
    far = (((((((2.01033439929228813265e-7 * e + 2.71155556874348757815e-5) * e + 0.0012426609473880784386) * e
               + 0.026532189526576123093) * e + 0.29656057182850489123) * e + 1.7848265399172913358) * e
            + 5.4637849111641143699) * e + 6.6579046435011037772) / (
        ((((((2.04426310338993978564e-15 * e + 1.4215117583164458887e-7) * e + 1.8463183175100546818e-5) * e
            + 7.868691311456132591e-4) * e + 0.0148753612908506148525) * e + 0.13692988092273580531) * e
         + 0.59983220655588793769) * e + 1.0)
    return tl.where(q <= 0.425, central, tl.where(s <= 5.0, mid, far))


@triton.jit
def _halve(n, x, s: tl.constexpr):
    """One halving step of ``leading_zeros``: are the top ``s`` bits of x all zero?"""
    small = x < (1 << (64 - s))
    return n + tl.where(small, s, 0), tl.where(small, x << s, x)


@triton.jit
def leading_zeros(x):
    """Count of leading zero bits of a uint64 (x > 0), by halving."""
    n = tl.zeros_like(x).to(tl.int64)
    n, x = _halve(n, x, 32)
    n, x = _halve(n, x, 16)
    n, x = _halve(n, x, 8)
    n, x = _halve(n, x, 4)
    n, x = _halve(n, x, 2)
    n, x = _halve(n, x, 1)
    return n


@triton.jit
def symmetric_table(table_ptr, z):
    """The CPU kernel's tabulated symmetric draw (``rawaug.cpu.quantile_table.symmetric``),
    the same lookup and interpolation in float64: used where a value feeds the Poisson
    draw, so that both backends count the same electrons."""
    r = (z & 0x7FFFFFFFFFFFFFFF) | 1
    lz = leading_zeros(r)  # 1..63
    pos = (r.to(tl.float64) * tl.exp2((lz - 63).to(tl.float64)) - 1.0) * 1024.0
    j = pos.to(tl.int64)
    idx = (lz - 1) * 1025 + j
    lo = tl.load(table_ptr + idx)
    q = lo + (pos - j.to(tl.float64)) * (tl.load(table_ptr + idx + 1) - lo)
    return q * (1.0 - 2.0 * (z >> 63).to(tl.float64))
