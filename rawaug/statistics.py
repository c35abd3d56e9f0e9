"""The battery of frame statistics the loop compares between measured and synthesized frames.

Every statistic maps a stack of packed frames ``(N, 4, h, w)`` in DN (black-subtracted,
float) to one number. Each is listed in ``STATISTICS`` with the smallest stack it needs,
the frame kind it applies to (``bias``: dark/bias frames, ``flat``: uniformly lit frames,
``any``) and the resolution below which a difference means nothing (one pixel for a
pixel fraction). Which effect a statistic points to is declared by the effects themselves
(``rawaug.loop.registry``); statistics of the base model (read noise, row noise) point
to a refit, not to a new effect. ``frame_statistics`` computes every statistic but
``defect_lines`` on the frames with their defect lines repaired (``repaired``): a stuck
column is one defect, not also hot pixels, heavy tails and low-frequency power.
"""
from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import fft as sp_fft  # pocketfft with SIMD: ~2x NumPy's on a stack's frames
from scipy import ndimage
from scipy import stats as sstats

from .code_histogram import code_histogram
from .engine.layout import COLUMN_SET, READ_MAP_BLOCKS, ROW_SET, TAP_EDGES, XTALK_LAGS
from .selection import middle_pair

MAD_TO_SIGMA = 1.482602218505602
_LOW_BAND = 16  # low-frequency band: the lowest 1/16 of the frequencies


def _power(spectrum):
    """|X|^2 of a complex spectrum, without the square root of ``np.abs``."""
    return spectrum.real**2 + spectrum.imag**2


def _centered(frames):
    return frames - frames.mean(axis=(2, 3), keepdims=True)


_last_moments = threading.local()  # the last read-only stack's channel moments on this thread


def channel_moments(frames):
    """(mean, variance (ddof 0)) of each frame's channels, (N, 4) each, DN and DN^2: from the
    sums of the values and of their squares (no centred copy of the stack). Computed once
    for the same read-only array in a row (the battery's views)."""
    def compute():
        n = frames.shape[2] * frames.shape[3]
        mean = frames.sum(axis=(2, 3)) / n
        return mean, np.maximum(np.einsum("ijkl,ijkl->ij", frames, frames) / n - mean**2, 0.0)

    return _once(_last_moments, frames, compute)


def _once(store, frames, compute):
    """``compute()`` of ``frames``, kept in the thread-local ``store`` for the same read-only
    array (the battery's views): the next statistic of that stack reads it again."""
    if getattr(store, "source", None) is frames:
        return store.result
    result = compute()
    if isinstance(frames, np.ndarray) and not frames.flags.writeable:
        store.source, store.result = frames, result
    return result


PARTITION_MIN = 64  # median: a selection along an axis this long or longer, a sort along a shorter one


