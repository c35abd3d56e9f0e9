"""Stage 1 of calibration: noise parameters at one ISO from bias frames and flat pairs.

All arrays are packed (4, h, w) in (R, G1, B, G2) order, in DN (black-subtracted digital
numbers). Methods follow ELD (Wei et al., CVPR 2020), section 3.2:

* system gain K (DN/e-) by photon transfer on flat-field pairs;
* row noise sigma_r (DN) from per-sensor-row means of bias frames (maximum likelihood);
* read noise from the row-corrected bias residual: Tukey-lambda shape by PPCC, sigma_TL
  (DN) from the probability-plot slope, and the Gaussian sigma_G for comparison;
* colour bias (per-channel mean of a bias frame, DN).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import special, stats

from ..statistics import SPIKE_Z, beyond_dark, far_cut, spike_side, stuck_outliers, written_codes
from .censored import black_floor, censored_read_noise, clipped_share, hot_under_clip
from .joint import IsoParameters
from .kernels import pair_tile_stats, pixel_extremes
from .stuck_bits import raw_codes_of, through_stuck_bits
from .read_noise import (LAMBDA_GRID, ReadNoiseEstimate, estimate_read_noise, sample_indices,  # noqa: F401 (re-exported)
                         subsample)

# Packed channels read out from the same sensor row (see rawaug.bayer).
SENSOR_ROWS = ((0, 1), (2, 3))


def _packed(x, name) -> np.ndarray:
    x = np.asarray(x)
    if x.ndim != 3 or x.shape[0] != 4:
        raise ValueError(f"{name} must be packed Bayer DN of shape (4, h, w), got {x.shape}")
    if x.shape[1] < 2 or x.shape[2] < 2:
        raise ValueError(f"{name} is too small: {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} holds NaN or Inf values")
    return x


# ----------------------------------------------------------------------------- row noise
@dataclass
class RowNoiseEstimate:
    """Row noise of one bias frame.

    sigma_r : std of the per-sensor-row offset, DN (read noise averaged over the row removed).
    shapiro_p : Shapiro-Wilk p-value of the row means (Gaussian offsets give p ~ U(0, 1)).
    row_means : per-sensor-row means, DN, shape (2, h): [rows of (R, G1), rows of (B, G2)],
        after removing the per-channel mean.
    read_variance_dn2 : per-pixel variance left after removing the row offsets, DN^2.
    pixels_per_row : pixels averaged in one row mean.
    """

    sigma_r: float
    shapiro_p: float
    row_means: np.ndarray
    read_variance_dn2: float
    pixels_per_row: int


def defect_mask(bias_dn) -> np.ndarray:
    """(4, h, w) True on the defect lines of a packed frame (a stuck or dead row or column,
    ``rawaug.statistics.defect_line_masks``): excluded from every noise estimate, as EMVA
    1288 excludes defect pixels (one hot column would otherwise set the read noise's tails)."""
    from ..statistics import defect_line_masks

    rows, cols = defect_line_masks(np.asarray(bias_dn, dtype=np.float64)[None])
    return rows[0][:, :, None] | cols[0][:, None, :]


def _without_defects(bias_dn) -> np.ndarray:
    """The frame as float64 with its defect lines set to NaN (a copy)."""
    mask = defect_mask(bias_dn)
    bias = np.array(bias_dn, dtype=np.float64)
    if mask.any():
        bias[mask] = np.nan
    return bias


def _mean(x, axis, keepdims=False):
    """Mean leaving NaN (defect) pixels out; NumPy's plain mean where there are none (5x faster)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a defect row: all NaN
        plain = np.mean(x, axis=axis, keepdims=keepdims)
        return np.nanmean(x, axis=axis, keepdims=keepdims) if np.isnan(plain).any() else plain


def _centered(bias_dn):
    """Each channel minus its mean over the pixels off defect lines (defect pixels NaN)."""
    bias = _without_defects(bias_dn)
    bias -= _mean(bias, (1, 2), keepdims=True)
    return bias


def estimate_row_noise(bias_dn: np.ndarray) -> RowNoiseEstimate:
    """Row noise sigma_r (DN) of a packed bias frame by maximum likelihood.

    Each sensor row mean ``m_j ~ N(0, sigma_r^2 + s^2 / n)``: the row offset plus the read
    noise (per-pixel variance ``s^2``) averaged over the ``n`` pixels of the row. The ML
    estimate is ``sigma_r^2 = max(0, mean(m^2) - s^2 / n)``; ``s^2`` comes from the
    row-corrected residual. Without that subtraction sigma_r would be biased upward when
    it is small.
    """
    return _row_noise(_centered(_packed(bias_dn, "bias_dn")))  # defect lines NaN: left out


def _row_noise(bias) -> RowNoiseEstimate:
    """``estimate_row_noise`` of a frame already centered (defect lines NaN)."""
    rows = _row_means(bias)  # (2, h), NaN on a sensor row that is a defect line
    n = int(np.median(np.isfinite(bias[[0, 1]]).sum(axis=(0, 2))))  # pixels per row mean
    residual = bias - rows[[0, 0, 1, 1]][:, :, None]
    # Removing the row mean takes 1/n of the pixel variance away; restore it.
    read_var = float((np.nanvar(residual) if np.isnan(residual).any() else residual.var()) * n / (n - 1))
    good = rows[np.isfinite(rows)]
    dof = good.size - 2  # two per-channel-pair means were removed
    mean_square = float((good**2).sum() / max(dof, 1))
    sigma_r = math.sqrt(max(0.0, mean_square - read_var / n))
    rows = np.nan_to_num(rows)  # a defect row's offset is not row noise: 0
    flat = good
    if flat.size > 5000:  # scipy's p-value is accurate up to N = 5000
        flat = flat[np.linspace(0, flat.size - 1, 5000).astype(int)]
    p = float(stats.shapiro(flat).pvalue) if flat.size >= 3 else float("nan")
    return RowNoiseEstimate(sigma_r, p, rows, read_var, n)


def _row_means(centered) -> np.ndarray:
    """(2, h) per-sensor-row means of a centered frame, NaN pixels left out (NaN where a
    whole row is)."""
    return np.stack([_mean(centered[list(pair)], (0, 2)) for pair in SENSOR_ROWS])


def row_corrected(bias_dn: np.ndarray, row_means: np.ndarray | None = None) -> np.ndarray:
    """Bias frame with per-channel means and per-sensor-row offsets removed (DN, float64);
    NaN on defect lines (``defect_mask``)."""
    bias = _centered(_packed(bias_dn, "bias_dn"))
    if row_means is None:
        row_means = np.nan_to_num(_row_means(bias))
    return bias - np.asarray(row_means)[[0, 0, 1, 1]][:, :, None]


def read_residual(bias_dn: np.ndarray, row_means: np.ndarray | None = None, exclude=None) -> np.ndarray:
    """The values the read noise is fitted to (DN, 1-D): the row-corrected frame off its
    defect lines and off ``exclude`` (a (4, h, w) mask: the dead pixels a stack shows,
    ``rawaug.statistics.stuck_outliers``)."""
    r = row_corrected(bias_dn, row_means)
    keep = np.isfinite(r)
    if exclude is not None:
        keep &= ~np.asarray(exclude, dtype=bool)
    return r[keep]


def bias_frame_noise(bias_dn, exclude=None, *, lowest=None, max_samples: int | None = 200_000,
                     seed: int = 0, black_code=None) -> tuple[ReadNoiseEstimate, float, tuple | None]:
    """(read noise, row noise sigma_r in DN, channel locations in DN or None) of one packed
    bias frame, ``exclude`` (a (4, h, w) mask: dead pixels, impulses) left out: the
    row-corrected residual's PPCC fit (``estimate_read_noise``); or, for a frame clipped from
    below (``censored.black_floor``), the censored fit of each channel (``_censored_channels``),
    the row noise scaled up by the share the clip hides (``censored.clipped_share``), and the
    channel locations the clip moves the means away from; with ``lowest`` (each pixel's lowest
    value over its stack) the hot pixels are left out of that fit (``censored.hot_under_clip``).
    With ``black_code`` (the raw code of 0 DN per channel) an unclipped frame's stuck bits are
    fitted through (``stuck_bits.through_stuck_bits``)."""
    bias = _packed(bias_dn, "bias_dn")
    row = estimate_row_noise(bias)
    floor = black_floor(bias)
    if floor is None:
        read = estimate_read_noise(read_residual(bias, row.row_means, exclude=exclude), max_samples=max_samples, seed=seed)
        if black_code is None:
            return read, row.sigma_r, None
        codes = raw_codes_of(_without_defects(bias), black_code, exclude, max_samples and max(1, max_samples // 4), seed)
        read, sigma_r, _ = through_stuck_bits(codes, read, row.sigma_r)
        return read, sigma_r, None
    keep = ~defect_mask(bias)
    if exclude is not None:
        keep &= ~np.asarray(exclude, dtype=bool)
    if lowest is not None:
        keep &= ~hot_under_clip(lowest, bias)
    sigma_r = row.sigma_r / max(1.0 - clipped_share(bias[keep], floor), 0.05)
    read, location = _censored_channels([[bias[c][keep[c]]] for c in range(4)], floor, sigma_r, max_samples, seed)
    return read, sigma_r, location


# ----------------------------------------------------------------------------- colour bias, banding, quantization
def estimate_color_bias(bias_dn) -> np.ndarray:
    """Per-channel mean of a packed bias frame (R, G1, B, G2) off its defect lines, DN: the
    black-level error."""
    return _mean(_without_defects(_packed(bias_dn, "bias_dn")), (1, 2))


def centered_spectrum(image, max_size: int = 1024) -> np.ndarray:
    """log10 power of the centralized 2-D FFT of a (centre crop of a) 2-D image, mean removed.

    Row noise shows as a bright vertical line through the centre (power at horizontal
    frequency 0), column noise as a horizontal line."""
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape
    ch, cw = min(h, max_size), min(w, max_size)
    top, left = (h - ch) // 2, (w - cw) // 2
    img = img[top: top + ch, left: left + cw]
    power = np.abs(np.fft.fftshift(np.fft.fft2(img - img.mean()))) ** 2
    return np.log10(power + 1e-12)


def banding_ratios(image, max_size: int = 1024) -> dict:
    """Share of spectral power on the zero-frequency axes, over the share white noise gives.

    ``row`` (power at horizontal frequency 0, i.e. constant along a row) and ``column``;
    about 1 for white noise, much larger with row/column banding."""
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape
    img = img[(h - min(h, max_size)) // 2:][: min(h, max_size), (w - min(w, max_size)) // 2:][:, : min(w, max_size)]
    power = np.abs(np.fft.fft2(img - img.mean())) ** 2
    power[0, 0] = 0.0
    total = power.sum()
    if total <= 0:
        return {"row": float("nan"), "column": float("nan")}
    ch, cw = img.shape
    row_share = power[:, 0].sum() / total  # constant along rows: horizontal frequency 0
    col_share = power[0, :].sum() / total
    return {"row": float(row_share * cw), "column": float(col_share * ch)}


def estimate_quantization_step(codes, max_values: int = 1_000_000) -> float | None:
    """Quantization step (DN) of integer-valued codes: the gcd of the gaps between occupied
    codes. None when the values are not integers (e.g. already scaled floats)."""
    values = subsample(codes, max_values)
    if values.size == 0 or not np.all(values == np.round(values)):
        return None
    levels = np.unique(values.astype(np.int64))
    if levels.size < 2:
        return None
    return float(np.gcd.reduce(np.diff(levels)))


def missing_code_fraction(codes, max_values: int = 1_000_000) -> float:
    """Fraction of codes between the 1st and 99th percentile (in steps of the quantization
    step) that never occur: > 0 means missing ADC codes (a non-ideal ADC or a digital gain).
    A code counts as missing only in a short gap between well-populated codes
    (``written_codes``): a long empty run between two populations (leaky columns far above
    the noise) or a sparse tail is no missing code."""
    values = subsample(codes, max_values)
    step = estimate_quantization_step(values)
    if step is None:
        return 0.0
    lo, hi = np.percentile(values, [1, 99])
    levels = np.rint(values / step)
    written = written_codes(levels)
    start = int(round(lo / step)) - int(levels.min())
    return float((~written[start : start + int(round((hi - lo) / step)) + 1]).mean())


# ----------------------------------------------------------------------------- gain (photon transfer)
@dataclass
class GainEstimate:
    """Photon-transfer result.

    k : system gain, DN per electron (slope of pair variance against mean).
    read_variance_dn2 : intercept, DN^2 (read + row + quantization variance at zero signal).
    k_per_channel : slope fitted per packed channel (R, G1, B, G2).
    tile_mean_dn, tile_variance_dn2 : the tiles used (for the plot).
    n_tiles, n_excluded : tiles used and tiles excluded (saturated, black-clipped, outliers).
    pair_means_dn : mean signal of each pair.
    curvature_per_dn : q of ``variance = intercept + k mean (1 + q mean)`` where the curve
        bends significantly (flats at >= 3 levels; 0: a line).
    """

    k: float
    read_variance_dn2: float
    k_per_channel: tuple = ()
    tile_mean_dn: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tile_variance_dn2: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_tiles: int = 0
    n_excluded: int = 0
    pair_means_dn: tuple = ()
    curvature_per_dn: float = 0.0


STUCK_TILE = 0.01  # a tile with more of its pixels equal in both frames at a clip is clipped there


def _robust_poly(x, y, n_per_tile, degree=1, iterations=8):
    """Weighted polynomial fit of y on x (coefficients from the highest power) with Huber
    reweighting; a tile variance has standard error ~ y * sqrt(2 / (n - 1)). Returns
    (coefficients, their covariance, inlier mask)."""
    keep = np.ones(x.size, bool)
    coef = np.polyfit(x, y, degree)
    cov = np.full((degree + 1, degree + 1), np.nan)
    for _ in range(iterations):
        pred = np.maximum(np.polyval(coef, x), 1e-12)
        se = pred * math.sqrt(2.0 / (n_per_tile - 1))
        z = (y - pred) / se
        keep = np.abs(z) < 5.0
        huber = np.where(np.abs(z) <= 1.5, 1.0, 1.5 / np.maximum(np.abs(z), 1e-12))
        wts = np.where(keep, huber / se**2, 0.0)
        if wts.sum() == 0 or np.unique(x[keep]).size < degree + 1:
            break
        sw = np.sqrt(wts)
        design = np.stack([x**p * sw for p in range(degree, -1, -1)], axis=1)
        coef, *_ = np.linalg.lstsq(design, y * sw, rcond=None)
        cov = np.linalg.pinv(design.T @ design)
    return coef, cov, keep


def _robust_line(x, y, n_per_tile, iterations=8):
    """``_robust_poly`` of degree 1: (k, c, inlier mask)."""
    (k, c), _, keep = _robust_poly(x, y, n_per_tile, 1, iterations)
    return float(k), float(c), keep


CURVATURE_Z = 5.0  # a photon transfer curve is fitted as a parabola where its curvature is this many sd from 0


def _photon_transfer(m, v, n_per_tile, levels):
    """(K, intercept, curvature per DN, inlier mask) of ``variance = c + K mean (1 + q mean)``:
    a line, or, with flats at >= 3 levels whose curve bends significantly (a gain
    non-linearity compresses the shot noise of bright flats: q ~ -3 c_nl), a parabola whose
    slope at zero is K."""
    k, c, keep = _robust_line(m, v, n_per_tile)
    if levels < 3:
        return k, c, 0.0, keep
    (a, k2, c2), cov, keep2 = _robust_poly(m, v, n_per_tile, 2)
    if not (np.isfinite(cov[0, 0]) and abs(a) > CURVATURE_Z * math.sqrt(cov[0, 0]) and k2 > 0):
        return k, c, 0.0, keep
    return float(k2), float(c2), float(a / k2), keep2


def estimate_gain(flat_pairs, *, tile: int = 32, saturation_dn: float | None = None,
                  black_clip_dn: float | None = None, read_variance_dn2: float | None = None) -> GainEstimate:
    """System gain K (DN/e-) by photon transfer on flat-field pairs (packed DN).

    For every ``tile x tile`` tile of every channel of every pair: mean of the two frames
    and half the variance of their difference (the difference cancels fixed patterns such as
    PRNU and vignetting). ``variance = K * mean + read variance``; the line is fitted robustly
    (weighted by the expected standard error of a tile variance, Huber reweighting, 5-sigma
    rejection). Tiles touching ``saturation_dn`` or ``black_clip_dn`` are excluded (a pixel
    that differs between the two frames at a clip, or more than STUCK_TILE of the tile held
    there in both: one dead pixel does not exclude its tile); the clipping levels are
    detected from the data when not given (many pixels sharing the extreme value).

    ``read_variance_dn2`` (from bias frames, optional) decides which pairs are too dark to
    carry shot noise.

    Raises ValueError for a pair with frames of different shapes, a saturated pair, a pair too
    dark to carry shot noise, or when fewer than 2 usable exposure levels remain.
    """
    pairs = list(flat_pairs)
    if not pairs:
        raise ValueError("photon transfer needs at least one flat pair, got none")
    chans, means, variances, pair_means = [], [], [], []
    n_total = 0
    rejected = []
    for i, pair in enumerate(pairs):
        if not isinstance(pair, (tuple, list)) or len(pair) != 2:
            raise ValueError(f"flat pair {i} must be a (frame_a, frame_b) pair, got {type(pair).__name__}")
        a, b = (_packed(x, f"flat pair {i} frame {ab}") for x, ab in zip(pair, "ab"))
        if not (a.dtype == b.dtype == np.float32):  # float32 frames are read as they are (values as float64's)
            a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        if a.shape != b.shape:
            raise ValueError(f"flat pair {i}: frames differ in size: {a.shape} vs {b.shape}")
        sat = saturation_dn if saturation_dn is not None else _clip_level(a, b, high=True)
        low = black_clip_dn if black_clip_dn is not None else _clip_level(a, b, high=False)
        ch, m, v, lo, hi, (lo_same, frac_lo), (hi_same, frac_hi) = pair_tile_stats(a, b, tile)
        ok = np.ones(m.size, bool)
        if sat is not None:  # a moving pixel at the clip, or more than a few pixels held there
            ok &= (hi < sat) & ~((hi_same >= sat) & (frac_hi > STUCK_TILE))
        if low is not None:
            ok &= (lo > low) & ~((lo_same <= low) & (frac_lo > STUCK_TILE))
        clipped = ~ok
        if read_variance_dn2 is not None:  # pixels held at their full well below the white level
            ok &= ~held_tiles(a, b, tile, v, read_variance_dn2)
        n_total += m.size
        mean_dn = float(0.5 * (a.mean(dtype=np.float64) + b.mean(dtype=np.float64)))
        pair_means.append(mean_dn)
        if ok.mean() < 0.5:
            which = ("saturated" if sat is not None and np.mean(np.maximum(hi, hi_same) >= sat) >= 0.5
                     else "black-clipped" if clipped.mean() >= 0.5 else "held at the pixels' full wells")
            rejected.append(f"pair {i} (mean {mean_dn:.1f} DN) is {which}: {100 * (1 - ok.mean()):.0f}% of tiles clipped")
            continue
        pair_var = float(np.median(v[ok]))
        read_var = read_variance_dn2
        if read_var is not None:
            excess = pair_var - read_var
            se = pair_var * math.sqrt(2.0 / max(int(ok.sum()) * (tile * tile - 1), 1))
            if excess < max(5 * se, 0.05 * read_var) or mean_dn < 3 * math.sqrt(read_var):
                rejected.append(f"pair {i} (mean {mean_dn:.2f} DN) is too dark to carry shot noise: variance "
                                f"{pair_var:.3g} DN^2 vs read variance {read_var:.3g} DN^2")
                continue
        chans.append(ch[ok]); means.append(m[ok]); variances.append(v[ok])
    if rejected:
        message = "; ".join(rejected)
        if not means:
            raise ValueError(f"no usable flat pair: {message}")
        warnings.warn(f"flat pairs not used: {message}", stacklevel=2)
    ch = np.concatenate(chans); m = np.concatenate(means); v = np.concatenate(variances)
    if m.max() < 1.5 * max(m.min(), 1e-9) and read_variance_dn2 is None:
        raise ValueError(f"photon transfer needs flat pairs at >= 2 exposure levels (tile means span "
                         f"{m.min():.1f}..{m.max():.1f} DN); add pairs at another exposure or give bias frames")
    if m.max() < 1.5 * max(m.min(), 1e-9):  # one level: anchor the intercept at the bias read variance
        k = float(np.sum(m * (v - read_variance_dn2)) / np.sum(m * m))
        c, keep, curvature = float(read_variance_dn2), np.ones(m.size, bool), 0.0
    else:
        k, c, curvature, keep = _photon_transfer(m, v, tile * tile, _distinct_levels([float(np.median(x)) for x in means]))
    if not k > 0:
        raise ValueError(f"photon transfer gave a non-positive gain K = {k:.4g} DN/e-: flats carry no shot noise "
                         f"(too dark?) or frames are not pairs at equal settings")
    per_channel = []
    for j in range(4):
        sel = keep & (ch == j)
        degree = 2 if curvature else 1  # the slope at zero
        per_channel.append(float(np.polyfit(m[sel], v[sel], degree)[degree - 1]) if np.unique(m[sel]).size > degree
                           else float("nan"))
    return GainEstimate(k=k, read_variance_dn2=c, k_per_channel=tuple(per_channel), tile_mean_dn=m[keep],
                        tile_variance_dn2=v[keep], n_tiles=int(keep.sum()), n_excluded=int(n_total - keep.sum()),
                        pair_means_dn=tuple(pair_means), curvature_per_dn=curvature)


HELD_Z = 5.0  # binomial sds of a tile's share of still pixels above a Gaussian's: pixels held at their wells
HELD_SLACK = 0.02  # and this share more (whole codes, tails)


def held_tiles(a, b, tile: int, variance, read_variance_dn2: float) -> np.ndarray:
    """Mask over ``pair_tile_stats``' tiles (channel-major) of a flat pair (packed (c, h, w), DN)
    where more pixels hold still between the two frames (|a - b| within 2 sd of the read
    noise's difference) than a Gaussian of the tile's own single-frame ``variance`` gives:
    pixels saturated at their full well, below the white level, which carry read noise only."""
    c, h, w = a.shape
    t = np.floor(2.0 * math.sqrt(2.0 * read_variance_dn2)) + 0.5  # whole-code differences
    ny, nx = h // tile, w // tile
    d = np.abs(np.asarray(a[:, : ny * tile, : nx * tile], np.float32) - np.asarray(b[:, : ny * tile, : nx * tile], np.float32))
    share = (d <= t).reshape(c, ny, tile, nx, tile).mean(axis=(2, 4)).ravel()
    var = np.asarray(variance, dtype=np.float64)
    expected = np.where(var > 0, special.erf(t / (2.0 * np.sqrt(np.maximum(var, 1e-300)))), 1.0)
    n = tile * tile
    return share > expected + HELD_Z * np.sqrt(expected * (1.0 - expected) / n) + HELD_SLACK


def _distinct_levels(means, rel=0.1) -> int:
    """Count of distinct levels among pair means (DN): means within ``rel`` of the previous are one."""
    out, last = 0, None
    for m in sorted(means):
        if last is None or m > last * (1 + rel):
            out, last = out + 1, m
    return out


def _clip_level(a, b, high: bool):
    """A clipping level, when many pixels share the extreme value (>= 0.01% and >= 10)."""
    both = (a, b)
    level = max(x.max() for x in both) if high else min(x.min() for x in both)
    count = sum(int(np.count_nonzero(x == level)) for x in both)
    if count >= max(10, 1e-4 * (a.size + b.size)):
        return level
    return None


# ----------------------------------------------------------------------------- one ISO
def _thin(x, y, n, seed):
    if x.size <= n:
        return x, y
    idx = np.random.default_rng(seed).choice(x.size, n, replace=False)
    return x[idx], y[idx]


def _censored_channels(channel_values, floor: float, sigma_r: float, max_samples, seed):
    """(read noise, (4,) locations in DN) of bias frames clipped from below at ``floor``: the
    censored fit (``censored_read_noise``) of each channel's values, pooled as the median
    lambda and the rms scales, less the row noise they hold (they are not row-corrected: a
    clip leaves no row mean to subtract)."""
    fits = [censored_read_noise(np.concatenate(v), floor, max_samples=max_samples and max_samples // 4, seed=seed + c)
            for c, v in enumerate(channel_values)]
    reads = [f[0] for f in fits]
    rms = lambda values: float(np.sqrt(np.mean(np.square(values))))  # noqa: E731
    sigma_g = rms([r.sigma_g for r in reads])
    shrink = float(np.sqrt(max(1.0 - sigma_r**2 / max(sigma_g**2, 1e-12), 0.25)))
    read = ReadNoiseEstimate(lam=float(np.median([r.lam for r in reads])), sigma_tl=shrink * rms([r.sigma_tl for r in reads]),
                             sigma_g=shrink * sigma_g, r2_tukey=float(np.mean([r.r2_tukey for r in reads])),
                             r2_gauss=float(np.mean([r.r2_gauss for r in reads])), ppcc_grid=reads[0].ppcc_grid,
                             n_samples=int(sum(r.n_samples for r in reads)), std_dn=shrink * sigma_g)
    return read, tuple(f[1] for f in fits)


def _load(item, what):
    array = item() if callable(item) else item
    return np.asarray(array)


def calibrate_iso(bias_frames, flat_pairs, iso: float, *, max_samples: int | None = 200_000,
                  saturation_dn: float | None = None, black_clip_dn: float | None = None,
                  tile: int = 32, seed: int = 0, progress=None, black_code=None) -> IsoParameters:
    """All stage-1 parameters at one ISO.

    Parameters
    ----------
    bias_frames : packed (4, h, w) bias frames in DN (or zero-argument callables returning
        one, so large frames are loaded one at a time).
    flat_pairs : (a, b) pairs of packed flats in DN (or callables), equal settings per pair.
    iso : the ISO of these frames.
    max_samples : values used by the PPCC read-noise fit, pooled over the bias frames.
    saturation_dn, black_clip_dn : clipping levels in DN (detected from the data if None).
    progress : optional callable(str) told about each step.
    black_code : the raw code of 0 DN per packed channel (R, G1, B, G2): with it, bits of the
        raw codes that never move (``stuck_bits.stuck_masks``) are found, and the read noise
        is fitted through them (``stuck_bits.fit_through_bits``) rather than by PPCC.

    Returns an :class:`IsoParameters` with K, sigma_TL, sigma_r, lambda, sigma_G and the
    colour bias (medians over bias frames where per frame); ``extra`` holds diagnostics.
    """
    if iso is None or not float(iso) > 0:
        raise ValueError(f"iso must be a positive number, got {iso!r}")
    iso = float(iso)
    bias_frames = list(bias_frames)
    if not bias_frames:
        raise ValueError(f"ISO {iso:g}: no bias frames; row and read noise need at least one")
    tell = progress or (lambda _msg: None)
    rows, biases, samples, shapes = [], [], [], []
    first_bias = lo = hi = extremes = None
    per_frame = max(1, (max_samples or 0) // len(bias_frames)) if max_samples else None
    floor, clipped, channel_values = None, [], [[] for _ in range(4)]  # a clip from below (``censored``)
    raw_codes = [[] for _ in range(4)]  # each channel's raw codes (a sample), where the black codes are given
    for i, item in enumerate(bias_frames):
        bias = _packed(_load(item, "bias"), f"ISO {iso:g} bias frame {i}")
        shapes.append(bias.shape)
        if bias.shape != shapes[0]:
            raise ValueError(f"ISO {iso:g}: bias frames differ in size: {shapes[0]} vs {bias.shape} (frame {i})")
        if i == 0:
            floor = black_floor(bias)
        without = _without_defects(bias)  # the defect lines found once per frame
        if floor is not None:  # each channel's values as they are: the censored fit's
            clipped.append(clipped_share(without[np.isfinite(without)], floor))
            for c in range(4):
                flat = without[c].ravel()
                at = np.flatnonzero(np.isfinite(flat))
                idx = sample_indices(at.size, per_frame and max(1, per_frame // 4), seed + 10 * i + c)
                at = at if idx is None else at[idx]
                channel_values[c].append((at, flat[at]))
        if black_code is not None:
            for c, codes in enumerate(raw_codes_of(without, black_code, None, per_frame and max(1, per_frame // 4), seed + 20 * i)):
                raw_codes[c].append(codes)
        color = _mean(without, (1, 2), keepdims=True)  # estimate_color_bias
        centered = without - color
        row = _row_noise(centered)  # estimate_row_noise
        rows.append(row)
        biases.append(color.ravel())
        r = (centered - row.row_means[[0, 0, 1, 1]][:, :, None]).ravel()  # row_corrected
        where = np.flatnonzero(np.isfinite(r))  # off the defect lines
        idx = sample_indices(where.size, per_frame, seed + i)
        where = where if idx is None else where[idx]
        samples.append((where, r[where]))
        if len(bias_frames) >= 3:  # each pixel's two highest and two lowest values, and their frames
            extremes = [pixel_extremes(e, r, i, sign) for e, sign in zip(extremes or (None, None), (1.0, -1.0))]
        if first_bias is None:
            first_bias, lo, hi = bias, bias.astype(np.float32), bias.astype(np.float32)
        else:
            np.minimum(lo, bias, out=lo, casting="unsafe")
            np.maximum(hi, bias, out=hi, casting="unsafe")
        tell(f"ISO {iso:g}: bias frame {i + 1}/{len(bias_frames)}")
    dead = stuck_outliers(lo, hi, first_bias).ravel() if len(bias_frames) >= 3 else None
    if floor is not None and dead is not None:  # the censored fit without the stuck and the hot pixels (no read noise)
        out = (dead | hot_under_clip(lo, first_bias).ravel()).reshape(4, -1)
        channel_values = [[v[~d[at]] for at, v in values] for values, d in zip(channel_values, out)]
    residual = np.concatenate([v if dead is None else v[~dead[w]] for w, v in samples])
    n_spikes = None
    if extremes:  # single-frame events (cosmic rays, charge bursts) are not read noise
        scale = 1.482602218505602 * float(np.median(np.abs(residual - np.median(residual))))
        (top, second, frame), (low, second_low, low_frame) = extremes  # the lows as the highs of -r
        gap, low_gap = top - second, low - second_low
        bright, dark = gap > SPIKE_Z * max(scale, 1e-9), low_gap > SPIKE_Z * max(scale, 1e-9)
        side = spike_side(int(bright.sum()), int(dark.sum()))
        if side:  # impulses: the events of the side in excess leave (bright ones, or dark ones: dropouts)
            hits, size, others = (bright, gap, dark) if side > 0 else (dark, low_gap, bright)
            spike = np.zeros_like(hits)
            spike[hits] = beyond_dark(size[hits], int(others.sum()))
            out_bright, out_dark = (spike, np.zeros_like(spike)) if side > 0 else (np.zeros_like(spike), spike)
        else:  # events of both signs as many: the read noise's tails, but for a far population (bit errors) of both
            cut = far_cut(np.concatenate([gap[bright], low_gap[dark]]), SPIKE_Z * max(scale, 1e-9))
            out_bright, out_dark = bright & (gap >= cut), dark & (low_gap >= cut)
        n_spikes = int(out_bright.sum() + out_dark.sum())
        if n_spikes:
            keep = lambda i, w: ~((out_bright[w] & (frame[w] == i)) | (out_dark[w] & (low_frame[w] == i))  # noqa: E731
                                  | (dead[w] if dead is not None else False))
            residual = np.concatenate([v[keep(i, w)] for i, (w, v) in enumerate(samples)])
    read_var = float(np.median([r.read_variance_dn2 for r in rows]))
    sigma_r = float(np.median([r.sigma_r for r in rows]))
    censored = None
    stuck = None
    if floor is None:
        read = estimate_read_noise(residual, max_samples=max_samples, seed=seed)
        if black_code is not None:  # stuck bits: the fit through them (of the codes, row offsets and all)
            read, sigma_r, stuck = through_stuck_bits([np.concatenate(c) for c in raw_codes], read, sigma_r)
    else:  # clipped from below: row offsets move a row's mean by the unclipped share of them only
        sigma_r /= max(1.0 - float(np.median(clipped)), 0.05)
        read, location = _censored_channels(channel_values, floor, sigma_r, max_samples, seed)
        read_var = read.sigma_g**2
        censored = {"floor_dn": floor, "fraction": float(np.median(clipped)), "location_dn": location}
    tell(f"ISO {iso:g}: read noise fitted")
    pairs = [tuple(_packed(_load(x, "flat"), f"ISO {iso:g} flat pair {j}") for x in pair) for j, pair in enumerate(flat_pairs)]
    for j, (a, b) in enumerate(pairs):
        if a.shape != shapes[0] or b.shape != shapes[0]:
            raise ValueError(f"ISO {iso:g}: flat pair {j} has size {a.shape}/{b.shape}, bias frames {shapes[0]}")
    if not pairs:
        raise ValueError(f"ISO {iso:g}: no flat pairs; the gain K needs flat-field pairs at equal settings")
    total_read_var = read_var + sigma_r**2
    gain = estimate_gain(pairs, tile=tile, saturation_dn=saturation_dn, black_clip_dn=black_clip_dn,
                         read_variance_dn2=total_read_var)
    tell(f"ISO {iso:g}: gain K = {gain.k:.4g} DN/e-")
    color = np.median(np.stack(biases), axis=0) if censored is None else np.asarray(censored["location_dn"])
    extra = {
        "black_floor": censored,  # a clip from below (None: none): its level, the share of values on it
        "stuck_bits": stuck,  # bits of every raw code that never move (None: none, or no black codes given)
        "r2_tukey": read.r2_tukey,
        "r2_gauss": read.r2_gauss,
        "ppcc_grid": [list(p) for p in read.ppcc_grid],
        "read_samples": read.n_samples,
        "read_std_dn": read.std_dn,
        "shapiro_p": [r.shapiro_p for r in rows],
        "sigma_r_per_frame": [r.sigma_r for r in rows],
        "read_variance_dn2": read_var,
        "ptc_intercept_dn2": gain.read_variance_dn2,
        "ptc_curvature_per_dn": gain.curvature_per_dn,
        "bias_read_plus_row_variance_dn2": total_read_var,
        "k_per_channel": list(gain.k_per_channel),
        "ptc_tiles": gain.n_tiles,
        "ptc_tiles_excluded": gain.n_excluded,
        "flat_pair_means_dn": list(gain.pair_means_dn),
        "color_bias_per_frame_dn": [b.tolist() for b in biases],
        "banding": banding_ratios(first_bias[1]),
        "n_bias": len(bias_frames),
        "dead_pixels": int(dead.sum()) if dead is not None else None,  # stuck outliers left out of the read-noise fit
        "spikes": n_spikes,  # single-frame events left out of it (None: fewer than 3 frames)
        "n_flat_pairs": len(pairs),
        # Kept for the report's figures, left out of report.json (leading underscore).
        "_residual_sample": subsample(residual, 20_000, seed),
        "_ptc": _thin(gain.tile_mean_dn, gain.tile_variance_dn2, 5000, seed),
    }
    return IsoParameters(iso=iso, k=gain.k, sigma_tl=read.sigma_tl, sigma_r=sigma_r, lam=read.lam,
                         sigma_g=read.sigma_g, color_bias_dn=tuple(float(v) for v in color), extra=extra)
