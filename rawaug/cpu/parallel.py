"""Split a job of rows over threads; the kernels release the GIL."""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor


_pool: ThreadPoolExecutor | None = None
_pool_pid = -1
_MIN_CHUNK = 1 << 16  # elements: below this a thread costs more than it saves


def _executor(threads: int) -> ThreadPoolExecutor:
    global _pool, _pool_pid
    if _pool is None or _pool_pid != os.getpid() or _pool._max_workers < threads:
        _pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="rawaug-cpu")
        _pool_pid = os.getpid()
    return _pool


def run_ranges(range_fn, rows: int, row_length: int, threads: int) -> int:
    """Call ``range_fn(r0, r1)`` over equal shares of ``rows`` rows on ``threads`` threads;
    returns the sum of what the calls return."""
    chunks = max(1, min(threads, rows, rows * row_length // _MIN_CHUNK))
    bounds = [rows * c // chunks for c in range(chunks + 1)]
    if chunks == 1:
        return range_fn(0, rows)
    pool = _executor(chunks)
    return sum(f.result() for f in [pool.submit(range_fn, lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:])])