def median(x, axis=None, keepdims: bool = False):
    """``np.median``'s values (NaN: NumPy's own): along a long axis of finite floats, the two
    middle values by a histogram selection (``selection.middle_pair``: 3-5x faster than
    NumPy's partition over a frame's pixels); of other values, a partition at the upper
    middle value and the largest below it; along a short axis, NumPy's vectorized sort (2x
    faster than a selection over a stack's N frames)."""
    x = np.asarray(x)
    finite = bool(np.isfinite(x).all())
    if not finite and np.isnan(x).any():  # a sort puts NaN last; np.median returns NaN
        return np.median(x, axis=axis, keepdims=keepdims)
    v = x.ravel() if axis is None else np.moveaxis(x, axis, -1)
    n = v.shape[-1]
    if n >= PARTITION_MIN and finite and v.dtype in (np.float32, np.float64):  # both middle values, one histogram selection
        lower, upper = middle_pair(v.reshape(-1, n), n // 2 - 1)
        out = (0.5 * (lower + upper) if n % 2 == 0 else 0.5 * (upper + upper)).reshape(v.shape[:-1])[()]
    elif n >= PARTITION_MIN:  # one selection: the lower middle value is the largest below the upper one
        v = np.partition(v, n // 2, axis=-1)
        upper = v[..., n // 2]
        out = 0.5 * (v[..., : n // 2].max(axis=-1) + upper) if n % 2 == 0 else 0.5 * (upper + upper)
    else:
        v = np.sort(v, axis=-1)
        out = 0.5 * (v[..., (n - 1) // 2] + v[..., n // 2])
    if keepdims:
        out = np.expand_dims(out, tuple(range(x.ndim)) if axis is None else axis)
    return out


def robust_scale(x, axis):
    """1.4826 MAD along ``axis`` (falls back to the std where the MAD is 0: coarse codes)."""
    med = median(x, axis=axis, keepdims=True)
    mad = MAD_TO_SIGMA * median(np.abs(x - med), axis=axis, keepdims=True)
    if np.all(mad > 0):
        return med, mad + 1e-12
    return med, np.where(mad > 0, mad, x.std(axis=axis, keepdims=True)) + 1e-12


def _rms(values):
    return float(np.sqrt(np.mean(np.square(values))))


_last_temporal = threading.local()  # the last read-only stack's temporal moments on this thread


def temporal_moments(frames):
    """(mean map, temporal variance map (ddof 1; 0 for one frame)), (4, h, w) each, of a stack
    (N, 4, h, w), DN and DN^2. Computed once for the same read-only array in a row (the
    battery's views): the mean map and the per-pixel variance serve several statistics."""
    def compute():
        n = frames.shape[0]
        mean = frames.sum(axis=0) / n
        if n > 1:  # one centred copy, its squares summed without another (einsum: ~2.5x np.var)
            d = frames - mean
            var = np.einsum("i...,i...->...", d, d) / (n - 1)
        else:
            var = np.zeros_like(mean)
        mean.flags.writeable = var.flags.writeable = False  # shared: no statistic may change them
        return mean, var

    return _once(_last_temporal, frames, compute)


_last_range = threading.local()  # the last read-only stack's temporal range on this thread


def temporal_range(frames):
    """(lowest, highest) value of each pixel over a stack (N, 4, h, w), (4, h, w) each, DN.
    Computed once for the same read-only array in a row: dead pixels, impulses and outliers
    are all found from it."""
    def compute():
        lo, hi = frames.min(axis=0), frames.max(axis=0)
        lo.flags.writeable = hi.flags.writeable = False
        return lo, hi

    return _once(_last_range, frames, compute)


# ----------------------------------------------------------------- single-frame statistics
def pixel_std(frames, level_dn=None):
    """Std of the pixels about their frame-channel mean (DN)."""
    return float(np.sqrt(channel_moments(frames)[1].mean()))


def line_mean_variance(c, axis):
    """Variance across lines of the line means (lines run along ``axis`` of a (..., h, w)
    array), from first differences of neighbouring lines: robust (1.4826 MAD)^2 / 2. Smooth
    shading does not count; offsets that differ line to line do; a few defect lines (a
    stuck column, a dead row) do not: they are outliers, not line noise (``difference_scale``).
    Shape (...)."""
    return difference_scale(np.diff(c.mean(axis=axis), axis=-1)) ** 2 / 2.0


def line_rel_parts(frames, level_dn, rows: bool) -> tuple[float, float]:
    """(per-frame, stack-mean) variance of a flat stack's (N, 4, h, w; DN) sensor-row (``rows``)
    or sensor-column means relative to each channel's level ``level_dn``, mean over the channels
    (``line_mean_variance``, neighbouring lines): the squared relative line gains, plus what
    pixels and temporal noise leave in a line mean (per-frame 0 for one frame)."""
    f = np.asarray(frames, dtype=np.float64)
    n = f.shape[0]
    level2 = np.maximum(np.broadcast_to(np.asarray(level_dn, dtype=np.float64), (4,)), 1e-12) ** 2
    mean_map = f.mean(axis=0)
    fixed = float(np.mean(line_mean_variance(mean_map, 2 if rows else 1) / level2))
    if n < 2:
        return 0.0, fixed
    frame = float(np.mean(line_mean_variance(f - mean_map[None], 3 if rows else 2).mean(axis=0) / level2)) * n / (n - 1)
    return frame, fixed


def difference_scale(d):
    """1.4826 MAD along the last axis of differences of neighbouring lines' means, about
    their mean (the end lines' difference over the span: no inner defect line moves it), not
    their median, which a pattern alternating from line to line puts on one of its two modes,
    at random; the rms where the MAD is 0 (coarse codes). Shape (...)."""
    dev = np.abs(d - d.mean(axis=-1, keepdims=True))
    mad = MAD_TO_SIGMA * median(dev, axis=-1)
    return np.where(mad > 0, mad, np.sqrt(np.mean(dev * dev, axis=-1)))


def _profile_excess(frames, axis):
    """Line-mean variance (``line_mean_variance``) times the line length, over the pixel
    variance, per frame and channel (mean over them): 1 for independent pixels, above 1
    when whole lines share an offset. Insensitive to per-pixel noise of any size and to
    smooth shading."""
    n = frames.shape[axis]
    line_var = line_mean_variance(frames, axis) * n  # differences of line means: no offset counts
    return float((line_var / (channel_moments(frames)[1] + 1e-30)).mean())


def row_excess(frames, level_dn=None):
    """Row-mean variance x row length / pixel variance: row (banding) noise."""
    return _profile_excess(frames, 3)


def col_excess(frames, level_dn=None):
    """Column-mean variance x column length / pixel variance: column noise."""
    return _profile_excess(frames, 2)


DEFECT_Z = 8.0  # robust sigmas from its neighbours: a line this far off is a defect, not noise


def _defects(means):
    """Defect lines among line means (..., n): residuals from a running median of 5 lines
    (smooth shading does not count) beyond ``DEFECT_Z`` x the larger of 1.4826 MAD of the
    residuals and of the line-to-line differences / sqrt(2): a pattern that moves from line
    to line as much as it stands out (periodic banding) is not a set of defects.
    Returns (mask, residuals)."""
    from scipy.ndimage import median_filter

    size = [1] * (means.ndim - 1) + [5]
    resid = means - median_filter(means, size=size, mode="mirror")  # an edge line is judged by its inner neighbours
    _, scale = robust_scale(resid, axis=-1)
    step = difference_scale(np.diff(means, axis=-1))[..., None]
    return np.abs(resid) > DEFECT_Z * np.maximum(scale, step / np.sqrt(2.0)), resid


def defect_line_masks(frames):
    """(rows (N, 4, h), columns (N, 4, w)) boolean masks of the defect lines of every frame
    and channel: a stuck or dead column or row, whose mean stands out from its neighbours."""
    c = np.asarray(frames, dtype=np.float64)
    return _defects(c.mean(axis=3))[0], _defects(c.mean(axis=2))[0]


def defect_line_residuals(mean_map):
    """Of one (4, h, w) map (a stack mean): (row mask (4, h), row offsets (4, h), column
    mask (4, w), column offsets (4, w)), offsets in DN from the running median of 5 lines."""
    m = np.asarray(mean_map, dtype=np.float64)
    rows, row_res = _defects(m.mean(axis=2))
    cols, col_res = _defects(m.mean(axis=1))
    return rows, row_res, cols, col_res


_last = threading.local()  # the last repaired stack of this thread


def _nearest_good(bad) -> np.ndarray:
    """Index of the nearest line that is not ``bad`` (1-D mask), for every line."""
    good = np.flatnonzero(~bad)
    idx = np.arange(bad.size)
    if good.size == 0:
        return idx
    pos = np.clip(np.searchsorted(good, idx), 1, max(good.size - 1, 1)) if good.size > 1 else np.zeros_like(idx)
    left, right = good[np.maximum(pos - 1, 0)], good[pos]
    return np.where(np.abs(idx - left) <= np.abs(right - idx), left, right)


def without_stuck(frames):
    """The frames (N >= 2) with each dead pixel (``stuck_outliers``: stuck far from its channel's
    noise) replaced in every frame by its nearest live neighbour along the row (same channel),
    DN: what every statistic but ``stuck_fraction`` looks at, so that a dead pixel counts
    once, as a stuck pixel, and not also in line means, tails and clips (a flat pair's too:
    clusters of pixels dead at black filled 14 flat pairs' low-frequency power). One frame,
    or no dead pixel: the frames themselves."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.shape[0] < 2:
        return frames
    lo, hi = temporal_range(frames)
    if not (lo == hi).any():  # no pixel stuck at all: the common case, without the medians
        return frames
    dead = stuck_outliers(lo, hi, frames[0])
    if not dead.any():
        return frames
    c = frames.copy()
    w = frames.shape[3]
    ch, y, x = np.nonzero(dead)
    src = x.copy()
    for d in range(1, w):  # nearest live pixel, left first
        todo = src == x
        if not todo.any():
            break
        for cand in (x - d, x + d):
            ok = todo & (cand >= 0) & (cand < w)
            ok[ok] = ~dead[ch[ok], y[ok], cand[ok]]
            src = np.where(ok & (src == x), cand, src)
    c[:, ch, y, x] = frames[:, ch, y, src]
    return c


def without_impulses(frames):
    """The frames (N >= 3) with each impulse (``spike_outliers``: a bright single-frame event
    beyond the read noise's own tail, as a cosmic ray makes, or a dark one) replaced by its pixel's median
    over the stack (the lower middle value of an even stack: one the pixel read), DN: an impulse is counted once, as an impulse, and not also as a defect
    line, a flickering line, a hot pixel or a heavy tail. Fewer frames, or no significant
    excess of bright events: the frames themselves."""
    f = np.asarray(frames, dtype=np.float64)
    if f.shape[0] < 3:
        return f
    hit = spike_outliers(f)
    if not hit.any():
        return f
    c = f.copy()
    n, ch, y, x = np.nonzero(hit)
    # the lower of the two middle values (an even stack's median is their mean, a half code): a
    # value the pixel read, so that whole codes stay whole (``code_dnl``, ``missing_codes``)
    c[n, ch, y, x] = np.partition(f[:, ch, y, x], (f.shape[0] - 1) // 2, axis=0)[(f.shape[0] - 1) // 2]
    return c


def without_outliers(frames):
    """The frames with their dead pixels (``without_stuck``) and impulses (``without_impulses``)
    replaced, DN: what line statistics and the line estimators read."""
    return without_impulses(without_stuck(frames))


def repaired(frames):
    """The frames with their dead pixels and impulses replaced (``without_outliers``), then
    every defect line (``defect_line_masks``) replaced by its nearest normal line of the same
    frame and channel, DN: what every statistic but ``defect_lines``, ``stuck_fraction`` and the
    impulse statistics (``with_impulses``) and the shading estimators look at, so that a stuck
    column is counted once, as a defect, and not also as hot pixels, heavy tails, pixel noise
    or low-frequency power. Read-only; computed once for the same array in a row."""
    return _repaired_views(frames)[0]


def with_impulses(frames):
    """``repaired`` with the impulses left in (defect lines found without them), DN: what the
    impulse statistics (``spike_fraction``, ``tail_mass``) read. Read-only; computed once for
    the same array in a row."""
    return _repaired_views(frames)[1]


def _repaired_views(frames):
    """(repaired, with_impulses, without_outliers) of a stack, computed once for the same array
    in a row: rows found and replaced first, then columns, on the frames without impulses; the
    same lines replaced in the frames with them."""
    if getattr(_last, "source", None) is frames:
        return _last.result
    kept = np.asarray(without_stuck(frames), dtype=np.float64)
    clean = without_impulses(kept)
    c = np.array(clean, dtype=np.float64)
    rows, _ = _defects(c.mean(axis=3))
    bad_rows = list(zip(*np.nonzero(rows.any(axis=2))))
    for n, ch in bad_rows:
        c[n, ch] = c[n, ch][_nearest_good(rows[n, ch])]
    cols, _ = _defects(c.mean(axis=2))
    bad_cols = list(zip(*np.nonzero(cols.any(axis=2))))
    for n, ch in bad_cols:
        c[n, ch] = c[n, ch][:, _nearest_good(cols[n, ch])]
    views = [c]
    if clean is not kept:  # the impulses left in, the same lines replaced
        d = np.array(kept, dtype=np.float64)
        for n, ch in bad_rows:
            d[n, ch] = d[n, ch][_nearest_good(rows[n, ch])]
        for n, ch in bad_cols:
            d[n, ch] = d[n, ch][:, _nearest_good(cols[n, ch])]
        views.append(d)
    for v in views:
        v.flags.writeable = False
    result = (views[0], views[-1], clean)
    _last.source, _last.result = frames, result
    return result


def defect_lines(frames, level_dn=None):
    """Fraction of rows and columns (per frame and channel) that are defect lines
    (``defect_line_masks``): stuck or dead columns and rows."""
    rows, cols = defect_line_masks(frames)
    return float((rows.sum() + cols.sum()) / (rows.size + cols.size))


def _lowfreq_ratio(profiles):
    """Mean power of the lowest 1/16 frequencies over the mean power (DC excluded) of
    1-D profiles along the last axis: 1 for white noise, large for smooth shading."""
    p = _power(sp_fft.rfft(profiles - profiles.mean(axis=-1, keepdims=True), axis=-1))
    p = p[..., 1:]
    n_low = max(1, p.shape[-1] // _LOW_BAND)
    return float(p[..., :n_low].mean() / (p.mean() + 1e-30))


def row_lowfreq(frames, level_dn=None):
    """Low-frequency power ratio of the row-mean profile (shading along columns)."""
    return _lowfreq_ratio(frames.mean(axis=3))


def col_lowfreq(frames, level_dn=None):
    """Low-frequency power ratio of the column-mean profile (shading along rows)."""
    return _lowfreq_ratio(frames.mean(axis=2))


def psd2d_lowfreq(frames, level_dn=None):
    """2-D power spectrum: mean power in the low-frequency disk (radius below 1/16 of the
    Nyquist frequency, DC excluded) over the mean power of all non-DC frequencies."""
    c = frames.astype(np.float32) - channel_moments(frames)[0][:, :, None, None].astype(np.float32)
    p = _power(sp_fft.rfft2(c, axes=(2, 3)))  # single precision: 2x faster, 1e-6 of the ratio
    fy = np.fft.fftfreq(c.shape[2])[:, None]
    fx = np.fft.rfftfreq(c.shape[3])[None, :]
    radius = np.sqrt(fy**2 + fx**2) / 0.5
    low = (radius > 0) & (radius <= 1.0 / _LOW_BAND + 1e-12)
    if not low.any():
        return 1.0
    return float(p[..., low].mean() / (p[..., radius > 0].mean() + 1e-30))


def grid_step(frames) -> float:
    """The grid of whole-code frames (1 DN), 0 for any other values."""
    return 1.0 if np.all(frames == np.rint(frames)) else 0.0


MAX_CELLS = 1 << 22  # a wider range of grid cells is read as continuous values


def cell_cdf(values, step: float):
    """(knots, cdf) of 1-D ``values`` on a grid of ``step``, each value spread evenly over its
    cell, piecewise linear: the values plus a uniform dither of one cell. A code next to
    missing ones (a gap ``written_codes`` counts: ``comb_gaps``) stands for the inputs the ADC writes it for: its cell reaches
    halfway to the next written code. None off the grid or over ``MAX_CELLS`` cells."""
    idx = np.rint(np.asarray(values, dtype=np.float64) / step)
    if not np.all(np.abs(idx * step - values) <= 1e-6 * step):
        return None
    lo, hi = idx.min(), idx.max()
    if hi - lo >= MAX_CELLS:
        return None
    counts = np.bincount((idx - lo).astype(np.int64))
    occupied = np.flatnonzero(counts)
    c = counts[occupied]
    gaps = np.diff(occupied)
    half = np.where(comb_gaps(occupied, c), gaps / 2.0, 0.5)
    left, right = occupied - np.r_[0.5, half], occupied + np.r_[half, 0.5]
    knots = (lo + np.stack([left, right], axis=1).ravel()) * step
    cum = np.cumsum(c)
    return knots, np.stack([cum - c, cum], axis=1).ravel() / idx.size


def cell_median_scale(knots, cdf):
    """Median and 1.4826 MAD of a piecewise-linear cdf (``cell_cdf``): smooth in the counts,
    where a sample MAD of whole codes moves in steps of half a code."""
    med = float(np.interp(0.5, cdf, knots))
    d = np.unique(np.abs(knots - med))
    inside = np.interp(med + d, knots, cdf) - np.interp(med - d, knots, cdf)
    return med, MAD_TO_SIGMA * float(np.interp(0.5, inside, d)) + 1e-12


def center_scale(values, step: float) -> tuple[float, float]:
    """(median, robust sigma) of 1-D ``values`` as ``outside_fraction`` reads them: of the
    values spread over their cells on a grid of ``step`` (``cell_median_scale``), else the
    sample's (1.4826 MAD)."""
    grid = cell_cdf(values, step) if step > 0 else None
    if grid is None:
        med, scale = robust_scale(values, axis=0)
        return float(med[0]), float(scale[0])
    return cell_median_scale(*grid)


def outside_fraction(values, step: float, z: float, upper_only: bool = False) -> float:
    """Fraction of ``values`` (1-D) beyond ``z`` robust sigmas of their median (above it
    only, with ``upper_only``). On a grid of ``step`` (whole codes, or means of N of them)
    the values count spread over their cells, and median and scale are those of that
    spread (``cell_median_scale``): a sample MAD of whole codes jumps by half a code, which
    at 1 DN of noise moves a 5-sigma threshold by 2.5 sigma, so two stacks of the same noise
    would count different tails. Elsewhere: 1.4826 MAD of the sample."""
    grid = cell_cdf(values, step) if step > 0 else None
    if grid is None:
        med, scale = robust_scale(values, axis=0)
        z_values = (values - med) / scale
        return float(((z_values > z) if upper_only else (np.abs(z_values) > z)).mean())
    knots, cdf = grid
    med, scale = cell_median_scale(knots, cdf)
    above = 1.0 - float(np.interp(med + z * scale, knots, cdf))
    return above if upper_only else above + float(np.interp(med - z * scale, knots, cdf))


def tail_mass(frames, level_dn=None):
    """Fraction of pixels beyond 5 robust sigma from their frame-channel median (whole codes
    spread over their cells: ``outside_fraction``); the mean over frames and channels."""
    step = grid_step(frames)
    rows = frames.reshape(-1, frames.shape[2] * frames.shape[3])
    return float(np.mean([outside_fraction(r, step, 5.0) for r in rows]))


def hot_fraction(frames, level_dn=None):
    """Fraction of pixels whose stack mean lies 8 robust sigma above the channel median
    (hot or stuck-high pixels; the mean of N whole codes on its grid of 1/N,
    ``outside_fraction``). With one frame, the frame itself."""
    step = grid_step(frames) / frames.shape[0]
    mean_map = temporal_moments(frames)[0].reshape(4, -1)
    return float(np.mean([outside_fraction(r, step, 8.0, upper_only=True) for r in mean_map]))


def ppcc_r2(frames, level_dn=None):
    """Normal probability-plot R^2 of the first frame's centered pixels (every channel,
    at most 20000 evenly strided values): below 1 for heavy tails or coarse codes."""
    x = _centered(frames[:1]).ravel()
    x = np.sort(x[:: max(1, x.size // 20000)])
    (_, _), (_, _, r) = sstats.probplot(x, dist="norm")
    return float(r**2)


MIN_COUNT = 10  # pixels on each side of a gap: P(no pixel at a code expecting 10) = 4.5e-5
MAX_GAP = 7  # longest run of missing codes (digital gain up to 8); a longer empty run separates populations
MAX_COMB_GAP = 63  # ... unless it repeats as a comb: equal runs at equal spacing (a stuck ADC bit, a digital gain up to 64)
COMB_REPEATS = 3  # runs a comb of long gaps needs


def comb_gaps(occupied, counts) -> np.ndarray:
    """Per gap between consecutive ``occupied`` codes (their ``counts``): True where its empty
    codes are missing ones, i.e. codes the camera does not write: both bounding codes hold >=
    ``MIN_COUNT`` pixels and the gap is at most ``MAX_GAP`` codes long, or at most
    ``MAX_COMB_GAP`` long and one of ``COMB_REPEATS`` or more gaps of its length at equal
    spacing (a comb; one long empty run is two populations, a stuck column above the noise)."""
    occupied, counts = np.asarray(occupied), np.asarray(counts)
    gaps = np.diff(occupied)
    bounded = np.minimum(counts[:-1], counts[1:]) >= MIN_COUNT
    out = (gaps > 1) & (gaps <= MAX_GAP + 1) & bounded
    long = np.flatnonzero((gaps > MAX_GAP + 1) & (gaps <= MAX_COMB_GAP + 1) & bounded)
    for length in np.unique(gaps[long]):
        at = long[gaps[long] == length]
        if at.size < COMB_REPEATS:
            continue
        steps = np.diff(occupied[at])
        run = 0
        for i in range(steps.size):  # runs of equal spacing, COMB_REPEATS gaps or more
            run = run + 1 if i > 0 and steps[i] == steps[i - 1] else 1
            if run >= COMB_REPEATS - 1:
                out[at[i - run + 1 : i + 2]] = True
    return out


def written_codes(values: np.ndarray) -> np.ndarray:
    """Boolean mask over ``[min, max]`` of whole-DN ``values``: the codes the camera writes,
    i.e. all but those in a gap of missing codes (``comb_gaps``). In a sparse tail an empty code is chance, and a
    long empty run separates two populations (a stuck column far above the noise): neither
    is a missing code."""
    v = np.asarray(values).astype(np.int64).ravel()
    return _written(np.bincount(v - v.min()))


def _written(counts):
    """``written_codes`` from the counts of the codes from the lowest up."""
    occupied = np.flatnonzero(counts)
    written = np.ones(counts.size, dtype=bool)
    missing = comb_gaps(occupied, counts[occupied])
    for a, b in zip(occupied[:-1][missing], occupied[1:][missing]):
        written[a + 1 : b] = False
    return written


def code_percentiles(counts, q):
    """``np.percentile`` (linear) of whole codes given as their counts from the lowest up: the
    percentiles' offsets from the lowest code."""
    cum = np.cumsum(counts)
    pos = np.asarray(q, dtype=np.float64) / 100.0 * (cum[-1] - 1)
    below = np.floor(pos)
    a = np.searchsorted(cum, below, side="right")  # the code of sorted value i: the first whose cumulative count exceeds i
    b = np.searchsorted(cum, np.minimum(below + 1, cum[-1] - 1), side="right")
    return a + (pos - below) * (b - a)


def missing_codes(frames, level_dn=None):
    """Histogram comb: fraction of integer codes between the 0.5 and 99.5 percentiles that
    are missing (values rounded to whole DN; ``written_codes``: an empty code in a gap
    between populated codes, not one in a sparse tail)."""
    counts = _codes(frames)[1]
    lo, hi = code_percentiles(counts, (0.5, 99.5))
    if hi - lo < 3:
        return 0.0
    written = _written(counts)
    start = int(lo)
    return float((~written[start : start + int(hi - lo) + 1]).mean())


DNL_MIN_COUNT = 100  # pixels a code must hold to weigh its width (a relative spread of 10 %)
DNL_WINDOW = 7  # codes of the local quartic a code's log count is compared with (a heavy tail's shape is smooth on it)
DNL_MIN_CODES = 9  # codes a histogram must span for a width to stand out of its neighbours

DNL_MAX_VALUES = 1 << 22  # values a code histogram reads, evenly strided (8 frames of 12 MP: 7.9 s -> 0.46 s)


def code_counts(frames):
    """(codes, counts) of the whole-DN values of a stack (at most ``DNL_MAX_VALUES``, evenly
    strided), from its lowest code up; None when the values are not whole numbers (not a raw
    file's codes)."""
    v = np.asarray(frames)
    stride = max(1, v.size // DNL_MAX_VALUES)
    lowest, counts, whole = _codes(v) if stride == 1 else code_histogram(v.ravel()[::stride])
    return (lowest + np.arange(counts.size), counts) if whole else None


_last_codes = threading.local()  # the last read-only stack's code histogram on this thread


def _codes(frames):
    """``code_histogram`` of a stack, once for the same read-only array in a row."""
    return _once(_last_codes, frames, lambda: code_histogram(frames))


def well_filled(counts) -> slice | None:
    """The longest run of consecutive codes that hold >= ``DNL_MIN_COUNT`` pixels each (the
    lowest and highest code left out: a clip piles up there); None when shorter than
    ``DNL_MIN_CODES``."""
    keep = counts >= DNL_MIN_COUNT
    keep[[0, -1]] = False
    edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(np.int8), [0]])))
    if edges.size == 0:
        return None
    starts, stops = edges[::2], edges[1::2]
    i = int(np.argmax(stops - starts))
    return slice(int(starts[i]), int(stops[i])) if stops[i] - starts[i] >= DNL_MIN_CODES else None


def code_log_residuals(codes, counts):
    """(codes, residuals, counts) over the well-filled codes (``well_filled``): each log count
    less a local quartic over ``DNL_WINDOW`` codes (Savitzky-Golay), i.e. each code's log
    width relative to its neighbours', with variance about 1 / count. None when too few."""
    from scipy.signal import savgol_filter

    run = well_filled(counts)
    if run is None:
        return None
    n = counts[run].astype(np.float64)
    log_n = np.log(n)
    return codes[run], log_n - savgol_filter(log_n, DNL_WINDOW, 4), n


def code_dnl(frames, level_dn=None):
    """ADC differential non-linearity: the mean over the well-filled codes of count x
    squared log-width residual (``code_log_residuals``): below 1 when every code is equally
    wide (Poisson counts, less what the local quartic takes), far more when some codes take
    more of the input than others. 0 for values that are not whole codes or a histogram too
    narrow to tell."""
    cc = code_counts(frames)
    r = None if cc is None else code_log_residuals(*cc)
    if r is None:
        return 0.0
    _, resid, n = r
    return float(np.mean(n * resid**2))


def clip_low(frames, level_dn=None):
    """Pile-up at the lowest code: fraction of pixels at the stack minimum (whole DN)."""
    counts = _codes(frames)[1]
    return float(counts[0] / counts.sum())


def mean_dn(frames, level_dn=None):
    """Mean of all pixels (DN): the black-level error of a bias stack."""
    return float(frames.mean())


# ----------------------------------------------------------------- stack statistics
def temporal_std(frames, level_dn=None):
    """Per-pixel std across the stack (DN, rms over pixels)."""
    return float(np.sqrt(temporal_moments(frames)[1].mean()))


QUIET = 1.0 / 16.0  # a quiet pixel's temporal variance, at most this share of the stack's median


def quiet_pixels(frames) -> np.ndarray:
    """(4, h, w) mask of a stack's pixels (N >= 2; DN) whose temporal variance is below ``QUIET``
    of the stack's median: pixels that hold their value while the others carry the noise."""
    var = temporal_moments(frames)[1]
    return var < QUIET * float(np.median(var))


QUIET_TRIM = 0.995  # the quiet weights' scale: the mean temporal variance of the pixels below this quantile of it


def quiet_fraction(frames, level_dn=None):
    """Share of a flat stack's pixels that hold their value from frame to frame while the
    others carry the shot noise (pixels saturated at their full well), smooth: the mean over
    the pixels of exp(-v / (``QUIET`` x m)), v a pixel's temporal variance and m the mean of
    those below their ``QUIET_TRIM`` quantile. A held pixel weighs 1, a pair of Gaussian values
    0.17 on average, at any scale. (Since the thirty-first session; before, the share below
    ``QUIET`` of the median, which jumps with the codes' discreteness: 0.116 to 0.141 for pairs
    of rounded normals of std 10 to 24, against a spread of 0.0007 over a model's syntheses.)"""
    if np.asarray(frames).shape[0] < 2:
        return 0.0
    var = temporal_moments(frames)[1]
    scale = float(np.mean(var[var <= np.quantile(var, QUIET_TRIM)]))
    return float(np.mean(np.exp(-var / max(QUIET * scale, 1e-12))))


MASK_LEVEL = 0.1  # a line of a flat without light: its mean at most this share of the median line's


def _edge_run(v) -> int:
    """Lines from the start of ``v`` (line means) below ``MASK_LEVEL`` of their median, in a
    row; at most a quarter of the lines."""
    dark = np.asarray(v) < MASK_LEVEL * float(np.median(v))
    n = int(np.argmin(dark)) if not dark.all() else len(v)
    return min(n, len(v) // 4)


def masked_edges(mean_dn) -> tuple[int, int, int, int]:
    """(top, bottom, left, right): the sensor lines at each edge of a flat's mean frame (4, h, w;
    DN above black) that hold no light, optically black lines left in the raw: the runs from
    each edge of sensor rows (columns) whose mean is below ``MASK_LEVEL`` of the median line's."""
    m = np.asarray(mean_dn, dtype=np.float64)
    _, h, w = m.shape
    rows, cols = np.empty(2 * h), np.empty(2 * w)
    for line_set in (0, 1):
        rows[line_set::2] = m[[c for c in range(4) if ROW_SET[c] == line_set]].mean(axis=(0, 2))
        cols[line_set::2] = m[[c for c in range(4) if COLUMN_SET[c] == line_set]].mean(axis=(0, 1))
    if not np.median(rows) > 0:
        return 0, 0, 0, 0
    return _edge_run(rows), _edge_run(rows[::-1]), _edge_run(cols), _edge_run(cols[::-1])


def lit_pixels(mean_dn) -> np.ndarray:
    """(4, h, w) mask of a flat's pixels outside its lines without light (``masked_edges``)."""
    m = np.asarray(mean_dn, dtype=np.float64)
    _, h, w = m.shape
    top, bottom, left, right = masked_edges(m)
    sy = 2 * np.arange(h)[None, :, None] + np.array(ROW_SET)[:, None, None]
    sx = 2 * np.arange(w)[None, None, :] + np.array(COLUMN_SET)[:, None, None]
    return (sy >= top) & (sy < 2 * h - bottom) & (sx >= left) & (sx < 2 * w - right)


def masked_lines(frames, level_dn=None):
    """Share of a flat stack's sensor lines at the frame's edges that hold no light
    (``masked_edges`` of its mean): rows over the rows plus columns over the columns; 0 for a
    sensor lit to its edges."""
    f = np.asarray(frames, dtype=np.float64)
    top, bottom, left, right = masked_edges(f.mean(axis=0))
    return (top + bottom) / (2.0 * f.shape[2]) + (left + right) / (2.0 * f.shape[3])


def _mean_map(frames):
    m = temporal_moments(frames)[0]
    return m - m.mean(axis=(1, 2), keepdims=True)


def fixed_std(frames, level_dn=None):
    """Robust std (1.4826 MAD) over pixels of the stack-mean map, per channel (DN): white
    fixed pattern plus temporal noise / sqrt(N); a few hot pixels do not move it."""
    m = _mean_map(frames).reshape(4, -1)
    _, scale = robust_scale(m, axis=1)
    return _rms(scale)


def _double_difference(x):
    """2x2 double differences of a packed channel's neighbours: a pattern constant along a
    row or a column, and smooth shading, cancel; a white pattern of variance v gives 4 v."""
    dx = x[..., 1:] - x[..., :-1]
    return dx[..., 1:, :] - dx[..., :-1, :]


OUTLIER_SIGMAS = 6.0  # a double difference this many robust sigmas out is a defect or an impulse


def fixed_pixel_var(frames, level_dn=None):
    """Variance of the pixel-to-pixel fixed pattern, DN^2 (DSNU of offsets and dark current):
    the stack-mean map's spread less what temporal noise leaves in a mean of N frames,

        (mean d(m)^2 - sum_i mean d(x_i - m)^2 / (N (N - 1))) / 4,

    with ``d`` the 2x2 double difference (row and column patterns, row noise and shading
    cancel). A cell beyond ``OUTLIER_SIGMAS`` robust sigmas in the mean map or in any frame
    (hot pixels, impulses, telegraph jumps) counts in neither term: unbiased for Gaussian
    temporal noise, +0.14 % of its variance for a heavy tail (Student t, 3 dof). Mean over
    channels; 0 for a model without a fixed pattern."""
    n = frames.shape[0]
    mean = temporal_moments(frames)[0]
    a = _double_difference(mean)  # (4, h-1, w-1)
    t = _double_difference(frames) - a  # (N, 4, h-1, w-1): the double differences of frames - mean
    ca, sa = robust_scale(a.reshape(4, -1), axis=1)
    # the temporal scale from every other cell along both axes: a quarter of the sort, a 6-sigma
    # threshold within 1 % of the full sample's
    sub = t[:, :, ::2, ::2]
    ct, st = robust_scale(sub.transpose(1, 0, 2, 3).reshape(4, -1), axis=1)
    ct, st = ct[:, :, None], st[:, :, None]
    keep = np.abs(a - ca[:, :, None]) <= OUTLIER_SIGMAS * sa[:, :, None]
    keep &= (t.max(axis=0) - ct <= OUTLIER_SIGMAS * st) & (ct - t.min(axis=0) <= OUTLIER_SIGMAS * st)
    count = np.maximum(keep.sum(axis=(1, 2)), 1)
    fixed = np.einsum("ijk,ijk->i", np.where(keep, a, 0.0), a) / count
    temporal = np.einsum("ijk,ijk->i", keep, np.einsum("nijk,nijk->ijk", t, t)) / count / (n * (n - 1))
    return float(np.mean(fixed - temporal) / 4.0)


def fixed_col_excess(frames, level_dn=None):
    """``col_excess`` of the stack-mean map: a fixed column pattern."""
    return _profile_excess(_mean_map(frames)[None], 2)


def fixed_row_excess(frames, level_dn=None):
    """``row_excess`` of the stack-mean map: a fixed row pattern."""
    return _profile_excess(_mean_map(frames)[None], 3)


def frame_means(frames):
    """(N, 4) per-frame, per-channel means (DN)."""
    return frames.mean(axis=(2, 3))


def frame_mean_std(frames, level_dn=None):
    """Std across frames of the frame-channel means (DN, rms over channels)."""
    return _rms(frame_means(frames).std(axis=0, ddof=1))


def frame_mean_common_cov(frames, level_dn=None):
    """Covariance across frames of the means of channel pairs that share neither a sensor
    row nor a sensor column ((R, B) and (G1, G2)), DN^2: common-mode offsets only."""
    m = frame_means(frames)
    c = np.cov(m.T)
    return float((c[0, 2] + c[1, 3]) / 2.0)


def frame_mean_lag1(frames, level_dn=None):
    """Lag-1 autocorrelation of the frame means (mean over the channels) about the stack's, in
    the order the frames were taken: about -1/N for offsets new in every frame, towards 1 for
    a level that drifts from frame to frame."""
    m = frame_means(frames).mean(axis=1)
    c = m - m.mean()
    return float(np.sum(c[1:] * c[:-1]) / max(float(np.sum(c * c)), 1e-300))


HIGH_PASS = 7  # packed pixels: the local mean taken out before lag correlations (smooth fields do not count)
# raw lags of the correlation curve: a half plane of radius 2 (every lag XTALK_LAGS holds among them)
CURVE_LAGS = tuple((dy, dx) for dy in range(3) for dx in range(-2, 3) if dy > 0 or dx > 0)


_last_highpass = threading.local()  # the last read-only stack high-passed on this thread


def highpass_gain(h: int, w: int) -> float:
    """Fraction of a white noise's variance that ``temporal_highpass`` keeps on h x w channels
    (its row means, column means and local means taken out), to first order."""
    return (1.0 - 1.0 / h) * (1.0 - 1.0 / w) * (1.0 - 1.0 / HIGH_PASS**2)


@functools.lru_cache(maxsize=32)
def _axis_diagonals(n: int, lags: tuple) -> np.ndarray:
    """(4, len(lags)) sums of the lag-th diagonals of the four n x n matrices whose Kronecker
    products make ``temporal_highpass``'s covariance of white noise along one axis: C, C U^T,
    U C and U C U^T (C the centring, U the HIGH_PASS box mean with reflected ends; U keeps
    constants, so U C = U - J / n)."""
    u = ndimage.uniform_filter1d(np.eye(n), HIGH_PASS, axis=0, mode="reflect")  # u[i, k]: weight of x_k in the mean at i
    out = np.zeros((4, len(lags)))
    for j, a in enumerate(lags):
        a = abs(int(a))  # every matrix here is symmetric or transposed into its pair at -a: the sums agree
        ones = (n - a) / n  # the lag-th diagonal of J / n
        if a >= n:
            continue
        out[0, j] = (n if a == 0 else 0.0) - ones
        out[1, j] = out[2, j] = float(np.trace(u, offset=a)) - ones
        out[3, j] = float(np.sum(u[: n - a] * u[a:])) - ones
    return out


@functools.lru_cache(maxsize=32)
def highpass_lag_correlations(h: int, w: int, lags: tuple = XTALK_LAGS) -> np.ndarray:
    """(len(lags),) correlation that ``temporal_mosaic`` gives white noise at each raw lag
    (dy, dx) on h x w channels, exactly: 0 between two channels (each is filtered alone), and
    about -1 / HIGH_PASS^2 at one channel's neighbours (each pixel and its neighbour share
    most of their local mean). What a lag's correlation is measured against."""
    packed = [(dy // 2, dx // 2) for dy, dx in lags]
    rows, cols = _axis_diagonals(h, tuple(a for a, _ in packed) + (0,)), _axis_diagonals(w, tuple(b for _, b in packed) + (0,))
    sign = np.array([1.0, -1.0, -1.0, 1.0])

    def lag_sum(i):  # sum over every pixel pair at packed lag i of their covariance
        return float(np.sum(sign * rows[:, i] * cols[:, i]))

    var = lag_sum(len(lags)) / (h * w)
    out = np.zeros(len(lags))
    for i, ((dy, dx), (a, b)) in enumerate(zip(lags, packed)):
        if dy % 2 == 0 and dx % 2 == 0 and abs(a) < h and abs(b) < w:
            out[i] = lag_sum(i) / ((h - abs(a)) * (w - abs(b))) / var
    out.flags.writeable = False
    return out


def temporal_highpass(frames):
    """The temporal residual of a stack (N >= 2, 4, h, w), DN: each frame minus the stack mean
    (scaled by sqrt(N / (N - 1)), so its variances are the frames'), less each channel's row
    and column means (row and column noise) and its local mean over HIGH_PASS x HIGH_PASS
    packed pixels (smooth fields). White noise keeps ``highpass_gain(h, w)`` of its variance.
    Computed once for the same read-only array in a row (the battery's repaired view)."""
    cached = getattr(_last_highpass, "source", None) is frames
    if cached:
        return _last_highpass.result
    n = frames.shape[0]
    r = frames - frames.mean(axis=0, keepdims=True)
    r *= np.sqrt(n / (n - 1))
    r -= r.mean(axis=3, keepdims=True)
    r -= r.mean(axis=2, keepdims=True)
    r -= ndimage.uniform_filter(r, size=(1, 1, HIGH_PASS, HIGH_PASS), mode="reflect")
    if isinstance(frames, np.ndarray) and not frames.flags.writeable:  # the battery's repaired view: reused
        r.flags.writeable = False
        _last_highpass.source, _last_highpass.result = frames, r
    return r


def temporal_mosaic(frames):
    """The temporal residual of a stack (N >= 2) as raw mosaics (N, 2h, 2w), DN: each frame
    minus the stack mean (scaled by sqrt(N / (N - 1)), so its covariances are the frames'),
    less each channel's row and column means (row and column noise) and its local mean over
    HIGH_PASS x HIGH_PASS packed pixels (smooth fields), the channels put back at their
    sensor positions (``rawaug.engine.layout.ROW_SET`` / ``COLUMN_SET``)."""
    n, _, h, w = frames.shape
    r = temporal_highpass(frames)
    raw = np.empty((n, 2 * h, 2 * w))
    for c in range(4):
        raw[:, ROW_SET[c]::2, COLUMN_SET[c]::2] = r[:, c]
    return raw


TILE_LAGS = XTALK_LAGS[:4]  # raw lags at which two pixels may lie in one 2x2 (Bayer) tile: (0,1), (1,0), (1,1), (1,-1)


def lag_pairs(raw, dy, dx):
    """(products of the raw-mosaic pairs (dy, dx) apart, (N, hh - dy, ww - |dx|); mask of the
    pairs whose two pixels lie in one 2x2 tile)."""
    _, hh, ww = raw.shape
    a = raw[:, : hh - dy, max(0, -dx) : ww - max(0, dx)]
    b = raw[:, dy:, max(0, dx) : ww - max(0, -dx)]
    y = np.arange(hh - dy)[:, None]
    x = np.arange(max(0, -dx), ww - max(0, dx))[None, :]
    return a * b, (y // 2 == (y + dy) // 2) & (x // 2 == (x + dx) // 2)


def lag_covariances(frames, lags=XTALK_LAGS, across_tiles=False):
    """(variance, covariance at each raw lag (dy, dx)) of ``temporal_mosaic``, DN^2; with
    ``across_tiles``, of the pairs whose pixels lie in different 2x2 tiles only (what a
    shared-pixel readout does not touch)."""
    raw = temporal_mosaic(np.asarray(frames, dtype=np.float64))
    out = []
    for dy, dx in lags:
        if across_tiles:
            prod, within = lag_pairs(raw, dy, dx)
            out.append(float(np.mean(prod[:, ~within])))
        else:  # a sum of products without the product array (einsum: ~10x faster than mean(a * b))
            _, hh, ww = raw.shape
            a = raw[:, : hh - dy, max(0, -dx) : ww - max(0, dx)]
            b = raw[:, dy:, max(0, dx) : ww - max(0, -dx)]
            out.append(float(_dot(a, b)) / a.size)
    return float(_dot(raw, raw)) / raw.size, np.array(out)


def _dot(a, b) -> float:
    """Sum of the products of two (N, h, w) arrays or views of one shape."""
    return float(np.einsum("ijk,ijk->", a, b))


def tile_pair_covariances(frames):
    """(variance, covariance of the pairs in one 2x2 tile at each of TILE_LAGS, of the pairs
    in adjacent tiles at each), DN^2, of the temporal residual (each frame less the stack
    mean; flickering pixels, ``flickering``, left out)."""
    frames = np.asarray(frames, dtype=np.float64)
    n, _, h, w = frames.shape
    r = (frames - frames.mean(axis=0, keepdims=True)) * np.sqrt(n / (n - 1))
    if n >= 3:
        r = np.where(flickering(frames)[None], 0.0, r)
    raw = np.empty((n, 2 * h, 2 * w))
    for c in range(4):
        raw[:, ROW_SET[c]::2, COLUMN_SET[c]::2] = r[:, c]
    # the pairs at each lag and the pairs (a strided view) whose pixels share a tile
    pairs = ((raw[:, :, :-1], raw[:, :, 1:], (slice(None), slice(0, None, 2))),  # (0, 1): x even
             (raw[:, :-1], raw[:, 1:], (slice(0, None, 2), slice(None))),  # (1, 0): y even
             (raw[:, :-1, :-1], raw[:, 1:, 1:], (slice(0, None, 2), slice(0, None, 2))),  # (1, 1): y, x even
             (raw[:, :-1, 1:], raw[:, 1:, :-1], (slice(0, None, 2), slice(0, None, 2))))  # (1, -1): y even, x odd
    within, across = [], []
    for a, b, (sy, sx) in pairs:
        total, size = _dot(a, b), a.size
        inner, inner_size = _dot(a[:, sy, sx], b[:, sy, sx]), a[:, sy, sx].size
        within.append(inner / inner_size)
        across.append((total - inner) / (size - inner_size))
    return _dot(raw, raw) / raw.size, np.array(within), np.array(across)


def tile_covariance_excess(frames):
    """(mean over TILE_LAGS of the covariance of raw neighbours in one 2x2 tile less that of
    neighbours in adjacent tiles, the variance), DN^2 (``tile_pair_covariances``). Row,
    column and smooth noise, crosstalk and black-level errors touch both kinds of pair alike;
    a shared-pixel readout only the first."""
    var, within, across = tile_pair_covariances(frames)
    return float(np.mean(within - across)), var


def tile_corr(frames, level_dn=None):
    """``tile_covariance_excess`` over the variance: about 0 (spread ~ 1 / sqrt(pixels)) but
    for a shared-pixel readout, the fraction of the noise a tile's pixels share."""
    d, var = tile_covariance_excess(frames)
    return d / max(var, 1e-12)


def neighbour_corr(frames, level_dn=None):
    """Rms over the raw lags of ``XTALK_LAGS`` of the correlation of the temporal residual
    (``temporal_mosaic``), each less what the high-pass gives white noise there
    (``highpass_lag_correlations``): about 1 / sqrt(pixels) for independent pixels, more where
    neighbouring pixels share noise (crosstalk, a shared readout; in flats, where shot noise
    dominates, photo charge that diffuses to the neighbours, or is left behind in transfer).
    Without the baseline, one lag's 0.02 hid under the -0.03 of the same-colour lags."""
    frames = np.asarray(frames)
    var, cov = lag_covariances(frames)
    return _rms(cov / max(var, 1e-12) - highpass_lag_correlations(*frames.shape[2:]))


def block_index(n: int, blocks: int = READ_MAP_BLOCKS) -> np.ndarray:
    """Block of each of ``n`` lines when they are cut into ``blocks`` equal runs (int, (n,))."""
    return (np.arange(n) * blocks) // n


FLICKER = 25.0  # a pixel whose temporal variance exceeds this many times the stack's median flickers (telegraph noise)


def white_variance(frames) -> tuple[np.ndarray, np.ndarray]:
    """((4, h, w) per-pixel variance of the high-passed temporal residual (``temporal_highpass``;
    DN^2), (4, h, w) mask of the pixels kept): white temporal noise only, so that a per-frame
    field of uneven amplitude (interference) does not count; pixels that flicker (variance
    beyond FLICKER x the stack's median: telegraph noise) are left out."""
    frames = np.asarray(frames, dtype=np.float64)
    var = np.mean(temporal_highpass(frames) ** 2, axis=0)
    return var, var <= FLICKER * max(float(median(var)), 1e-12)


def variance_cells(var, keep):
    """(4, B, B) mean over each cell of the kept pixels' variance (``white_variance``), the
    cells being each channel cut into B = READ_MAP_BLOCKS row and column blocks; a mean, not a
    median, so that the noise's shape (its kurtosis) does not weigh on the level."""
    _, h, w = var.shape
    b = READ_MAP_BLOCKS
    cell = (np.arange(4)[:, None, None] * b + block_index(h)[:, None]) * b + block_index(w)  # (4, h, w) cell of each pixel
    total = np.bincount(cell.ravel(), np.where(keep, var, 0.0).ravel(), minlength=4 * b * b)
    count = np.bincount(cell.ravel(), keep.ravel(), minlength=4 * b * b)
    return (total / np.maximum(count, 1.0)).reshape(4, b, b)


def variance_lines(var, keep) -> tuple[np.ndarray, np.ndarray]:
    """((h,), (w,)) mean over each packed row and each packed column (every channel) of the
    kept pixels' variance (``white_variance``): ``variance_cells`` line by line."""
    kept = np.where(keep, var, 0.0)
    return (kept.sum(axis=(0, 2)) / np.maximum(keep.sum(axis=(0, 2)), 1),
            kept.sum(axis=(0, 1)) / np.maximum(keep.sum(axis=(0, 1)), 1))


def temporal_variance_cells(frames):
    """(4, B, B) white temporal variance per cell of a stack (``variance_cells`` of its
    ``white_variance``), DN^2."""
    return variance_cells(*white_variance(frames))


FLICKER_P = 1e-6  # a white pixel's chance of being counted as flickering


def flicker_threshold(n: int) -> float:
    """Temporal variance (ddof 1) over the stack's median that a pixel of white noise exceeds
    with probability FLICKER_P in a stack of ``n`` frames (chi-square of n - 1 degrees)."""
    return float(sstats.chi2.isf(FLICKER_P, n - 1) / sstats.chi2.median(n - 1))


def two_levels(values):
    """(step, share of high values) of each row of ``values`` (M, N), split at the largest gap
    between its sorted values."""
    v = np.sort(values, axis=1)
    n = v.shape[1]
    cut = np.argmax(np.diff(v, axis=1), axis=1) + 1  # first index of the high group
    csum = np.cumsum(v, axis=1)
    rows = np.arange(v.shape[0])
    low = csum[rows, cut - 1] / cut
    high = (csum[:, -1] - csum[rows, cut - 1]) / (n - cut)
    return high - low, (n - cut) / n


def two_state(values, threshold):
    """Which rows of ``values`` (M, N) show two states: variance (ddof 1) over ``threshold`` and,
    with N >= 4, at least 2 values on each side of the largest gap (one extreme value of
    heavy-tailed read noise is not a state); and (step, share of high values) of those."""
    return two_state_of(values, values.var(axis=1, ddof=1) > threshold)


def two_state_of(values, high):
    """``two_state`` given the rows of high variance ``high`` (M,), a mask it does not modify."""
    seen = high.copy()
    step, share = two_levels(values[seen])
    n = values.shape[1]
    if n >= 4:
        ok = (share * n >= 2 - 1e-9) & ((1 - share) * n >= 2 - 1e-9)
        seen[np.flatnonzero(seen)[~ok]] = False
        step, share = step[ok], share[ok]
    return seen, step, share


def pixel_variances(frames):
    """Of a stack (N, 4, h, w): (temporal variance (ddof 1) of each pixel, flat over (4, h, w),
    DN^2; the median of those)."""
    frames = np.asarray(frames, dtype=np.float64)
    var = temporal_moments(frames)[1].ravel()
    return var, max(float(median(var)), 1e-12)


def trimmed_variances(values):
    """Temporal variance (ddof 1) of each row of ``values`` (M, N >= 3) without its value
    farthest from the row's mean: one extreme value of a heavy-tailed read noise (or one
    telegraph frame) does not make a pixel noisy."""
    values = np.asarray(values, dtype=np.float64)
    n = values.shape[1]
    mean = values.mean(axis=1, keepdims=True)
    lo, hi = values.min(axis=1), values.max(axis=1)
    far = np.where(hi - mean[:, 0] >= mean[:, 0] - lo, hi, lo)
    sq = np.einsum("ij,ij->i", values - mean, values - mean) - (far - mean[:, 0]) ** 2 * n / (n - 1)
    return np.maximum(sq, 0.0) / (n - 2)


def two_state_pixels(frames):
    """Of a stack (N, 4, h, w): (mask of the pixels that flicker between two states, flat over
    (4, h, w); their steps (DN); their shares of high frames; the median temporal variance,
    DN^2). A pixel flickers where its temporal variance (ddof 1) exceeds ``flicker_threshold``
    x that median and the rule of ``two_state`` holds."""
    frames = np.asarray(frames, dtype=np.float64)
    n = frames.shape[0]
    var, med = pixel_variances(frames)
    return (*two_state_of(frames.reshape(n, -1).T, var > flicker_threshold(n) * med), med)


_last_states = threading.local()  # the last read-only stack's pixel states on this thread


def pixel_states(frames):
    """((4, h, w) mask of the pixels that flicker between two states (random telegraph pixels,
    ``two_state_pixels``), (4, h, w) mask of those whose temporal variance is as high but that
    show no two states and stay as high without their most extreme value (noisy pixels:
    ``trimmed_variances`` over ``flicker_threshold`` of N - 1 frames x the median variance)).
    Computed once for the same read-only array in a row (the battery's repaired view:
    ``tile_corr``, ``flicker_fraction`` and ``noisy_fraction`` read it)."""
    if getattr(_last_states, "source", None) is frames:
        return _last_states.result
    arr = np.asarray(frames, dtype=np.float64)
    n, shape = arr.shape[0], arr.shape[1:]
    var, med = pixel_variances(arr)
    high = var > flicker_threshold(n) * med
    flick = two_state_of(arr.reshape(n, -1).T, high)[0]
    rows = np.flatnonzero(high & ~flick)
    noisy = np.zeros_like(high)
    noisy[rows] = trimmed_variances(arr.reshape(n, -1)[:, rows].T) > flicker_threshold(n - 1) * med
    result = (flick.reshape(shape), noisy.reshape(shape))
    if isinstance(frames, np.ndarray) and not frames.flags.writeable:
        for m in result:
            m.flags.writeable = False
        _last_states.source, _last_states.result = frames, result
    return result


def flickering(frames):
    """(4, h, w) mask of the pixels that flicker between two states (``pixel_states``)."""
    return pixel_states(frames)[0]


def flicker_fraction(frames, level_dn=None):
    """Fraction of the pixels that flicker (``flickering``)."""
    return float(flickering(frames).mean())


def noisy_fraction(frames, level_dn=None):
    """Fraction of the pixels whose temporal variance is a flickering pixel's, with or without
    their most extreme value, but that show no two states (``pixel_states``): noisy pixels,
    whose extra temporal noise is unimodal. A heavy read-noise tail's single extreme values,
    and telegraph pixels high or low in all but one frame, do not count."""
    return float(pixel_states(frames)[1].mean())


def flickering_lines(m):
    """Of sensor-line means (N, L; DN): (mask over the L lines of those whose frame means -- less
    the line's mean over frames and each frame's mean -- show two states by the pixels' rule
    (``two_state`` over ``flicker_threshold`` x the median line's temporal variance), their
    steps (DN), their shares of high frames)."""
    values = _line_residuals(m).T
    var = max(float(median(values.var(axis=1, ddof=1))), 1e-12)
    return two_state(values, flicker_threshold(values.shape[1]) * var)


def flickering_columns(frames):
    """``flickering_lines`` of a stack's (N, 4, h, w; DN) 2w sensor columns."""
    return flickering_lines(sensor_col_means(np.asarray(frames, dtype=np.float64)))


def flickering_rows(frames):
    """``flickering_lines`` of a stack's (N, 4, h, w; DN) 2h sensor rows."""
    return flickering_lines(sensor_row_means(np.asarray(frames, dtype=np.float64)))


def col_flicker_fraction(frames, level_dn=None):
    """Fraction of the sensor columns with two states (``flickering_columns``)."""
    return float(flickering_columns(frames)[0].mean())


def row_flicker_fraction(frames, level_dn=None):
    """Fraction of the sensor rows with two states (``flickering_rows``)."""
    return float(flickering_rows(frames)[0].mean())


NOISY_LINE_Z = 6.0  # robust sigmas (over the sensor columns) above the median column: a noisy column


def row_noise_blocks(frames):
    """(READ_MAP_BLOCKS,) temporal variance (ddof 1) of the sensor-row means in each row block
    (``block_index`` of the packed rows, as the kernels cut them), DN^2: each frame's row means
    less that frame's mean (``frame_row_means``) and less the stack's mean row means (a fixed
    row pattern)."""
    m = frame_row_means(np.asarray(frames, dtype=np.float64))
    n = m.shape[0]
    r2 = (m - m.mean(axis=0, keepdims=True)) ** 2 * (n / (n - 1))
    block = block_index(m.shape[1] // 2)[np.arange(m.shape[1]) // 2]
    return np.bincount(block, weights=r2.sum(axis=0), minlength=READ_MAP_BLOCKS) / (n * np.bincount(block, minlength=READ_MAP_BLOCKS))


def row_noise_spread(frames, level_dn=None):
    """Rms over the row blocks of the log temporal variance of the sensor-row means
    (``row_noise_blocks``) less their mean: near sqrt(2 / ((N - 1) rows per block)) for row
    noise of one level; more where the row noise grows or falls along the frame (a reference
    settling during readout, a row driver far from its supply)."""
    v = np.log(np.maximum(row_noise_blocks(frames), 1e-12))
    return float(np.sqrt(np.mean((v - v.mean()) ** 2)))


def frame_row_variances(frames) -> tuple[np.ndarray, np.ndarray]:
    """((N,), (N,)) each frame's variance of its sensor rows' temporal means (stack mean and
    frame mean out), robust (1.4826 MAD, squared: a row glitch does not count), DN^2: of the
    mean over the whole row, and of half the difference between its even and its odd packed
    columns' means, which holds the row mean's white noise and none of the row offset."""
    f = np.asarray(frames, dtype=np.float64)
    n, _, h, _ = f.shape
    halves = np.empty((2, n, 2 * h))
    for parity in (0, 1):
        for row_set in (0, 1):
            halves[parity, :, row_set::2] = f[:, [c for c in range(4) if ROW_SET[c] == row_set], :, parity::2].mean(axis=(1, 3))
    halves -= halves.mean(axis=1, keepdims=True)
    halves -= halves.mean(axis=2, keepdims=True)
    whole, white = 0.5 * (halves[0] + halves[1]), 0.5 * (halves[0] - halves[1])
    return robust_scale(whole, 1)[1][:, 0] ** 2, robust_scale(white, 1)[1][:, 0] ** 2


def frame_row_spread(frames, level_dn=None):
    """Standard deviation over frames (N >= 3) of the log of each frame's row-mean variance
    (``frame_row_variances``): near 2.3 sqrt(1 / sensor rows) for row noise of one level; more
    where the row noise of some frames is stronger than of others (interference that comes and
    goes, a supply that switches mode between frames)."""
    return float(np.std(np.log(np.maximum(frame_row_variances(frames)[0], 1e-12)), ddof=1))


def column_pixel_noise(frames):
    """(2w,) of a stack (N >= 2, 4, h, w; DN): each sensor column's median, over its pixels (its
    two packed channels, all rows), of their temporal variance (ddof 1) once each frame's
    column mean is taken out, DN^2: the pixels' own temporal noise along the column. A column
    offset, fixed or new in every frame (``Col``, ``ColRTS``), is taken out; a few telegraph or
    noisy pixels do not move a median."""
    frames = np.asarray(frames, dtype=np.float64)
    n, _, h, w = frames.shape
    out = np.empty(2 * w)
    for col_set in (0, 1):
        f = frames[:, [c for c in range(4) if COLUMN_SET[c] == col_set]]  # (N, 2, h, w)
        f = f - f.mean(axis=(1, 2), keepdims=True)
        out[col_set::2] = median(f.var(axis=0, ddof=1).reshape(2 * h, w), axis=0)
    return out


def noisy_columns(frames):
    """(mask over the 2w sensor columns of the noisy ones, ``column_pixel_noise``'s median over
    the columns, DN^2): a column is noisy where its pixels' temporal noise exceeds the median
    column's by NOISY_LINE_Z robust sigmas (1.4826 MAD over the columns)."""
    return noisy_of(column_pixel_noise(frames))


def noisy_of(v):
    """``noisy_columns`` of the columns' ``column_pixel_noise`` ``v`` (2w,), DN^2."""
    med = float(median(v))
    mad = 1.482602218505602 * float(median(np.abs(v - med)))
    return v > med + NOISY_LINE_Z * max(mad, 1e-12), med


def noisy_col_fraction(frames, level_dn=None):
    """Fraction of the sensor columns that are noisy (``noisy_columns``)."""
    return float(noisy_columns(frames)[0].mean())


TAP_WINDOW = 16  # sensor lines each side of a gap whose levels are compared (a readout tap's edge)
TAP_TRIM = 2  # lines left out at each end of a window's sorted values: a flickering or defect line does not count
TAP_P = 1e-3  # chance that a stack with one black level shows an edge along an axis


def _line_residuals(m):
    """Sensor-line means (N, L) less each line's mean over frames and each frame's mean."""
    return m - m.mean(axis=0, keepdims=True) - m.mean(axis=1, keepdims=True) + m.mean()


def tap_steps(m, window: int = TAP_WINDOW):
    """(L + 1,) of sensor-line means ``m`` (N >= 2, L; DN): at each gap g (before line g), the
    temporal variance (ddof 1) of the step from the level of the ``window`` lines before it to
    that of the ``window`` lines after it, of each frame's line residuals (less the line's mean
    over frames and the frame's mean); NaN within ``window`` lines of an end. A level is the
    mean of a window's values less the ``TAP_TRIM`` lowest and highest (94 % of a mean's
    efficiency on Gaussian lines; a flickering or defect line does not move it). A black
    level of its own per readout tap, new in every frame, steps at the tap's edges."""
    n, lines = m.shape
    out = np.full(lines + 1, np.nan)
    if lines < 2 * window:
        return out
    r = _line_residuals(m)
    v = np.sort(np.lib.stride_tricks.sliding_window_view(r, window, axis=1), axis=2)  # (N, L - window + 1, window): lines g..
    level = v[:, :, TAP_TRIM:window - TAP_TRIM].mean(axis=2)
    out[window:lines - window + 1] = (level[:, window:] - level[:, :-window]).var(axis=0, ddof=1)
    return out


def _change_point(r, lo: int, hi: int, first: int, last: int) -> int:
    """The gap g in [first, last] that splits lines lo .. hi - 1 of the residuals ``r`` (N, L)
    into two runs, each with a level of its own in every frame, with the least squared error."""
    x = r[:, lo:hi]
    c1 = np.concatenate([np.zeros((x.shape[0], 1)), np.cumsum(x, axis=1)], axis=1)  # sums of lines lo .. lo + j - 1
    c2 = np.concatenate([np.zeros((x.shape[0], 1)), np.cumsum(x * x, axis=1)], axis=1)
    j = np.arange(first - lo, last - lo + 1)
    n = hi - lo
    left = c2[:, j] - c1[:, j] ** 2 / j
    right = (c2[:, -1:] - c2[:, j]) - (c1[:, -1:] - c1[:, j]) ** 2 / (n - j)
    return int(lo + j[np.argmin((left + right).sum(axis=0))])


def tap_edges(m, window: int = TAP_WINDOW, p: float = TAP_P) -> list[int]:
    """Readout-tap edges (gaps, ascending: the first line of each new tap) of sensor-line means
    ``m`` (N >= 3, L; DN): the gaps whose ``tap_steps`` exceed the median gap's by more than a
    chi-square of N - 1 degrees does by chance at one of the gaps with probability ``p`` (over
    its median), the largest within ``window`` gaps, each then placed by least squares
    (``_change_point``) within ``window / 2`` lines of it."""
    s = tap_steps(m, window)
    ok = np.isfinite(s)
    n = m.shape[0]
    if ok.sum() < 3 or n < 3:
        return []
    med = float(np.median(s[ok]))
    ratio = sstats.chi2.isf(p / ok.sum(), n - 1) / sstats.chi2.median(n - 1)
    v = np.where(ok, s, -np.inf)
    high = v > max(med, 1e-30) * ratio
    peak = ndimage.maximum_filter1d(v, 2 * window + 1, mode="constant", cval=-np.inf)
    r = _line_residuals(m)
    lines = m.shape[1]
    half = window // 2
    return sorted({_change_point(r, max(g - window, 0), min(g + window, lines), max(g - half, 1), min(g + half, lines - 1))
                   for g in np.flatnonzero(high & (v >= peak))})


def tap_step_ratio(frames, level_dn=None):
    """Largest ``tap_steps`` over the median gap's, over the sensor columns and the sensor rows:
    near 1 to a few for a readout with one black level, the tap offsets' variance over the
    lines' noise for a readout in taps (halves, quadrants) each with a black level of its own
    that moves from frame to frame."""
    f = np.asarray(frames, dtype=np.float64)
    best = 1.0
    for m in (sensor_col_means(f), sensor_row_means(f)):
        s = tap_steps(m)
        s = s[np.isfinite(s)]
        if s.size >= 3:
            best = max(best, float(s.max() / max(np.median(s), 1e-30)))
    return best


SPIKE_Z = 8.0  # robust sigmas above the pixel's other frames: a single-frame event, not noise


def spike_scale(frames, var=None):
    """(4,) temporal scale of each channel of a stack (N >= 3; DN): the median pixel's temporal
    variance as a Gaussian's sigma (what ``spikes`` measures single-frame events against).
    ``var``: the stack's temporal variance map (``temporal_moments``) if known."""
    f = np.asarray(frames, dtype=np.float64)
    n = f.shape[0]
    var = temporal_moments(f)[1] if var is None else var
    return np.sqrt(median(var.reshape(f.shape[1], -1), axis=1) / (sstats.chi2.median(n - 1) / (n - 1)))


def spikes(frames, scale=None):
    """(N, 4, h, w) mask of single-frame events of a stack (N >= 3; DN): a value more than
    ``SPIKE_Z`` x the larger of its channel's temporal scale (the median pixel's temporal
    variance, as a Gaussian's sigma) and the spread of the pixel's other frames above the
    median of those, in a pixel where no other frame is. A hot pixel is high in every frame, a
    telegraph pixel in several, a pixel with much dark shot noise spread in all: none of them
    is a spike. Only pixels whose highest value stands 4.5 scales above their mean can be one
    (the rule implies it for N >= 3); the rule is applied to those. ``scale``: the (4,)
    ``spike_scale`` if known (that of ``-frames`` is the same)."""
    f = np.asarray(frames, dtype=np.float64)
    mask = np.zeros(f.shape, dtype=bool)
    if f.shape[0] < 3:
        return mask
    scale = spike_scale(f) if scale is None else np.asarray(scale)
    mask[_spike_hits(f, f.max(axis=0) - f.mean(axis=0), scale, 1.0)] = True
    return mask


def _spike_hits(f, rise, scale, sign: float):
    """(frame, channel, y, x) indices of the events of ``sign`` (1: bright, -1: dark) in a
    stack ``f`` (N >= 3), given each pixel's ``rise`` (its highest value, or its lowest
    negated, less its mean) and the (4,) ``scale`` (``spikes``' rule)."""
    scale = np.asarray(scale)[:, None, None]
    cand = np.nonzero(rise > 4.5 * np.maximum(scale, 1e-9))
    if cand[0].size == 0:
        return (np.zeros(0, dtype=np.intp),) * 4
    v = np.sort(sign * f[(slice(None),) + cand], axis=0)  # (N, candidates)
    others = v[:-1]
    spread = others.std(axis=0, ddof=1)
    hit = (v[-1] - median(others, axis=0)) > SPIKE_Z * np.maximum(np.maximum(scale[cand[0], 0, 0], spread), 1e-9)
    sel = tuple(c[hit] for c in cand)
    frame = (sign * f[(slice(None),) + sel]).argmax(axis=0)
    return (frame,) + sel


def spike_counts(frames) -> tuple[int, int]:
    """(bright, dark) single-frame events (``spikes``' rule, on the stack and on its negative) of
    a stack (N >= 3; DN); (0, 0) for fewer frames."""
    f = np.asarray(frames, dtype=np.float64)
    if f.shape[0] < 3:
        return 0, 0
    mean, var = temporal_moments(f)
    scale = spike_scale(f, var)
    lo, hi = temporal_range(f)
    return _spike_hits(f, hi - mean, scale, 1.0)[0].size, _spike_hits(f, mean - lo, scale, -1.0)[0].size


def spike_fraction(frames, level_dn=None):
    """Excess of bright single-frame events (``spikes``) over dark ones, as a fraction of a
    stack's pixel values: heavy-tailed read noise makes both alike (at Tukey lambda -0.14 each
    ~5e-4), an impulse only bright ones."""
    bright, dark = spike_counts(frames)
    return float((bright - dark) / np.asarray(frames).size)


def spike_outliers(frames):
    """(N, 4, h, w) mask of a stack's impulses: where bright single-frame events (``spikes``)
    outnumber the dark ones significantly (``significant_spikes``), the brightest of them,
    all but as many as there are dark ones (those are the read noise's own tail); where dark
    ones outnumber the bright ones so (lost charge packets, dropouts), the darkest of them
    likewise; else those of either sign beyond the tail's reach (``far_cut``, in units of
    their channel's scale: bit errors), or none."""
    f = np.asarray(frames, dtype=np.float64)
    out = np.zeros(f.shape, dtype=bool)
    if f.shape[0] < 3:
        return out
    mean, var = temporal_moments(f)  # one computation, the array may be writeable (uncached)
    scale = spike_scale(f, var)
    lo, hi = temporal_range(f)
    bright = _spike_hits(f, hi - mean, scale, 1.0)
    dark = _spike_hits(f, mean - lo, scale, -1.0)
    side = spike_side(bright[0].size, dark[0].size)
    if side:
        hits, others = (bright, dark) if side > 0 else (dark, bright)
        _, ch, y, x = hits
        out[hits] = beyond_dark(side * (f[hits] - median(f[:, ch, y, x], axis=0)), others[0].size)
    elif bright[0].size + dark[0].size:  # as many of each sign: the tails, but for a far population of both (``far_cut``)
        sizes = [sign * (f[hits] - median(f[:, hits[1], hits[2], hits[3]], axis=0)) / scale[hits[1]]
                 for hits, sign in ((bright, 1.0), (dark, -1.0))]
        cut = far_cut(np.concatenate(sizes), SPIKE_Z)
        for hits, size in zip((bright, dark), sizes):
            out[tuple(c[size >= cut] for c in hits)] = True
    return out


def beyond_dark(excess, n_dark: int):
    """Mask over bright single-frame events with ``excess`` (DN above their pixel) of the
    impulses among them: all but the ``n_dark`` smallest, as many as there are dark events
    (the read noise's own tail, symmetric)."""
    excess = np.asarray(excess)
    cut = np.sort(excess)[n_dark] if n_dark < excess.size else np.inf
    return excess >= cut


FAR_P = 1e-6  # chance under the tail's power law of as many events beyond a size: a far population
FAR_MIN = 3  # events a far population needs
FAR_FIT = 10  # events below a candidate size the tail's power law is fitted to
FAR_RATIO = 3.0  # ... or a gap of this ratio between sorted sizes (a light tail: too few events to fit)


def _truncated_rate(mean, top, ok) -> np.ndarray:
    """Rate (maximum likelihood) of an exponential truncated to [0, ``top``) whose sample mean is
    ``mean`` (each candidate's; 0 where not ``ok``): the root of 1/a - top/(e^(a top) - 1) =
    mean, by bisection on log a."""
    lo, hi = np.full(mean.shape, -20.0), np.full(mean.shape, 20.0)
    t = np.where(ok, top, 1.0)
    m = np.where(ok, mean, 0.25)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        a = np.exp(mid)
        with np.errstate(over="ignore"):
            fitted = 1.0 / a - t / np.expm1(a * t)
        lo, hi = np.where(fitted > m, mid, lo), np.where(fitted > m, hi, mid)  # the mean falls as the rate grows
    return np.where(ok, np.exp(0.5 * (lo + hi)), 0.0)


def far_cut(sizes, floor: float) -> float:
    """Size from which single-frame events (``sizes``: each one's excess over its pixel, DN, of
    either sign's events, all above the detection threshold ``floor``) form a population of
    their own, beyond the read noise's tail; inf where none does. For each candidate size
    (each event's, with ``FAR_FIT`` events or more below it), the events below it fit a
    power law above ``floor`` truncated at the candidate (maximum likelihood; the index taken
    3 of its sd, from Fisher's information, lower), which predicts how many reach that size; the
    candidate whose count (at least ``FAR_MIN``) is least likely under that prediction
    (binomial) is the cut, where that chance is under ``FAR_P``. A heavy read-noise tail is a power law (Tukey lambda < 0: index
    1 / -lambda) and is predicted by its own lower part; a bit error on a data link moves codes
    by 2^b: a cluster of equal sizes far above what that tail reaches. A light tail leaves too
    few events to fit: there a gap of ``FAR_RATIO`` between consecutive sorted sizes (the floor
    below the smallest) sets the far ones apart (the top two of a power law of index a are that
    far apart with chance FAR_RATIO^-a: Tukey lambda -0.14, a = 7: 5e-4)."""
    v = np.sort(np.asarray(sizes, dtype=np.float64).ravel())
    floor = max(float(floor), 1e-12)
    v = v[v > floor]
    n = v.size
    if n < FAR_MIN + 2:
        return np.inf
    logs = np.log(v / floor)
    below = np.concatenate([[0.0], np.cumsum(logs)])[:-1]  # sum of the logs of the events below each one
    k = np.arange(n)  # events below each candidate
    far = n - k  # events at or beyond it
    ok = (k >= FAR_FIT) & (far >= FAR_MIN)
    mean = np.where(ok, below / np.maximum(k, 1), 0.0)  # mean log size of the events below each candidate
    top = logs  # their log sizes lie in [0, top): a truncated exponential of rate alpha
    ok &= mean < top / 2.0  # else no decreasing power law fits them
    rate = _truncated_rate(mean, top, ok)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # Fisher's information of one event on the rate
        e = np.exp(-np.where(ok, rate * top, 1.0))
        info = 1.0 / np.where(ok, rate, 1.0) ** 2 - np.where(ok, top, 0.0) ** 2 * e / (1.0 - e) ** 2
    alpha = rate - 3.0 / np.sqrt(np.maximum(k * np.where(ok & (info > 0), info, 1e-300), 1e-300))  # 3 sd lower: more beyond
    ok &= alpha > 0
    survive = np.exp(-np.where(ok, alpha, 0.0) * logs)  # the power law's share of events beyond each candidate
    p = np.where(ok, sstats.binom.sf(far - 1, n, np.clip(survive, 0.0, 1.0)), 1.0)
    i = int(np.argmin(p))
    cut = float(v[i]) if p[i] < FAR_P else np.inf
    # a light tail leaves few events to fit: a gap of FAR_RATIO between sorted sizes sets a far population apart
    w = np.concatenate([[floor], v])
    ratio = w[1:] / w[:-1]
    j = int(np.argmax(ratio))
    return min(cut, float(w[j + 1]) if ratio[j] >= FAR_RATIO and n - j >= FAR_MIN else np.inf)


def spike_side(n_bright: int, n_dark: int) -> int:
    """1 where bright single-frame events outnumber the dark ones significantly
    (``significant_spikes``), -1 where the dark ones outnumber the bright ones so (dropouts),
    else 0: the side whose events are impulses, the other's being the read noise's own tail."""
    return 1 if significant_spikes(n_bright, n_dark) else -1 if significant_spikes(n_dark, n_bright) else 0


def significant_spikes(n_bright: int, n_dark: int) -> bool:
    """True when ``n_bright`` single-frame events above the noise outnumber the ``n_dark`` below
    it by more than 5 standard deviations of their difference (symmetric noise: none)."""
    return n_bright - n_dark > 5.0 * np.sqrt(max(n_bright + n_dark, 1))


def stuck_from_range(lo, hi, lines: bool = True):
    """Mask of the stuck pixels from each pixel's lowest and highest value over a stack (same
    shape, (4, h, w)): equal in every frame. A pixel that stays at the stack's lowest (highest)
    value is left out where pixels that move also reach it: there it is the clip at black
    (white), not a stuck pixel; so is one on a row or column of its channel stuck for more
    than half its length: a defect line (kept with ``lines`` False)."""
    const = lo == hi
    moving = ~const
    if moving.any():
        at_floor = (lo == lo.min()) & bool(lo[moving].min() == lo.min())
        at_ceiling = (hi == hi.max()) & bool(hi[moving].max() == hi.max())
        const &= ~(at_floor | at_ceiling)
    if lines and const.ndim == 3:  # (4, h, w): a row or column stuck for the most part is a defect line (Lines), not dead pixels
        const &= ~((const.mean(axis=2) > 0.5)[:, :, None] | (const.mean(axis=1) > 0.5)[:, None, :])
    return const


def stuck_pixels(frames):
    """Of a stack (N >= 2, 4, h, w): ((4, h, w) mask of the dead pixels, ``stuck_outliers``: the
    same value in every frame, far from the channel's noise; their values, DN). A pixel stuck
    within the noise is left out: coarse codes (a digital gain) make that happen by chance."""
    v = np.asarray(frames, dtype=np.float64)
    lo, hi = temporal_range(v)
    stuck = stuck_outliers(lo, hi, v[0]) if (lo == hi).any() else np.zeros(lo.shape, dtype=bool)
    return stuck, lo[stuck]


STUCK_OUTLIER = 5.0  # robust sigma from the channel median: a stuck pixel the noise estimates leave out


def stuck_outliers(lo, hi, frame, lines: bool = True):
    """(4, h, w) mask of the stuck pixels (``stuck_from_range`` of the per-pixel lowest and
    highest values ``lo``, ``hi`` over a stack) lying more than STUCK_OUTLIER robust sigma
    from their channel's median in ``frame`` (one frame of the stack): dead pixels, left out
    of noise estimates as EMVA 1288 leaves out defect pixels. Stuck pixels within the noise
    (read noise well under a DN sticks by chance) stay in."""
    frame = np.asarray(frame, dtype=np.float64)
    med, scale = robust_scale(frame.reshape(4, -1), axis=1)
    far = np.abs(frame - med[:, :, None]) > STUCK_OUTLIER * scale[:, :, None]
    return stuck_from_range(np.asarray(lo), np.asarray(hi), lines).reshape(frame.shape) & far


def stuck_fraction(frames, level_dn=None):
    """Fraction of the pixels stuck at one value in every frame, far from the noise
    (``stuck_pixels``): 0 without dead pixels."""
    return float(stuck_pixels(frames)[0].mean())


def repeated_row_mask(frames) -> np.ndarray:
    """(N, 2, h - 1) True where sensor row 2y + row_set (y >= 1) of a frame reads exactly as the
    same colour's row above it, in both of its packed channels: a line read out twice."""
    frames = np.asarray(frames)
    same = np.all(frames[:, :, 1:] == frames[:, :, :-1], axis=3)  # (N, 4, h - 1)
    return np.stack([same[:, [c for c in range(4) if ROW_SET[c] == rs]].all(axis=1) for rs in (0, 1)], axis=1)


def repeated_rows(frames, level_dn=None):
    """Fraction of the sensor rows (below the first of each colour) that read exactly as the same
    colour's row above them (``repeated_row_mask``): 0 where every row has its own noise."""
    return float(repeated_row_mask(frames).mean())


BURST_Z = 8.0  # sds of a row's variance ratio by which a burst row stands out
BURST_CLIP = 8.0  # robust sigmas a residual counts up to in its row's variance


_last_burst = threading.local()  # the last read-only stack's clipped temporal residual on this thread


def _clipped_residual(f):
    """The temporal residual of a stack (DN), clipped at ``BURST_CLIP`` robust sigma of it."""
    resid = f - temporal_moments(f)[0]
    sub = resid[:, :, ::7, ::7]
    scale = 1.482602218505602 * float(np.median(np.abs(sub - np.median(sub))))
    if scale > 0:
        np.clip(resid, -BURST_CLIP * scale, BURST_CLIP * scale, out=resid)
    resid.flags.writeable = False  # shared by the rows' and the columns' ratios
    return resid


def burst_row_ratios(frames, columns: bool = False) -> tuple[np.ndarray, float, np.ndarray]:
    """((N, 2h) ratios, threshold, (2h,) each row's median variance in DN^2) of a stack (N >= 3;
    DN): each frame's sensor row's variance (its pixels' temporal residuals, both packed
    channels, clipped at ``BURST_CLIP`` robust sigma of the stack's residuals: a pixel's spike
    moves a row's little) over that row's median over the frames (a row noisier in every frame,
    a glow's shot noise, is its own reference), and the ratio a burst row exceeds: 1 +
    ``BURST_Z`` sds of that ratio for Gaussian noise (a variance of n values: sqrt(2 / n); a
    median of N variances: sqrt(pi / 2N) of that more). With ``columns``, the same of the
    sensor columns ((N, 2w) ratios)."""
    f = np.asarray(frames, dtype=np.float64)
    n_frames, _, h, w = f.shape
    resid = _once(_last_burst, frames, lambda: _clipped_residual(f))
    sets, along, across = (COLUMN_SET, (1, 2), w) if columns else (ROW_SET, (1, 3), h)
    var = np.empty((n_frames, 2 * across))
    for line_set in (0, 1):
        var[:, line_set::2] = resid[:, [c for c in range(4) if sets[c] == line_set]].var(axis=along, ddof=1)
    line = np.median(var, axis=0)
    ratio = var / np.maximum(line, 1e-30)[None, :]
    n = 2 * (h if columns else w)  # values in one sensor line's variance
    sd = np.sqrt(2.0 / n) * np.sqrt(1.0 + np.pi / (2.0 * n_frames))
    return ratio, 1.0 + BURST_Z * sd, line


def burst_rows(frames, level_dn=None):
    """Fraction of a stack's frames' sensor rows much noisier than the same row in the other
    frames (``burst_row_ratios``): interference bursts during the readout of a few rows; 0
    without them."""
    if np.asarray(frames).shape[0] < 3:
        return 0.0
    ratio, threshold, _ = burst_row_ratios(frames)
    return float((ratio > threshold).mean())


def burst_cols(frames, level_dn=None):
    """Fraction of a stack's frames' sensor columns much noisier than the same column in the
    other frames (``burst_row_ratios`` of the columns): a column amplifier's noise bursts; 0
    without them."""
    if np.asarray(frames).shape[0] < 3:
        return 0.0
    ratio, threshold, _ = burst_row_ratios(frames, columns=True)
    return float((ratio > threshold).mean())


def read_noise_profile(frames):
    """(20,) white temporal variance (``temporal_variance_cells``, DN^2) averaged per channel
    (4), per row block and per column block (READ_MAP_BLOCKS each): what ``read_noise_spread``
    sums up."""
    cells = temporal_variance_cells(frames)
    return np.concatenate([cells.mean(axis=(1, 2)), cells.mean(axis=(0, 2)), cells.mean(axis=(0, 1))])


def map_effects(cells):
    """(channel, row-block, column-block) main effects of a (4, B, B) array: its means over
    the other two axes less the grand mean."""
    m = cells.mean()
    return cells.mean(axis=(1, 2)) - m, cells.mean(axis=(0, 2)) - m, cells.mean(axis=(0, 1)) - m


def frame_noise_spread(frames, level_dn=None):
    """Standard deviation over frames of the log of each frame's white-noise variance: the
    robust (1.4826 MAD) variance of its high-passed temporal residual (``temporal_highpass``),
    so that smooth fields, line noise, spikes and telegraph pixels do not count. Near
    sqrt(2 / pixels) for a read noise of one level."""
    r = temporal_highpass(np.asarray(frames, dtype=np.float64))
    flat = r.reshape(r.shape[0], -1).astype(np.float32)  # sorted 3x faster; the MAD within 1e-7 of float64's
    mad = median(np.abs(flat - median(flat, axis=1, keepdims=True)), axis=1).astype(np.float64)
    return float(np.std(np.log(np.maximum(MAD_TO_SIGMA * mad, 1e-12) ** 2), ddof=1))


def read_noise_spread(frames, level_dn=None):
    """Rms of the channel, row-block and column-block main effects (``map_effects``) of the
    log temporal variance per cell (``temporal_variance_cells``): near 0 for read noise the same
    everywhere; more for a channel's own amplifier or a readout half of its own."""
    parts = map_effects(np.log(np.maximum(temporal_variance_cells(frames), 1e-12)))
    return float(np.sqrt(sum(np.mean(p**2) for p in parts)))


_last_row_means = threading.local()  # the last read-only stack's sensor-row means on this thread
_last_col_means = threading.local()  # ... and sensor-column means


def sensor_row_means(frames):
    """(N, 2h) mean of each sensor row (its two packed channels, all columns), DN (read-only
    for a read-only stack: kept for the next statistic of it)."""
    def compute():
        n, _, h, _ = frames.shape
        out = np.empty((n, 2 * h))
        for row_set in (0, 1):
            out[:, row_set::2] = frames[:, [c for c in range(4) if ROW_SET[c] == row_set]].mean(axis=(1, 3))
        out.flags.writeable = False
        return out

    return _once(_last_row_means, frames, compute)


def sensor_col_means(frames):
    """(N, 2w) mean of each sensor column (its two packed channels, all rows), DN (read-only for
    a read-only stack, as ``sensor_row_means``)."""
    def compute():
        n, _, _, w = frames.shape
        out = np.empty((n, 2 * w))
        for col_set in (0, 1):
            out[:, col_set::2] = frames[:, [c for c in range(4) if COLUMN_SET[c] == col_set]].mean(axis=(1, 2))
        out.flags.writeable = False
        return out

    return _once(_last_col_means, frames, compute)


def temporal_col_deviations(frames, rows: bool = False):
    """(N, 2w) each frame's sensor-column means (``sensor_col_means``) less the column's mean
    over the stack and less the frame's mean over the columns, DN: the columns' temporal part;
    with ``rows``, the same of the sensor rows ((N, 2h), ``sensor_row_means``)."""
    d = (sensor_row_means if rows else sensor_col_means)(np.asarray(frames, dtype=np.float64))
    d = d - d.mean(axis=0, keepdims=True)
    return d - d.mean(axis=1, keepdims=True)


COL_SPREAD_BLOCKS = 8  # blocks of sensor columns whose column noise ``col_noise_spread`` compares


def column_temporal_variance(frames) -> np.ndarray:
    """(2w,) each sensor column's temporal variance over the stack of its mean
    (``temporal_col_deviations``; N - 1 degrees of freedom), DN^2: its column noise plus its
    pixels' noise over the column's length."""
    d = temporal_col_deviations(frames)
    return (d * d).sum(axis=0) / max(d.shape[0] - 1, 1)


def col_noise_spread(frames, level_dn=None):
    """The largest over the smallest, over ``COL_SPREAD_BLOCKS`` blocks of sensor columns, of
    the median of their columns' ``column_temporal_variance``: near 1 where every column's
    offsets move alike from frame to frame; the ratio of the taps' column noise where a readout
    tap (an ADC bank) has column noise of its own."""
    if np.asarray(frames).shape[0] < 3:
        return 1.0
    v = column_temporal_variance(frames)
    if v.size < 2 * COL_SPREAD_BLOCKS:
        return 1.0
    med = [float(np.median(b)) for b in np.array_split(v, COL_SPREAD_BLOCKS)]
    return max(med) / max(min(med), 1e-30)


def col_lag_covariances(frames, lags: int) -> np.ndarray:
    """(lags + 1,) covariance of the columns' temporal parts (``temporal_col_deviations``) of
    sensor columns j apart, j = 0 .. lags (DN^2)."""
    d = temporal_col_deviations(frames)
    n = d.shape[1]
    return np.array([np.mean(d[:, : n - j] * d[:, j:]) for j in range(min(lags, n - 1) + 1)])


def col_neighbour_corr(frames, level_dn=None):
    """Correlation of neighbouring sensor columns' temporal parts (``col_lag_covariances``):
    columns whose offsets move together from frame to frame (a group's shared reference); near
    0 for independent columns."""
    if np.asarray(frames).shape[0] < 3:
        return 0.0
    c = col_lag_covariances(frames, 1)
    return float(c[1] / c[0]) if c[0] > 0 else 0.0


def frame_slopes(frames, columns: bool = False) -> np.ndarray:
    """(N,) least-squares slope of each frame's sensor-row means (``sensor_row_means``; with
    ``columns`` its sensor-column means) less the stack's mean profile, DN per sensor line:
    a black level that ramps across the frame by a new amount in every frame."""
    m = (sensor_col_means if columns else sensor_row_means)(np.asarray(frames, dtype=np.float64))
    m = m - m.mean(axis=0, keepdims=True)
    i = np.arange(m.shape[1]) - 0.5 * (m.shape[1] - 1)
    return m @ i / float(i @ i)


STEP_EDGE = 8  # sensor rows at either end where no step is looked for (a change point there is a few rows' noise)


def step_scan(e) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """((N,), (N,), (N,)) each row profile's of ``e`` (N, rows; DN) largest standardized step,
    the first row after it and the profile's noise: the CUSUM of the profile (its mean out) at
    each cut over its standard error under white noise of the profile's level (1.4826 MAD of
    successive rows' differences over sqrt(2): a smooth profile does not count), the
    ``STEP_EDGE`` rows at either end left out."""
    e = np.asarray(e, dtype=np.float64)
    n = e.shape[1]
    noise = MAD_TO_SIGMA * median(np.abs(np.diff(e, axis=1)), axis=1) / math.sqrt(2.0) + 1e-12
    t = np.arange(1, n)
    z = np.abs(np.cumsum(e - e.mean(axis=1, keepdims=True), axis=1)[:, :-1]) / np.sqrt(t * (n - t) / n) / noise[:, None]
    edge = min(STEP_EDGE, max((n - 2) // 4, 0))
    z[:, :edge] = z[:, n - 1 - edge:] = 0.0
    at = np.argmax(z, axis=1)
    return z[np.arange(len(z)), at], t[at], noise


def row_step_scan(frames) -> tuple[np.ndarray, np.ndarray]:
    """((N,), (N,)) each frame's largest standardized step down its sensor rows and the first
    sensor row after it: ``step_scan`` of its temporal row means (``temporal_col_deviations(rows=
    True)``)."""
    return step_scan(temporal_col_deviations(frames, rows=True))[:2]


def row_step_z(frames, level_dn=None):
    """Mean over the frames (N >= 3) of each frame's largest standardized step down its sensor
    rows (``row_step_scan``): about 3 for white row noise; more where the black level steps at a
    row of each frame (a clamp that re-triggers during readout, a load switched mid-frame)."""
    return float(row_step_scan(frames)[0].mean())


def row_ramp_std(frames, level_dn=None):
    """Spread over frames (std, ddof 1) of the frames' black ramps down the sensor rows
    (``frame_slopes``), DN over the frame's height: a clamp that droops during readout."""
    if np.asarray(frames).shape[0] < 3:
        return 0.0
    return float(frame_slopes(frames).std(ddof=1) * 2 * np.asarray(frames).shape[2])


def col_ramp_std(frames, level_dn=None):
    """``row_ramp_std`` across the sensor columns, DN over the frame's width."""
    if np.asarray(frames).shape[0] < 3:
        return 0.0
    return float(frame_slopes(frames, columns=True).std(ddof=1) * 2 * np.asarray(frames).shape[3])


def temporal_row_variance(frames) -> float:
    """Variance of the sensor rows' temporal parts (each frame's sensor-row means less the row's
    mean over the stack and the frame's mean), DN^2: the row noise new in every frame."""
    return float(np.mean(temporal_col_deviations(frames, rows=True) ** 2))


def row_pair_covariances(frames) -> tuple[float, float, float]:
    """(covariance of the two sensor rows of each Bayer row pair (2y, 2y + 1), of neighbouring
    rows of adjacent pairs (2y + 1, 2y + 2), variance) of the sensor rows' temporal parts (each
    frame's sensor-row means less the row's mean over the stack and the frame's mean), DN^2."""
    d = temporal_col_deviations(frames, rows=True)
    return float(np.mean(d[:, 0::2] * d[:, 1::2])), float(np.mean(d[:, 1:-1:2] * d[:, 2::2])), float(np.mean(d * d))


def row_pair_corr(frames, level_dn=None):
    """The correlation of the two sensor rows of a Bayer row pair beyond that of rows of adjacent
    pairs (``row_pair_covariances``): rows converted together (a two-row readout) share an
    offset; near 0 for row noise of one row's own, or one that wanders smoothly."""
    if np.asarray(frames).shape[0] < 3:
        return 0.0
    within, across, var = row_pair_covariances(frames)
    return (within - across) / var if var > 0 else 0.0


ROW_TAP_ROWS = 256  # sensor rows the row-tap steps read (evenly strided): 0.45 s on 8 frames of 12 MP
ROW_TAP_NOISY = 4.0  # a column whose temporal variance is this many times the median column's is left out of the levels


def row_tap_steps(frames, window: int = TAP_WINDOW) -> np.ndarray:
    """(2w + 1,) of a stack (N >= 2, 4, h, w; DN): at each gap g between sensor columns (before
    column g), the variance over frames and sensor rows of the step from the mean of the
    ``window`` columns before it to that of the ``window`` after it, on each frame's temporal
    residual (the frame less the stack's mean), each frame's mean step over its rows taken out;
    NaN within ``window`` columns of an end. Noisy columns (temporal variance beyond
    ``ROW_TAP_NOISY`` x the median column's) count as 0. Row noise of its own per readout tap (a
    column-ADC bank with its own reference) steps at the taps' edges in every row; row noise
    shared by the whole row does not step, nor does a column's or a tap's offset per frame."""
    f = np.asarray(frames, dtype=np.float64)
    n, _, h, w = f.shape
    out = np.full(2 * w + 1, np.nan)
    if n < 2 or w < window:
        return out
    f = f[:, :, :: max(1, -(-2 * h // ROW_TAP_ROWS))]
    r = frame_mosaic(f - f.mean(axis=0, keepdims=True))  # (N, R, 2w): temporal residual, sensor positions
    var = (r * r).mean(axis=(0, 1))
    r[:, :, var > ROW_TAP_NOISY * max(float(np.median(var)), 1e-30)] = 0.0
    g = np.arange(window, 2 * w - window + 1)
    total = np.zeros(g.size)
    for frame in r:  # one frame at a time: (R, gaps) at most
        c = np.concatenate([np.zeros((frame.shape[0], 1)), np.cumsum(frame, axis=1)], axis=1)
        step = (2.0 * c[:, g] - c[:, g - window] - c[:, g + window]) / window  # left level less right level
        step -= step.mean(axis=0, keepdims=True)
        total += (step * step).sum(axis=0)
    out[g] = total / ((n - 1) * (r.shape[1] - 1))  # the stack's mean took 1 / N, the rows' mean one row
    return out


def row_tap_ratio(frames, level_dn=None):
    """The largest ``row_tap_steps`` over their median: about 1 where a row's offset is shared
    by all its columns, more at the edge of readout taps with row noise of their own."""
    s = row_tap_steps(frames)
    ok = np.isfinite(s)
    if ok.sum() < 3:
        return 1.0
    return float(s[ok].max() / max(float(np.median(s[ok])), 1e-30))


def frame_row_means(frames):
    """Sensor-row means (``sensor_row_means``) of each frame less that frame's mean: (N, 2h) DN."""
    m = sensor_row_means(frames)
    return m - m.mean(axis=1, keepdims=True)


def frame_col_means(frames):
    """Sensor-column means (``sensor_col_means``) of each frame less that frame's mean: (N, 2w) DN."""
    m = sensor_col_means(frames)
    return m - m.mean(axis=1, keepdims=True)


def line_tone_spectrum(m):
    """(frequency in cycles per sensor line, mean periodogram over frames in DN^2) of each
    frame's sensor-line means ``m`` (N, n), above the low band (1 / (2 x 16) cycles per line:
    smooth fields are the low-frequency statistics' concern). Per frame, not about the stack
    mean: a tone of random phase has the same power in every frame, while its residual about
    the mean of a few frames does not."""
    p = (_power(sp_fft.rfft(m, axis=1)) / m.shape[1]).mean(axis=0)
    f = np.fft.rfftfreq(m.shape[1])
    keep = f >= 0.5 / _LOW_BAND
    return f[keep], p[keep]


def temporal_row_means(frames) -> np.ndarray:
    """(N, rows) mean of each sensor row of a stack's temporal residual (each frame less the
    stack mean; N >= 2), each frame's mean taken out, DN: the row noise new in every frame,
    without the fixed rows and the frame's black level. With N >= 4, rows of their own are left
    out: those with two states (``flickering_rows``) and those whose temporal variance exceeds
    ``FLICKER`` x the median row's (telegraph or noisy rows, ``RowRTS``: not every row's noise)."""
    f = np.asarray(frames, dtype=np.float64)
    rm = sensor_row_means(f - temporal_moments(f)[0])
    return steady_rows(rm, ~flickering_rows(f)[0] if f.shape[0] >= 4 else None)


def steady_rows(rm, keep=None) -> np.ndarray:
    """Temporal row means (N, rows; DN) with each frame's mean taken out and, with N >= 4, the
    rows whose temporal variance exceeds ``FLICKER`` x the median row's (and those not in
    ``keep``) left out (``temporal_row_means``)."""
    rm = rm - rm.mean(axis=1, keepdims=True)
    if rm.shape[0] >= 4:
        v = rm.var(axis=0)
        steady = v <= FLICKER * max(float(np.median(v)), 1e-30)
        rm = rm[:, steady if keep is None else steady & keep]
        rm = rm - rm.mean(axis=1, keepdims=True)
    return rm


ROW_TAIL_Z = 4.0  # robust sigmas of the temporal row means: a row burst, where a Gaussian gives 6e-5


ROW_SPIKE_Z = 8.0  # robust sigmas of the rows' frame-to-frame spread: a row's event in one frame


def row_spike_events(frames) -> tuple[np.ndarray, np.ndarray, float]:
    """((N, 2h) offsets DN, (N, 2h) mask of events, robust sigma DN) of a stack (N >= 3; DN):
    each frame's sensor-row means less that frame's median row and less the row's median
    over the frames; an event is an offset beyond ``ROW_SPIKE_Z`` robust sigmas of them all,
    in a row that has it in one frame only (a row that jumps in several is a telegraph's)."""
    m = sensor_row_means(np.asarray(frames, dtype=np.float64))
    m = m - median(m, axis=1, keepdims=True)
    d = m - median(m, axis=0, keepdims=True)
    _, scale = robust_scale(d.ravel(), axis=0)
    hit = np.abs(d) > ROW_SPIKE_Z * float(scale[0])
    return d, hit & (hit.sum(axis=0, keepdims=True) == 1), float(scale[0])


def row_spike_fraction(frames, level_dn=None):
    """Share of a stack's frames' sensor rows offset far from the same row in the other frames
    (``row_spike_events``): row glitches, new rows in every frame; 0 without them. Read on the
    frames as measured: a row far off in one frame is what the line repair takes out."""
    if np.asarray(frames).shape[0] < 3:
        return 0.0
    return float(row_spike_events(frames)[1].mean())


def row_tail_mass(frames, level_dn=None):
    """Fraction of the temporal row means (``temporal_row_means``, rows of their own left out)
    beyond ``ROW_TAIL_Z`` robust sigmas (1.4826 MAD) of their median: heavy-tailed row noise
    (bursts in random rows). A count, so one odd row moves it by one value, not as it moves a
    kurtosis."""
    return tail_share(temporal_row_means(frames))


def tail_share(values) -> float:
    """Share of ``values`` beyond ``ROW_TAIL_Z`` robust sigmas (1.4826 MAD) of their median."""
    v = np.asarray(values, dtype=np.float64).ravel()
    med, scale = robust_scale(v[:, None], axis=0)
    return float(np.mean(np.abs(v - med[0]) > ROW_TAIL_Z * scale[0]))


def row_tone_spectrum(frames):
    """``line_tone_spectrum`` of each frame's sensor-row means: tones along the sensor rows."""
    return line_tone_spectrum(frame_row_means(np.asarray(frames, dtype=np.float64)))


def col_tone_spectrum(frames):
    """``line_tone_spectrum`` of each frame's sensor-column means: tones along the sensor columns."""
    return line_tone_spectrum(frame_col_means(np.asarray(frames, dtype=np.float64)))


def _peak_over_median(p):
    return float(p.max() - np.median(p))


def row_tone(frames, level_dn=None):
    """Power of the largest bin of the sensor-row means' periodogram (``row_tone_spectrum``)
    above its median bin, above the low band (DN^2): for white row noise a few times the
    median, for a tone of amplitude a over n sensor rows about n a^2 / 4 (periodic banding)."""
    return _peak_over_median(row_tone_spectrum(frames)[1])


def col_tone(frames, level_dn=None):
    """``row_tone`` along the other axis: the largest bin of the sensor-column means'
    periodogram (``col_tone_spectrum``) above its median bin (DN^2): vertical banding."""
    return _peak_over_median(col_tone_spectrum(frames)[1])


def frame_mosaic(frames):
    """Each frame of a stack (N, 4, h, w) as its raw mosaic (N, 2h, 2w), less each channel's
    mean (DN), the channels at their sensor positions (``ROW_SET`` / ``COLUMN_SET``)."""
    frames = np.asarray(frames, dtype=np.float64)
    mean = channel_moments(frames)[0]
    n, _, h, w = frames.shape
    raw = np.empty((n, 2 * h, 2 * w))
    for ch in range(4):
        np.subtract(frames[:, ch], mean[:, ch, None, None], out=raw[:, ROW_SET[ch]::2, COLUMN_SET[ch]::2])
    return raw


AXIS_CLEAR = 2  # bins: the Hann window's main lobe spreads a tone over 2 bins either side


def diagonal_bins(shape):
    """(fy, fx, mask) of the ``rfft2`` bins of a raw mosaic of ``shape`` (2h, 2w), in cycles per
    sensor row and column, that ``diag_tone`` reads: AXIS_CLEAR bins or more off both axes
    (tones along one axis, row and column noise: the 1-D statistics' concern) and off both
    Nyquist lines (where per-channel line offsets of a Bayer mosaic lie), outside the
    low-frequency disk."""
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.rfftfreq(shape[1])[None, :]
    dy, dx = AXIS_CLEAR / shape[0] - 1e-12, AXIS_CLEAR / shape[1] - 1e-12
    mask = ((np.abs(fy) >= dy) & (np.abs(fy) <= 0.5 - dy) & (fx >= dx) & (fx <= 0.5 - dx)
            & (np.hypot(fy, fx) >= 0.5 / _LOW_BAND))
    fy, fx = np.broadcast_arrays(fy, fx)
    return fy, fx, mask


def hann_2d(shape):
    """(H, W) separable Hann window: a smooth field's power leaks into far bins of a windowed
    periodogram as 1 / d^6 (d bins away), not 1 / d^2."""
    return np.outer(np.hanning(shape[0]), np.hanning(shape[1]))


def windowed_periodogram(raw):
    """Mean over frames of the ``rfft2`` periodogram of raw mosaics (N, H, W) under
    ``hann_2d``, DN^2: |X|^2 / sum(w^2), so white noise of variance s^2 reads s^2 in every bin
    and a tone of amplitude a reads about a^2 sum(w)^2 / (4 sum(w^2))."""
    w = hann_2d(raw.shape[1:])
    x = sp_fft.rfft2((raw * w).astype(np.float32), axes=(1, 2))  # single precision: 2x faster, 1e-6 of a bin
    return _power(x).mean(axis=0, dtype=np.float64) / float(np.sum(w * w))


LOCAL, CORE = 9, 5  # bins along each axis: a tone must stand out of the ring between these squares around it


def local_background(p):
    """Mean of a 2-D periodogram over the ring of bins around each bin between a LOCAL x LOCAL
    and a CORE x CORE square (edges mirrored): what surrounds a tone, whose windowed main lobe
    lies within the core; a smooth excess (leakage, a glow's spectrum) moves it with it."""
    big = ndimage.uniform_filter(p, size=LOCAL, mode="mirror") * LOCAL**2
    core = ndimage.uniform_filter(p, size=CORE, mode="mirror") * CORE**2
    return (big - core) / (LOCAL**2 - CORE**2)


FIXED_OUTLIER_Z = 8.0  # robust sigmas of the mean map beyond which a pixel's fixed offset is a defect's (as hot_fraction's)


def without_fixed_outliers(frames, z: float = FIXED_OUTLIER_Z):
    """The frames (N, 4, h, w; DN) with the pixels whose stack mean stands ``z`` robust sigmas
    from its channel's median (hot pixels and tiles, dim ones) set to that median, moved with
    the frame's channel mean: a sparse fixed pattern's broad spectrum, the same in every frame,
    is not a tone's (a tone of any phase moves the mean map's scale with it and makes no outlier)."""
    frames = np.asarray(frames, dtype=np.float64)
    m = temporal_moments(frames)[0].reshape(4, -1)
    med, scale = robust_scale(m, axis=1)
    scale = np.maximum(scale, grid_step(frames) / frames.shape[0])  # the mean of N whole codes: a grid of 1/N
    out = (np.abs(m - med) > z * scale).reshape(frames.shape[1:])
    if not out.any():
        return frames
    means = frames.mean(axis=(2, 3))  # (N, 4)
    fill = med.reshape(1, 4) + means - means.mean(axis=0, keepdims=True)
    return np.where(out[None], fill[:, :, None, None], frames)


def diag_tone_spectrum(frames):
    """(fy, fx, mean windowed periodogram over frames in DN^2 (``windowed_periodogram``), its
    ``local_background``) of each frame's raw mosaic (``frame_mosaic``) at the bins
    ``diagonal_bins`` keeps. Per frame: a tone of random phase has the same power in every
    frame. Windowed and against the local median: the leakage and the broad spectrum of strong
    smooth fields (a glow, low-frequency interference) are not taken for a tone; nor is a sparse
    fixed pattern's (``without_fixed_outliers``)."""
    raw = frame_mosaic(without_fixed_outliers(frames))
    p = windowed_periodogram(raw)
    fy, fx, mask = diagonal_bins(raw.shape[1:])
    return fy[mask], fx[mask], p[mask], local_background(p)[mask]


def diag_tone(frames, level_dn=None):
    """Power of the bin of the raw mosaics' windowed 2-D periodogram off both axes
    (``diag_tone_spectrum``) that stands most above the ring of bins around it (DN^2): a few
    times the median for white noise, about n a^2 / 10 over n pixels (the Hann window's gains)
    for a tone of amplitude a whose phase advances from row to row (diagonal stripes of a
    serial readout); a smooth excess moves the ring with it."""
    _, _, p, local = diag_tone_spectrum(frames)
    return float((p - local).max())


def pixel_fixed_std(frames, level_dn=None):
    """Pixel-to-pixel std of the stack-mean map from neighbouring-pixel differences along
    rows (robust: 1.4826 MAD / sqrt(2)), per channel, rms (DN). Smooth patterns (vignetting,
    uneven illumination of a flat) do not count; a white fixed pattern and temporal noise /
    sqrt(N) do."""
    d = np.diff(temporal_moments(frames)[0], axis=2).reshape(4, -1)
    _, scale = robust_scale(d, axis=1)
    return _rms(scale) / np.sqrt(2.0)


def flat_fixed_rel(frames, level_dn=None):
    """Pixel-to-pixel fixed-pattern std of a flat stack (``pixel_fixed_std``) relative to its
    mean level (dimensionless)."""
    level = float(np.mean(level_dn)) if level_dn is not None else float(frames.mean())
    return pixel_fixed_std(frames) / max(level, 1e-12)


def linearity_errors(frames, level_dn, name: str = "flat_linearity") -> np.ndarray:
    """(4,) each channel's mean of a flat stack relative to the level a linear response gives it
    (the line through zero a series of flats fits; ``level_dn`` including the black offsets),
    less 1: EMVA 1288's linearity error at this level."""
    if level_dn is None:
        raise ValueError(f"{name} needs the level of a linear response (level_dn)")
    level = np.broadcast_to(np.asarray(level_dn, dtype=np.float64), (4,))
    return frames.mean(axis=(0, 2, 3)) / np.maximum(level, 1e-12) - 1.0


def flat_linearity(frames, level_dn=None):
    """The linearity error (``linearity_errors``), mean over channels."""
    return float(np.mean(linearity_errors(frames, level_dn)))


def channel_linearity(frames, level_dn=None):
    """Spread over the channels (rms about their mean) of the linearity error
    (``linearity_errors``): a channel whose response bends unlike the others'. The light's
    instability, common to the channels, cancels."""
    e = linearity_errors(frames, level_dn, "channel_linearity")
    return float(np.sqrt(np.mean((e - e.mean()) ** 2)))


def flat_gain_spread(frames, level_dn=None):
    """Spread (ddof 1) over a flat stack's frames of their means, over the stack's level (its
    mean or ``level_dn``'s): a gain or a light that changes from frame to frame."""
    level = float(np.mean(level_dn)) if level_dn is not None else float(frames.mean())
    return float(frames.mean(axis=(1, 2, 3)).std(ddof=1) / max(level, 1e-12))


GRID_MAX_PERIOD = 16  # packed pixels along each axis (32 sensor pixels): the periods a gain grid is looked for at
GRID_SMOOTH = 2 * GRID_MAX_PERIOD + 1  # packed pixels of the box a flat's light shape is taken over


def flat_relative_map(frames) -> np.ndarray:
    """(4, h, w) fixed pattern of a flat stack (N, 4, h, w; DN) relative to its light: the
    stack mean over its box average of ``GRID_SMOOTH`` pixels, less 1 (a light's shape, smooth
    over the box, does not count; a pattern of a short period averages out of the box)."""
    m = np.asarray(frames, dtype=np.float64).mean(axis=0)
    smooth = ndimage.uniform_filter(m, size=(1, GRID_SMOOTH, GRID_SMOOTH), mode="reflect")
    return m / np.where(np.abs(smooth) > 1e-12, smooth, 1e-12) - 1.0


def _phase_counts(n, p):
    """(p,) lines of each phase of a period p among n lines."""
    return (n - np.arange(p) + p - 1) // p


def _phase_means(n, max_period):
    """(n, sum of 1 .. max_period) matrix: column block p (p columns) averages the lines of
    each phase of a period p among n lines."""
    blocks = []
    for p in range(1, max_period + 1):
        m = np.zeros((n, p))
        m[np.arange(n), np.arange(n) % p] = 1.0
        blocks.append(m / _phase_counts(n, p))
    return np.concatenate(blocks, axis=1)


def period_excess(rel) -> dict:
    """{(py, px): excess} for every period up to ``GRID_MAX_PERIOD`` but 1 x 1: the variance of
    the fold's cell means over the cells, less what white noise of the map's variance leaves in
    a mean of h w / (py px) pixels, summed over the channels (relative units squared). All
    folds at once: two products with phase-averaging matrices."""
    rel = np.asarray(rel, dtype=np.float64)
    h, w = rel.shape[1:]
    my, mx = min(GRID_MAX_PERIOD, h), min(GRID_MAX_PERIOD, w)
    cells = np.matmul(np.matmul(_phase_means(h, my).T[None], rel), _phase_means(w, mx))  # (4, sum py, sum px)
    starts_y, starts_x = np.cumsum([0, *range(1, my)]), np.cumsum([0, *range(1, mx)])
    block_sum = lambda a: np.add.reduceat(np.add.reduceat(a, starts_y, axis=1), starts_x, axis=2)  # noqa: E731
    n = np.arange(1, my + 1)[:, None] * np.arange(1, mx + 1)[None, :]  # cells of each period
    mean, mean2 = block_sum(cells) / n, block_sum(cells**2) / n
    noise = rel.var(axis=(1, 2))[:, None, None] * n / (h * w)
    excess = np.sum(mean2 - mean**2 - noise, axis=0)  # (my, mx)
    return {(py, px): float(excess[py - 1, px - 1]) for py in range(1, my + 1) for px in range(1, mx + 1)
            if not py == px == 1}


def grid_excess(frames, level_dn=None):
    """Largest excess variance of a flat stack's relative fixed pattern folded over a period
    (``period_excess``) over the pattern's variance: about 0 for a pattern with no period, up
    to 1 for one that is all periodic (phase-detection pixels, a repeating microlens cell)."""
    rel = flat_relative_map(frames)
    return max(period_excess(rel).values()) / max(float(rel.var(axis=(1, 2)).sum()), 1e-30)


GAIN_WINDOW = 32  # sensor lines each side of a gap in the local fit of a flat's step (a light is smooth over 64 lines)
GAIN_DEGREE = 3  # the light's local shape: a cubic (its slope, curvature and skew do not read as a step)
GAIN_P = 1e-3  # chance that a flat of one gain shows an edge along an axis
UNLIT = math.log(0.5)  # a flat's line below half the light (log): masked or dead, not a gain
GAIN_END_WINDOW = GAIN_DEGREE + 2  # the fewest lines a side a step is fitted over, near a frame's end (a cubic and a step)
GAIN_TRIM = 0.05  # share of a line's values left out at each end of its profile's mean (dead, hot and PDAF pixels)


@functools.lru_cache(maxsize=64)
def step_kernel(window: int) -> np.ndarray:
    """(2 window,) weights whose dot with 2 ``window`` lines is the step at their middle gap:
    the least-squares coefficient of a step in a fit of a cubic, an alternation from line to
    line (the two colours of a sensor line, each over its own mean: a light's slope shifts
    them by half a pixel) and a step."""
    x = np.arange(-window, window) + 0.5
    alternation = np.where(np.arange(2 * window) % 2 == 0, 1.0, -1.0)
    design = np.stack([x**j for j in range(GAIN_DEGREE + 1)] + [alternation, np.sign(x) / 2.0], axis=1)
    out = np.linalg.pinv(design)[-1]
    out.flags.writeable = False
    return out


def line_noise(p) -> float:
    """Std of the white noise of a line profile ``p`` (L,), robust: from its second
    differences between lines two apart (of one colour: a light's slope, an alternation from
    line to line and a single step do not count), 1.4826 MAD / sqrt(6)."""
    p = np.asarray(p, dtype=np.float64)
    d = p[4:] - 2.0 * p[2:-2] + p[:-4]
    return MAD_TO_SIGMA * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(6.0)


GAIN_TEMPORAL_P = 0.01  # chance that white temporal noise reads as coloured in a stack's steps
WHITE_DOF = 0.19  # degrees of freedom per line of ``line_noise``'s variance: a MAD's 37 % efficiency over second differences correlated at lags 2 and 4 (1 + 2 (4/9 + 1/36))


@functools.lru_cache(maxsize=256)
def step_dof(window: int, gaps: int) -> float:
    """Degrees of freedom of the mean square of the steps (``step_kernel``) at ``gaps``
    consecutive gaps of one profile of white noise: the steps overlap, n^2 / sum of their
    squared correlations over every pair."""
    w = step_kernel(window)
    a = np.correlate(w, w, "full")
    lags = np.arange(-(w.size - 1), w.size)
    return float(gaps**2 / np.sum(np.clip(gaps - np.abs(lags), 0, None) * (a / a[w.size - 1]) ** 2))


def temporal_step_excess(profiles, window: int = GAIN_WINDOW) -> float:
    """Variance of a stack mean's step (``step_kernel``) that the frames' temporal noise adds
    beyond its white part, from the frames' log line profiles ``profiles`` (N >= 2, L): their
    steps about the mean profile against the steps their white noise (``line_noise``) gives.
    Row noise of a 1/f spectrum or a flickering light steps at every gap by more; 0 unless
    the excess is significant (chi^2 of ``step_dof``, ``GAIN_TEMPORAL_P``)."""
    p = np.asarray(profiles, dtype=np.float64)
    n, length = p.shape
    if n < 2 or length < 2 * window + 5:
        return 0.0
    d = p - p.mean(axis=0)
    w = step_kernel(window)
    steps = np.stack([np.correlate(x, w, "valid") for x in d])
    step_var = float(np.sum(steps**2)) / ((n - 1) * steps.shape[1])  # one frame's
    white_var = float(np.mean([line_noise(x) ** 2 for x in d])) * n / (n - 1) * float(w @ w)
    dof = (n - 1) * step_dof(window, steps.shape[1])
    white_dof = (n - 1) * WHITE_DOF * (length - 4)
    if not step_var > white_var * sstats.f.isf(GAIN_TEMPORAL_P, dof, white_dof):
        return 0.0
    return (step_var - white_var) / n


LINE_SPIKE_Z = 5.0  # a line this many noise sigmas off the median of its 5 lines is one line's own (a bright, dark or flickering column)


def despiked(p) -> np.ndarray:
    """A line profile ``p`` (L,) with each line further than ``LINE_SPIKE_Z`` white-noise sigmas
    (``line_noise``) from the median of the 5 lines around it set to that median (a Hampel
    filter): one line's offset is not a step, and a median of 5 keeps a step's edge."""
    p = np.asarray(p, dtype=np.float64)
    med = ndimage.median_filter(p, size=5, mode="nearest")
    return np.where(np.abs(p - med) > LINE_SPIKE_Z * line_noise(p), med, p)


def gain_steps(p, window: int = GAIN_WINDOW, excess: float = 0.0):
    """(L + 1,) of a flat's log line profile ``p`` (L,): at each gap g (before line g), the
    step of a local fit of a cubic plus a step over the ``window`` lines either side
    (``step_kernel``) of the profile ``despiked``, over its noise: the white noise's (``line_noise``) and ``excess``, the
    step variance coloured temporal noise adds (``temporal_step_excess``); within ``window``
    lines of an end, over the lines there are (down to ``GAIN_END_WINDOW`` a side; NaN
    nearer). A readout tap with a gain of its own steps at its edges by the
    log of the gains' ratio; a light's smooth shape does not step. Profiles are
    ``trimmed_line_means``."""
    p = np.asarray(p, dtype=np.float64)
    out = np.full(p.shape[0] + 1, np.nan)
    if p.shape[0] < 2 * window + 5:
        return out
    p = despiked(p)
    w = step_kernel(window)
    white = line_noise(p)
    noise = math.sqrt((white * float(np.linalg.norm(w))) ** 2 + max(float(excess), 0.0))
    out[window:p.shape[0] - window + 1] = np.correlate(p, w, "valid") / max(noise, 1e-30)
    # near an end, the window shrinks to the lines there are (a band of edge rows or columns with a
    # gain of its own); the coloured excess scaled as white noise through the shorter kernel
    for half in range(GAIN_END_WINDOW, window):
        wk = step_kernel(half)
        scale = float(wk @ wk)
        noise_k = math.sqrt(white**2 * scale + max(float(excess), 0.0) * scale / float(w @ w))
        for gap in (half, p.shape[0] - half):
            out[gap] = float(p[gap - half:gap + half] @ wk) / max(noise_k, 1e-30)
    # no step across lines that see less than half the light (masked or dead bands, which a
    # despike of single lines leaves): they are no tap's gain
    dark = np.concatenate([[0], np.cumsum(p < UNLIT)])
    gaps = np.arange(out.size)
    reach = np.where((gaps >= window) & (gaps <= p.shape[0] - window), window, np.minimum(gaps, p.shape[0] - gaps))
    lo, hi = np.clip(gaps - reach, 0, p.shape[0]), np.clip(gaps + reach, 0, p.shape[0])
    out[dark[hi] - dark[lo] > 0] = np.nan
    return out


def frame_log_profiles(frames) -> dict:
    """{"col": (N, 2w), "row": (N, 2h)}: each frame's log line profiles of a flat stack (N, 4,
    h, w; DN), the mosaic's line means of the frame over its stack's channel levels (plain
    means: a fixed outlier cancels about the stack's mean profile, the only use they have)."""
    f = np.asarray(frames, dtype=np.float64)
    level = f.mean(axis=(0, 2, 3))
    rel = f / np.where(level > 0, level, 1.0)[None, :, None, None]
    return {"col": np.log(np.maximum(sensor_col_means(rel), 1e-6)), "row": np.log(np.maximum(sensor_row_means(rel), 1e-6))}


def stack_step_excess(frames) -> dict:
    """{"col": excess, "row": excess}: ``temporal_step_excess`` of a flat stack's frames (N, 4,
    h, w; DN) along its sensor columns and rows (0 for a single frame)."""
    profiles = frame_log_profiles(frames)
    return {axis: temporal_step_excess(profiles[axis]) for axis in ("col", "row")}


def flat_log_mosaic(frames) -> np.ndarray:
    """(2h, 2w) log of a flat stack's mean frame (N, 4, h, w; DN) over each channel's mean, at
    the channels' sensor positions: the light's shape and the sensor's gains, colour taken
    out (a channel without signal: 0)."""
    m = np.asarray(frames, dtype=np.float64).mean(axis=0)
    h, w = m.shape[1:]
    out = np.zeros((2 * h, 2 * w))
    for ch in range(4):
        level = float(m[ch].mean())
        if level > 0:
            out[ROW_SET[ch]::2, COLUMN_SET[ch]::2] = np.log(np.maximum(m[ch] / level, 1e-6))
    return out


def trimmed_line_means(x, axis: int) -> np.ndarray:
    """Means along ``axis`` of a 2-D map, each less its ``GAIN_TRIM`` lowest and highest
    values (a dead or hot pixel does not move a line; 97 % of a mean's efficiency on Gaussian
    values): the line profile across the other axis."""
    x = np.sort(np.asarray(x, dtype=np.float64), axis=axis)
    n = x.shape[axis]
    cut = int(GAIN_TRIM * n)
    return np.take(x, np.arange(cut, n - cut), axis=axis).mean(axis=axis)


def gain_edges(p, window: int = GAIN_WINDOW, p_value: float = GAIN_P, excess: float = 0.0) -> list[int]:
    """Gain edges (gaps, ascending: the first line of each new tap) of a flat's log line
    profile ``p``: the gaps whose ``gain_steps`` stand out further than a normal does at one
    of the gaps with probability ``p_value``, each the largest within ``window`` gaps; of
    more than ``TAP_EDGES``, the largest steps."""
    z = np.abs(gain_steps(p, window, excess))
    ok = np.isfinite(z)
    if ok.sum() < 3:
        return []
    v = np.where(ok, z, -np.inf)
    peak = ndimage.maximum_filter1d(v, 2 * window + 1, mode="constant", cval=-np.inf)
    high = v > sstats.norm.isf(p_value / (2 * ok.sum()))
    found = np.flatnonzero(high & (v >= peak))
    return sorted(int(g) for g in found[np.argsort(-v[found], kind="stable")][:TAP_EDGES])


def flat_gain_edges(log_mosaic, excess=None) -> dict:
    """{"col": gaps, "row": gaps}: the gain edges (``gain_edges``) of a flat's log mosaic
    (``flat_log_mosaic``) along its sensor columns and along its sensor rows; ``excess``:
    the stack's ``stack_step_excess`` (none: white temporal noise)."""
    excess = excess or {}
    return {"col": gain_edges(trimmed_line_means(log_mosaic, 0), excess=excess.get("col", 0.0)),
            "row": gain_edges(trimmed_line_means(log_mosaic, 1), excess=excess.get("row", 0.0))}


def gain_step_z(frames, level_dn=None):
    """Largest ``gain_steps`` (absolute) of a flat stack over its sensor columns and its sensor
    rows: about 3 for a sensor of one gain under a smooth light; at the edge of a readout tap
    with a gain of its own, the step over its noise (its frames' coloured temporal noise
    included: ``stack_step_excess``)."""
    mosaic = flat_log_mosaic(frames)
    excess = stack_step_excess(frames)
    z = np.concatenate([gain_steps(trimmed_line_means(mosaic, 0), excess=excess["col"]),
                        gain_steps(trimmed_line_means(mosaic, 1), excess=excess["row"])])
    z = np.abs(z[np.isfinite(z)])
    return float(z.max()) if z.size else 0.0


def tap_log_gains(log_mosaic, col_edges, row_edges) -> tuple[np.ndarray, np.ndarray]:
    """((T_r, T_c) log gains of mean 0, their (T_r, T_c) standard errors) of the readout taps
    cut by ``col_edges`` and ``row_edges`` (sensor lines) from a flat's log mosaic: at each
    edge, in each band of taps across it, the step of the band's line profile
    (``step_kernel``; its window up to ``GAIN_WINDOW`` lines, within the next edges) is the
    log of the two taps' gain ratio; the log gains are the weighted least-squares fit of those
    steps (a light's smooth shape never enters)."""
    lm = np.asarray(log_mosaic, dtype=np.float64)
    ce, re = [int(e) for e in col_edges], [int(e) for e in row_edges]
    tr, tc = len(re) + 1, len(ce) + 1
    bounds = {"col": [0, *ce, lm.shape[1]], "row": [0, *re, lm.shape[0]]}
    eqs, vals, weights = [], [], []
    for axis, other in (("col", "row"), ("row", "col")):
        b, o = bounds[axis], bounds[other]
        for i in range(1, len(b) - 1):
            e = b[i]
            window = min(GAIN_WINDOW, e - b[i - 1], b[i + 1] - e)
            if window < GAIN_DEGREE + 2:
                continue  # taps too narrow to tell a step from the light
            w = step_kernel(window)
            for band in range(len(o) - 1):
                part = lm[o[band]:o[band + 1]] if axis == "col" else lm[:, o[band]:o[band + 1]].T
                p = trimmed_line_means(part, 0)
                row = np.zeros(tr * tc)
                lo, hi = ((band * tc + i - 1, band * tc + i) if axis == "col" else ((i - 1) * tc + band, i * tc + band))
                row[lo], row[hi] = -1.0, 1.0
                eqs.append(row)
                vals.append(float(p[e - window:e + window] @ w))
                weights.append(1.0 / max(line_noise(p) * float(np.linalg.norm(w)), 1e-12) ** 2)
    if not eqs:
        return np.zeros((tr, tc)), np.full((tr, tc), np.inf)
    a = np.asarray(eqs) * np.sqrt(np.asarray(weights))[:, None]
    cov = np.linalg.pinv(a.T @ a)  # steps fix only differences: the least-norm solution is the one of mean 0
    g = cov @ (a.T @ (np.asarray(vals) * np.sqrt(np.asarray(weights))))
    return g.reshape(tr, tc), np.sqrt(np.maximum(np.diag(cov), 0.0)).reshape(tr, tc)


LIGHT_STABILITY = 1e-3  # a flat's light is stable to about 0.1 %: smaller deviations of its mean are not resolved
CHANNEL_LINEARITY_FLOOR = 5e-4  # the channels' linearity errors resolved against each other: the light's colour, the lowest flats' noise


@dataclass(frozen=True)
class Statistic:
    name: str
    fn: Callable
    min_frames: int = 1
    kind: str = "any"  # "any", "bias" or "flat"
    view: str = "repaired"  # the frames it reads: "repaired" (repaired), "impulses" (with_impulses), "lines" (without_outliers), "raw"
    pixel_fraction: bool = False  # resolution: one pixel of the stack
    mad_of_mean: bool = False  # a robust (MAD) scale of the N-frame mean map: a grid of 1/(2N) DN on whole codes
    line_fraction: bool = False  # resolution: one line of the stack
    frame_line_fraction: bool = False  # resolution: one sensor line of a frame (its rows and columns)
    column_fraction: bool = False  # resolution: one sensor column
    row_fraction: bool = False  # resolution: one sensor row of the stack
    stack_column_fraction: bool = False  # resolution: one sensor column of the stack
    base: str = ""  # the base-model parameter it checks ("" when only effects explain it)
    floor: float = 0.0  # resolution of the measurement itself (e.g. the light's stability)
    fixed_variance: bool = False  # a fixed pattern's variance over pixels: its realization spread is a floor
    pooled: bool = False  # a spread over a stack's N frames (N - 1 degrees of freedom): judged over every stack that has it

    def applies(self, n_frames: int, kind: str) -> bool:
        # dark frames are bias frames of a longer exposure: every bias statistic applies
        return n_frames >= self.min_frames and self.kind in ("any", kind, "bias" if kind == "dark" else kind)

    def resolution(self, frames, value: float = 0.0) -> float:
        """Smallest meaningful difference of this statistic for this stack. A pixel
        fraction counts pixels of one frame's size n: its floor is the Poisson counting
        spread ``sqrt(max(value * n, 1)) / n`` of the model's value (this also covers the realization spread of
        a fixed pattern, which repeated syntheses from one seed do not show). A MAD of the
        mean map of N frames of whole codes moves in steps of 1.4826 / (2N) DN, so syntheses
        that agree to the step show no spread: the step is its floor. A ``floor`` (what the
        measurement itself resolves, such as a flat's light stability) comes first. Else 1e-9."""
        if self.floor:
            return self.floor
        if self.mad_of_mean:
            integer = bool(np.all(frames == np.rint(frames)))
            step = 1.482602218505602 / (2 * frames.shape[0]) if integer else 1e-9
            return step
        if self.fixed_variance:  # two white patterns' double-difference variances differ by 3 v / sqrt(n) rms
            return 3.0 * abs(value) / math.sqrt(frames[0].size) + 1e-9
        if self.frame_line_fraction:  # counts one frame's sensor lines
            n = 2 * (frames.shape[2] + frames.shape[3])
            return float(np.sqrt(max(value * n, 1.0)) / n)
        if self.line_fraction:  # counts lines, as a pixel fraction counts pixels
            n = frames.shape[0] * frames.shape[1] * (frames.shape[2] + frames.shape[3])
            return float(np.sqrt(max(value * n, 1.0)) / n)
        if self.row_fraction:  # counts the stack's sensor rows
            n = frames.shape[0] * 2 * frames.shape[2]
            return float(np.sqrt(max(value * n, 1.0)) / n)
        if self.stack_column_fraction:  # counts the stack's sensor columns
            n = frames.shape[0] * 2 * frames.shape[3]
            return float(np.sqrt(max(value * n, 1.0)) / n)
        if self.column_fraction:  # counts sensor columns
            n = 2 * frames.shape[3]
            return float(np.sqrt(max(value * n, 1.0)) / n)
        if not self.pixel_fraction:
            return 1e-9
        n = frames[0].size
        return float(np.sqrt(max(value * n, 1.0)) / n)


STATISTICS: dict[str, Statistic] = {
    s.name: s
    for s in (
        Statistic("pixel_std", pixel_std, base="read noise scale sigma_TL / sigma_G"),
        Statistic("ppcc_r2", ppcc_r2, base="read-noise shape (Tukey lambda)"),
        Statistic("tail_mass", tail_mass, pixel_fraction=True, base="read-noise shape (Tukey lambda)", view="impulses"),
        Statistic("row_excess", row_excess, base="row noise sigma_r"),
        Statistic("col_excess", col_excess),
        Statistic("row_lowfreq", row_lowfreq),
        Statistic("col_lowfreq", col_lowfreq),
        Statistic("psd2d_lowfreq", psd2d_lowfreq),
        Statistic("defect_lines", defect_lines, line_fraction=True, view="lines"),
        Statistic("hot_fraction", hot_fraction, pixel_fraction=True),
        Statistic("missing_codes", missing_codes, base="ADC codes (a comb means digital gain: no effect models it)"),
        Statistic("code_dnl", code_dnl, base="ADC codes (every code equally wide)"),
        Statistic("clip_low", clip_low, pixel_fraction=True),
        Statistic("mean_dn", mean_dn, kind="bias", base="colour bias (black-level error)"),
        Statistic("temporal_std", temporal_std, min_frames=2, base="read noise scale sigma_TL / sigma_G"),
        Statistic("fixed_std", fixed_std, min_frames=2, mad_of_mean=True),
        Statistic("fixed_pixel_var", fixed_pixel_var, min_frames=2, kind="bias", fixed_variance=True),
        Statistic("fixed_col_excess", fixed_col_excess, min_frames=2),
        Statistic("fixed_row_excess", fixed_row_excess, min_frames=2),
        Statistic("neighbour_corr", neighbour_corr, min_frames=2),  # in flats: charge shared between pixels (diffusion)
        Statistic("read_noise_spread", read_noise_spread, min_frames=2, kind="bias"),
        Statistic("row_noise_spread", row_noise_spread, min_frames=3, kind="bias"),
        Statistic("frame_noise_spread", frame_noise_spread, min_frames=3, kind="bias"),
        Statistic("frame_row_spread", frame_row_spread, min_frames=3, kind="bias"),
        Statistic("tile_corr", tile_corr, min_frames=2, kind="bias"),
        Statistic("flicker_fraction", flicker_fraction, min_frames=3, kind="bias", pixel_fraction=True),
        Statistic("noisy_fraction", noisy_fraction, min_frames=4, kind="bias", pixel_fraction=True),
        Statistic("spike_fraction", spike_fraction, min_frames=3, kind="bias", pixel_fraction=True, view="impulses"),
        Statistic("col_flicker_fraction", col_flicker_fraction, min_frames=4, kind="bias", line_fraction=True, view="lines"),
        Statistic("row_flicker_fraction", row_flicker_fraction, min_frames=4, kind="bias", line_fraction=True, view="lines"),
        Statistic("noisy_col_fraction", noisy_col_fraction, min_frames=4, kind="bias", column_fraction=True),
        Statistic("tap_step_ratio", tap_step_ratio, min_frames=3, kind="bias"),
        # a pair too (since the thirty-second session): a pixel dead at black shows only in flats, and
        # flats come in pairs (EMVA 1288's protocol); a pair's dead pixels are repaired for the others
        Statistic("stuck_fraction", stuck_fraction, min_frames=2, pixel_fraction=True, view="raw"),
        Statistic("repeated_rows", repeated_rows, row_fraction=True, view="raw"),
        Statistic("burst_rows", burst_rows, min_frames=3, kind="bias", row_fraction=True),
        Statistic("burst_cols", burst_cols, min_frames=3, kind="bias", stack_column_fraction=True),
        Statistic("row_pair_corr", row_pair_corr, min_frames=3, kind="bias"),
        Statistic("row_tap_ratio", row_tap_ratio, min_frames=3, kind="bias"),
        Statistic("col_noise_spread", col_noise_spread, min_frames=3, kind="bias"),
        Statistic("row_ramp_std", row_ramp_std, min_frames=3, kind="bias"),
        Statistic("row_step_z", row_step_z, min_frames=3, kind="bias"),
        Statistic("col_ramp_std", col_ramp_std, min_frames=3, kind="bias"),
        Statistic("col_neighbour_corr", col_neighbour_corr, min_frames=3, kind="bias"),
        Statistic("masked_lines", masked_lines, kind="flat", view="raw", frame_line_fraction=True),
        Statistic("quiet_fraction", quiet_fraction, min_frames=2, kind="flat", pixel_fraction=True, view="raw"),
        Statistic("row_spike_fraction", row_spike_fraction, min_frames=3, kind="bias", row_fraction=True, view="raw"),
        Statistic("row_tail_mass", row_tail_mass, min_frames=2, kind="bias", view="lines", line_fraction=True,
                  base="row noise shape (Gaussian)"),
        Statistic("row_tone", row_tone, kind="bias"),
        Statistic("col_tone", col_tone, kind="bias"),
        Statistic("diag_tone", diag_tone, kind="bias"),
        Statistic("frame_mean_std", frame_mean_std, min_frames=3),
        Statistic("frame_mean_common_cov", frame_mean_common_cov, min_frames=3),
        Statistic("frame_mean_lag1", frame_mean_lag1, min_frames=4),  # a black level drifting over the frames
        Statistic("flat_fixed_rel", flat_fixed_rel, min_frames=2, kind="flat"),
        Statistic("flat_linearity", flat_linearity, kind="flat", floor=LIGHT_STABILITY),
        Statistic("channel_linearity", channel_linearity, kind="flat", floor=CHANNEL_LINEARITY_FLOOR),
        # a flat pair holds one degree of freedom: a jitter of a few times the light's stability
        # shows only in the pairs of every level and ISO together
        Statistic("flat_gain_spread", flat_gain_spread, min_frames=2, kind="flat", floor=LIGHT_STABILITY, pooled=True),
        Statistic("grid_excess", grid_excess, kind="flat", view="raw"),  # phase-detection rows are not defects to repair
        Statistic("gain_step_z", gain_step_z, kind="flat"),
    )
}


def frame_statistics(frames, kind: str = "bias", level_dn=None, names=None) -> dict[str, float]:
    """All statistics that apply to this stack: ``{name: value}``.

    Parameters
    ----------
    frames : array (N, 4, h, w)
        Packed frames in DN (black-subtracted).
    kind : "bias", "dark" or "flat"
    level_dn : the clean level of a flat stack (DN), scalar or (4,).
    names : restrict to these statistics.
    """
    given = frames
    frames = np.asarray(frames, dtype=np.float64)
    if frames is not given:  # our own copy (a synthesis in float32): read-only, so its statistics share what they compute
        frames.flags.writeable = False
    if frames.ndim != 4 or frames.shape[1] != 4:
        raise ValueError(f"frames must be packed (N, 4, h, w), got shape {frames.shape}")
    if min(frames.shape[2:]) < 8:
        raise ValueError(f"frames must be at least 8x8 per channel, got {frames.shape[2:]}")
    if kind not in ("bias", "dark", "flat"):
        raise ValueError(f"kind must be 'bias', 'dark' or 'flat', got {kind!r}")
    out = {}
    views: dict = {"raw": frames}
    for name, stat in STATISTICS.items():
        if names is not None and name not in names:
            continue
        if stat.applies(frames.shape[0], kind):
            if stat.view not in views:
                views[stat.view] = statistic_view(name, frames)
            out[name] = stat.fn(views[stat.view], level_dn)
    return out


def statistic_view(name: str, frames):
    """The frames statistic ``name`` reads (``Statistic.view``): a defect line counts once, as a
    defect line, and a dead pixel once, as a stuck pixel."""
    view = STATISTICS[name].view if name in STATISTICS else "repaired"
    frames = np.asarray(frames, dtype=np.float64)
    return {"raw": lambda: frames, "lines": lambda: _repaired_views(frames)[2], "impulses": lambda: with_impulses(frames),
            "repaired": lambda: repaired(frames)}[view]()
