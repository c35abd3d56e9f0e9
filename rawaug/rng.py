"""One counter-based random stream for every backend.

Every random number rawaug draws is a pure function of a 63-bit stream key and a counter:
``bits = mix64(key + counter * GOLDEN)``, output ``counter`` of SplitMix64 seeded with
``key`` (Steele et al. 2014). The numba CPU kernel, the Triton kernel and the host code
that draws per-sample parameters (numpy; torch as its reference) all compute it, so the same seed gives the same noise on
any device. Keys are derived on the host from the call seed and a purpose (an effect's
token, a parameter name); counters are element indices, so nothing is stored.

From 64 bits:

* ``unit``: uniform in (0, 1), ``(bits >> 11 + 1/2) * 2**-53``;
* a symmetric draw (Gaussian, Tukey lambda): the top bit is the sign, the low 63 bits the
  tail probability ``t = (bits & (2**63 - 1) | 1) * 2**-64`` in (0, 1/2), and the value is
  the distribution's upper quantile at ``t`` (``rawaug.distributions``).
"""
from __future__ import annotations

import zlib

import numpy as np
import torch

GOLDEN = 0x9E3779B97F4A7C15
M1 = 0xBF58476D1CE4E5B9
M2 = 0x94D049BB133111EB
MASK64 = (1 << 64) - 1
MASK63 = (1 << 63) - 1


def mix64(z: int) -> int:
    """SplitMix64's output function on a Python int (host side)."""
    z &= MASK64
    z = ((z ^ (z >> 30)) * M1) & MASK64
    z = ((z ^ (z >> 27)) * M2) & MASK64
    return z ^ (z >> 31)


def bits_at(key: int, counter: int) -> int:
    """64 random bits of element ``counter`` of stream ``key`` (host reference)."""
    return mix64(key + counter * GOLDEN)


def stream_key(seed: int, purpose: str) -> int:
    """63-bit key of one stream: the call (or pattern) ``seed`` and what the stream is for."""
    return mix64(mix64(int(seed) & MASK64) ^ (zlib.crc32(purpose.encode()) * GOLDEN)) & MASK63


# ------------------------------------------------------------------ torch (any device)
def _signed(v: int) -> int:
    """A uint64 constant as the int64 with the same bits."""
    v &= MASK64
    return v - (1 << 64) if v >= 1 << 63 else v


_G, _M1, _M2 = _signed(GOLDEN), _signed(M1), _signed(M2)


def _shr(z: torch.Tensor, s: int) -> torch.Tensor:
    """Logical right shift of int64 bits."""
    return (z >> s) & ((1 << (64 - s)) - 1)


def torch_bits(key: int, counter: torch.Tensor) -> torch.Tensor:
    """``bits_at`` on an int64 counter tensor (int64 multiplication wraps like uint64)."""
    z = counter.to(torch.int64) * _G + _signed(key)
    z = (z ^ _shr(z, 30)) * _M1
    z = (z ^ _shr(z, 27)) * _M2
    return z ^ _shr(z, 31)


def torch_unit(key: int, counter: torch.Tensor) -> torch.Tensor:
    """Uniform in (0, 1), float64, of the given counters."""
    return (_shr(torch_bits(key, counter), 11).to(torch.float64) + 0.5) * 2.0**-53


def torch_normal(key: int, counter: torch.Tensor) -> torch.Tensor:
    """Standard normal, float64, of the given counters (inverse CDF of ``torch_unit``)."""
    return torch.special.ndtri(torch_unit(key, counter))


# ------------------------------------------------------------------ numpy (host draws)
_NG, _NM1, _NM2, _NK = np.uint64(GOLDEN), np.uint64(M1), np.uint64(M2), np.uint64


def numpy_bits(key: int, counter: np.ndarray) -> np.ndarray:
    """``torch_bits`` in numpy uint64 (the same bits): a few microseconds per array, where the
    torch version's dozen small operations cost tens (the per-call parameter draws)."""
    with np.errstate(over="ignore"):
        z = np.asarray(counter, dtype=np.uint64) * _NG + _NK(key & MASK64)
        z = (z ^ (z >> _NK(30))) * _NM1
        z = (z ^ (z >> _NK(27))) * _NM2
    return z ^ (z >> _NK(31))


def host_unit(key: int, n: int) -> torch.Tensor:
    """``torch_unit(key, arange(n))`` on the CPU, the same values, computed in numpy."""
    return torch.from_numpy(((numpy_bits(key, np.arange(n)) >> _NK(11)).astype(np.float64) + 0.5) * 2.0**-53)


def host_normal(key: int, n: int) -> torch.Tensor:
    """``torch_normal(key, arange(n))`` on the CPU, the same values."""
    return torch.special.ndtri(host_unit(key, n))
