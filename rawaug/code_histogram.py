"""The code histogram of a stack in two passes (numba): the counts of its values rounded to
whole DN (``np.rint``: halves to even), its lowest code, and whether every value was whole
already. ``missing_codes``, ``code_dnl`` and ``clip_low`` read the same histogram: one
pass over the stack's pixels instead of a rounding, a copy and a count for each."""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(nogil=True, cache=True)
def _histogram(v):
    lo, hi, whole = np.inf, -np.inf, True
    for i in range(v.size):
        r = np.rint(v[i])
        if r != v[i]:
            whole = False
        if r < lo:
            lo = r
        if r > hi:
            hi = r
    counts = np.zeros(int(hi - lo) + 1, dtype=np.int64)
    for i in range(v.size):
        counts[int(np.rint(v[i]) - lo)] += 1
    return int(lo), counts, whole


def code_histogram(values) -> tuple[int, np.ndarray, bool]:
    """(lowest code, counts of the codes from it up (int64), every value whole) of finite
    ``values`` rounded to whole DN, as ``np.bincount(np.rint(v) - min)`` counts them."""
    v = np.asarray(values).ravel()
    if v.size == 0 or not np.isfinite(v).all():
        raise ValueError(f"code_histogram needs finite values, got {v.size} values with non-finite ones or none")
    if v.dtype.kind != "f":
        v = v.astype(np.float64)
    return _histogram(v)
