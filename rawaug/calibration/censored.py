"""Bias frames clipped from below: the read noise from what the clip leaves.

Many cameras store no value under a floor (code 0, or the black level itself: then half a
bias frame's values pile up there). The lower half of the read noise is lost: the frame's
mean, its spread and its probability plot are those of a censored sample, and a fit to them
gives a read noise too small, a wrong shape and a colour bias too high. A calibration
engineer fits the part above the clip: the order statistics above it, at their places in the
whole sample (type I censoring), give the Tukey-lambda shape, the scale and the location.
A clip at the file's lowest code (code 0: a black level within the noise) is the recording
format's, known like the white level: calibration puts it in the profile (``code_floor``).
A clip above code 0 (firmware clipping at the black level) is an effect the loop finds and
models (``Clip``); calibration only has to measure the noise under it right.
"""
from __future__ import annotations

import numpy as np
from scipy import optimize, stats

from .read_noise import LAMBDA_GRID, ReadNoiseEstimate, _filliben, _ppcc, subsample

CENSORED_MIN = 1e-3  # share of a bias frame's values at its lowest value, over the next value's count: a clip
NOISE_REACH = 3.0  # a clip cuts into the noise: its level within this many robust sigmas below the median
CENSOR_MARGIN = 0.01  # order statistics just above a clip left out too (row offsets smear its edge), share of all


def black_floor(bias_dn) -> float | None:
    """The value (DN) a bias frame is clipped at from below, or None: its lowest value, where
    at least CENSORED_MIN of its values pile up, more than at the next value above (a noise
    tail thins out towards its lowest value; a clip piles the whole lower tail on it) and
    within NOISE_REACH robust sigmas of the median (dead pixels stuck far below are no clip)."""
    v = np.asarray(bias_dn).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    low = v.min()
    n_low = int(np.count_nonzero(v == low))
    if n_low < max(10, CENSORED_MIN * v.size) or n_low == v.size:
        return None
    above = v[v > low]
    n_next = int(np.count_nonzero(above == above.min()))
    med = float(np.median(v))
    within = low >= med - NOISE_REACH * 1.4826 * float(np.median(np.abs(v - med)))  # in the noise, not a dead level
    return float(low) if n_low > n_next and within else None


HOT_OUTLIER = 6.0  # a pixel whose lowest value over a clipped stack (>= 3 frames) is this many upper-body sigmas above the median: hot


def hot_under_clip(lowest, first) -> np.ndarray:
    """(4, h, w) mask of the pixels of a clipped bias stack that are high in every frame: their
    lowest value ``lowest`` over the stack more than HOT_OUTLIER sigmas above their channel's
    median in ``first`` (one frame), the sigma read from the body above the clip (99th
    percentile less the median, over 2.326). A fixed offset, not read noise; the censored fit
    sees only the upper half, where 0.1 % of such pixels set its shape. The lowest of three
    frames of read noise is 6 sigma high with a chance of ~1e-10 (a Tukey lambda of -0.24)."""
    first = np.asarray(first, dtype=np.float64).reshape(4, -1)
    med = np.nanmedian(first, axis=1)
    sigma = (np.nanpercentile(first, 99.0, axis=1) - med) / 2.326
    hot = np.asarray(lowest, dtype=np.float64).reshape(4, -1) > (med + HOT_OUTLIER * sigma)[:, None]
    return (hot & (sigma > 0)[:, None]).reshape(np.shape(lowest))


def code_floor(floors_dn, black_levels) -> float | None:
    """The floor (DN) of the profile's ``Clip`` when bias frames are clipped at the file's
    lowest code: code 0, minus a black level of ``black_levels`` (one per channel) in DN,
    when any of the per-ISO ``floors_dn`` (``black_floor``; None where none) lies within half
    a code of it; else None (no clip, or one above code 0: the loop's to find)."""
    zero_codes = -np.unique(np.asarray(black_levels, dtype=np.float64))
    at_zero = [f for f in floors_dn if f is not None and np.min(np.abs(f - zero_codes)) <= 0.5]
    return float(min(at_zero)) if at_zero else None


