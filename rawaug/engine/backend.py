"""Run the fused chain on a batch: numba on the CPU, Triton on CUDA (or on CPU tensors
under ``TRITON_INTERPRET=1``), behind one ``torch.library`` operator so that
``torch.compile`` neither breaks the graph at it nor changes its noise."""
from __future__ import annotations

import functools
import os

import numpy as np
import torch

from . import layout as L

_BACKEND = os.environ.get("RAWAUG_BACKEND", "auto")  # auto | numba | triton


def set_backend(name: str) -> str:
    """Choose ``auto`` (numba on the CPU, Triton elsewhere), ``numba`` or ``triton``;
    returns the previous choice."""
    global _BACKEND
    if name not in ("auto", "numba", "triton"):
        raise ValueError(f"backend must be 'auto', 'numba' or 'triton', got {name!r}")
    previous, _BACKEND = _BACKEND, name
    return previous


def backend_for(device: torch.device) -> str:
    if _BACKEND != "auto":
        return _BACKEND
    return "numba" if device.type == "cpu" else "triton"


@functools.lru_cache(maxsize=8)
def poisson_tables(device: str):
    """The CPU kernel's Poisson tables (fine, coarse) as tensors on ``device``."""
    from ..cpu.poisson import tables

    return tuple(tuple(torch.as_tensor(a).to(device) for a in part) for part in tables())


@functools.lru_cache(maxsize=8)
def normal_table_on(device: str) -> torch.Tensor:
    """The CPU kernel's normal quantile table on ``device``."""
    from ..cpu.quantile_table import normal_table

    return torch.from_numpy(normal_table()).to(device)


@functools.lru_cache(maxsize=128)
def _read_table(lam):
    from ..cpu.quantile_table import normal_table, tukey_lambda_table

    return normal_table() if lam is None else tukey_lambda_table(lam)


def _numba(clean, out, values, keys, span, flags, grids, code_lut, read_lut, check_finite=False):
    from ..cpu.fused import synthesize
    from ..cpu.poisson import tables
    from ..cpu.quantile_table import normal_table

    v = values.detach().to("cpu", torch.float64).contiguous().numpy()
    if flags & L.READ_TUKEY:
        lams = [float(x) for x in v[:, L.COLUMN["lambda"]]]
        unique = sorted(set(lams))
        read_tables = np.stack([_read_table(lam) for lam in unique])
        read_index = np.array([unique.index(lam) for lam in lams], dtype=np.int64)
    else:
        read_tables = normal_table()[None]
        read_index = np.zeros(max(1, v.shape[0]), dtype=np.int64)
    fine, coarse = tables()
    bad = synthesize(clean.numpy(), out.numpy(), v, *L.flag_words(flags), keys.cpu().numpy().astype(np.uint64), span, read_tables, read_index,
               normal_table(), fine, coarse, grids.cpu().numpy().astype(np.float64),
                     code_lut.cpu().numpy().astype(np.float64), read_lut.cpu().numpy().astype(np.float64),
                     threads=torch.get_num_threads())
    if bad and check_finite:
        raise ValueError(f"input holds {bad} NaN or Inf values; expected finite normalized intensities")
    return out


def _triton(clean, out, values, keys, span, flags, grids, code_lut, read_lut):
    from ..gpu.fused import launch

    if clean.device.type == "cpu" and os.environ.get("TRITON_INTERPRET") != "1":
        raise RuntimeError("the Triton backend runs CPU tensors only under TRITON_INTERPRET=1 (set before importing triton)")
    fine, coarse = poisson_tables(str(clean.device))
    return launch(clean, out, values.to(torch.float64), keys, span, flags, fine, coarse, grids.to(clean.device, torch.float64),
                  normal_table_on(str(clean.device)), code_lut.to(clean.device, torch.float64).contiguous(),
                  read_lut.to(clean.device, torch.float64).contiguous())


def run(clean: torch.Tensor, values: torch.Tensor, keys: torch.Tensor, span: float, flags: int,
        grids: torch.Tensor, code_lut: torch.Tensor, read_lut: torch.Tensor, check_finite: bool = False) -> torch.Tensor:
    """Noisy batch (normalized) from a contiguous clean (B, 4, H, W) float32/float64 batch.
    ``check_finite``: refuse non-finite clean values where that costs no synchronization
    (the CPU kernel counts them as it goes); elsewhere they come out as NaN."""
    out = torch.empty_like(clean)
    if clean.numel() == 0:
        return out
    if backend_for(clean.device) == "numba":
        if clean.device.type != "cpu":  # no Triton here: the CPU kernel, same noise
            return _numba(clean.cpu(), out.cpu(), values, keys, span, flags, grids, code_lut, read_lut, check_finite).to(clean.device)
        return _numba(clean, out, values, keys, span, flags, grids, code_lut, read_lut, check_finite)
    return _triton(clean, out, values, keys.to(clean.device), span, flags, grids, code_lut, read_lut)


@torch.library.custom_op("rawaug::synthesize", mutates_args=())
def _synthesize(clean: torch.Tensor, values: torch.Tensor, keys: torch.Tensor, span: float, flags: int, flags_high: int,
                grids: torch.Tensor, code_lut: torch.Tensor, read_lut: torch.Tensor, check_finite: bool = False) -> torch.Tensor:
    return run(clean.contiguous(), values, keys, span, flags | flags_high << L.WORD_BITS, grids, code_lut, read_lut, check_finite)


@_synthesize.register_fake
def _(clean, values, keys, span, flags, flags_high, grids, code_lut, read_lut, check_finite=False):
    return torch.empty_like(clean)


def synthesize_op(clean: torch.Tensor, values: torch.Tensor, keys: torch.Tensor, span: float, flags: int,
                  grids: torch.Tensor, code_lut: torch.Tensor, read_lut: torch.Tensor, check_finite: bool = False) -> torch.Tensor:
    """The fused chain as one operator; ``flags`` (any stage set) reach it as two int64 words."""
    low, high = L.flag_words(flags)
    return _synthesize(clean, values, keys, span, low, high, grids, code_lut, read_lut, check_finite)
