"""Split a (B, n) job over threads; the kernels release the GIL."""
from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch

_pool: ThreadPoolExecutor | None = None
_pool_pid = -1
_MIN_CHUNK = 1 << 16  # elements: below this a thread costs more than it saves


def _executor(threads: int) -> ThreadPoolExecutor:
    global _pool, _pool_pid
    if _pool is None or _pool_pid != os.getpid() or _pool._max_workers < threads:
        _pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="rawaug-cpu")
        _pool_pid = os.getpid()
    return _pool


def segments(batch: int, n: int, threads: int) -> list[list[tuple[int, int, int]]]:
    """Per thread, the (sample, start, stop) pieces of an equal share of the B*n elements."""
    total = batch * n
    chunks = max(1, min(threads, total // _MIN_CHUNK))
    bounds = [total * c // chunks for c in range(chunks + 1)]
    work = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        pieces = []
        g = lo
        while g < hi:
            b, i = divmod(g, n)
            stop = min(n, i + hi - g)
            pieces.append((b, i, stop))
            g += stop - i
        work.append(pieces)
    return work


def run(piece_fn, batch: int, n: int) -> None:
    """Call ``piece_fn(b, start, stop)`` over every piece, on ``torch.get_num_threads()`` threads."""
    work = segments(batch, n, torch.get_num_threads())

    def job(pieces):
        for b, start, stop in pieces:
            piece_fn(b, start, stop)

    if len(work) == 1:
        job(work[0])
        return
    for future in [_executor(len(work)).submit(job, pieces) for pieces in work]:
        future.result()


def for_each_row(kernel, signal: torch.Tensor, out: torch.Tensor, per_sample: torch.Tensor, key: int,
                 *constants, tables=None) -> torch.Tensor:
    """Run ``kernel(x, out, per_sample[b], key, g0, [tables[b],] *constants)`` over the pieces
    of every sample's flattened row (``g0``: the piece's first global element index); returns ``out``."""
    x, o = rows_of(signal, out)
    values = per_sample.detach().to("cpu", torch.float64).reshape(-1).numpy()
    n, key = x.shape[1], np.uint64(key)
    if tables is None:
        run(lambda b, lo, hi: kernel(x[b, lo:hi], o[b, lo:hi], values[b], key, b * n + lo, *constants), x.shape[0], n)
    else:
        run(lambda b, lo, hi: kernel(x[b, lo:hi], o[b, lo:hi], values[b], key, b * n + lo, tables[b], *constants),
            x.shape[0], n)
    return out


def rows_of(signal: torch.Tensor, out: torch.Tensor):
    """(B, n) NumPy views of the input and of ``out`` (contiguous, same shape; may be the input)."""
    if not out.is_contiguous() or out.shape != signal.shape or out.dtype != signal.dtype:
        raise ValueError(f"out must be a contiguous {signal.dtype} tensor of shape {tuple(signal.shape)}")
    shape = (signal.shape[0], math.prod(signal.shape[1:]))
    return signal.contiguous().reshape(shape).numpy(), out.reshape(shape).numpy()