def clipped_share(values, floor_dn: float) -> float:
    """Share of the noise of ``values`` below the clip ``floor_dn``: of the values at it, less
    the upper half of its cell (on a grid of codes the clip's own code also holds values that
    were not clipped: half a cell of the density at its quarter point, extrapolated by the
    parabola through the counts of the next three codes). The row means of clipped frames move
    by 1 - this share of a row's offset."""
    v = np.asarray(values).ravel()
    at = int(np.count_nonzero(v <= floor_dn))
    codes, counts = np.unique(v[v > floor_dn], return_counts=True)
    half_cell = 0.0
    if codes.size >= 3:  # Lagrange weights at 1/4 cell of the parabola through cells 1, 2, 3 above the clip
        half_cell = max(0.5 * float(np.dot(counts[:3], (2.40625, -2.0625, 0.65625))), 0.0)
    elif codes.size:
        half_cell = 0.5 * float(counts[0])
    return float(at - half_cell) / max(v.size, 1)


def spread_over_cells(sorted_codes):
    """Sorted whole codes with the m values of each code spread evenly over its cell
    (code - 1/2, code + 1/2): the j-th at code - 1/2 + (j + 1/2) / m."""
    x = np.asarray(sorted_codes, dtype=np.float64)
    starts = np.flatnonzero(np.r_[True, x[1:] != x[:-1]])
    counts = np.diff(np.r_[starts, x.size])
    rank = np.arange(x.size) - np.repeat(starts, counts)
    return x - 0.5 + (rank + 0.5) / np.repeat(counts, counts)


def censored_read_noise(values_dn, floor_dn: float, *, max_samples: int | None = 200_000,
                        seed: int = 0) -> tuple[ReadNoiseEstimate, float]:
    """(read noise, location in DN) of values clipped from below at ``floor_dn``: PPCC on the
    order statistics above the clip (but the CENSOR_MARGIN just above it), each against the
    Tukey-lambda quantile at its plotting position in the whole sample (whole codes spread
    over their cells, ``spread_over_cells``); lambda maximizes the
    correlation (grid, then bounded refinement), sigma_TL is the slope, the location the
    intercept (the median of the noise before the clip). ``sigma_g`` likewise on normal
    quantiles."""
    x = np.sort(subsample(values_dn, max_samples, seed))
    if not np.all(np.isfinite(x)):
        raise ValueError("values_dn holds NaN or Inf values")
    n = x.size
    start = int(np.searchsorted(x, floor_dn, side="right")) + int(CENSOR_MARGIN * n)
    if np.all(x == np.rint(x)):  # whole codes: each spread over its cell (a step's part would bias the line)
        x = spread_over_cells(x)
    if n - start < 100 or x[start] == x[-1]:
        raise ValueError(f"a censored read-noise fit needs at least 100 distinct values above the clip at "
                         f"{floor_dn:g} DN, got {max(n - start, 0)} of {n}")
    osm, above = _filliben(n)[start:], x[start:]
    grid = [(float(lam), _ppcc(above, osm, lam)) for lam in LAMBDA_GRID]
    best = max(range(len(grid)), key=lambda i: grid[i][1])
    lo, hi = LAMBDA_GRID[max(best - 1, 0)], LAMBDA_GRID[min(best + 1, len(LAMBDA_GRID) - 1)]
    lam = float(LAMBDA_GRID[best])
    if hi > lo:
        res = optimize.minimize_scalar(lambda v: -_ppcc(above, osm, v), bounds=(float(lo), float(hi)), method="bounded",
                                       options={"xatol": 1e-3})
        if res.success and -res.fun >= grid[best][1]:
            lam = float(res.x)
    slope_tl, location, r_tl, _, _ = stats.linregress(stats.tukeylambda.ppf(osm, lam), above)
    slope_g, _, r_g, _, _ = stats.linregress(stats.norm.ppf(osm), above)
    read = ReadNoiseEstimate(lam=lam, sigma_tl=float(slope_tl), sigma_g=float(slope_g), r2_tukey=float(r_tl**2),
                             r2_gauss=float(r_g**2), ppcc_grid=tuple(grid), n_samples=int(n),
                             std_dn=float(slope_g))
    return read, float(location)
