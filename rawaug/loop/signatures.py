"""The curve behind a statistic: what a step's figure shows of the residual that drove it.

A statistic of the battery is one number; a person checks it against the curve it sums up:
the radial 2-D power spectrum (``psd2d_lowfreq``), the spectrum of the row or column means
(row / column noise and shading), the histogram of the pixel values (read-noise shape,
clipping), of the codes one by one (missing codes), of the stack-mean map (dark signal,
DSNU, PRNU, hot pixels), of the per-pixel temporal std, the sorted line means (defect
lines), the sorted sensor columns' pixel noise (noisy columns), the step variance at each gap between
sensor lines (readout taps), the sorted frame means (black-level error; over their level, a flat's gain jitter),
the frame means in the order taken (drift) or the correlation of neighbouring
pixels' temporal noise at raw lags (crosstalk), of pairs in one tile and in adjacent tiles
(a shared readout), the periodogram of the sensor-row or -column means (banding) or the
largest bins of the 2-D periodogram (diagonal banding), or the
white temporal variance per channel and block (read-noise map). ``step_signature`` gives the
measured curve and the model's before and after a step
(mean and spread over its syntheses), on the measured curve's grid; ``pooled_signature``
puts the curves of the stacks a pooled statistic was judged on end to end.
"""
from __future__ import annotations

import numpy as np

from ..statistics import (CURVE_LAGS, col_tone_spectrum, column_pixel_noise, diag_tone_spectrum, flat_log_mosaic, frame_row_variances,
                          gain_steps,
                          lag_covariances, read_noise_profile,
                          row_step_scan, row_tone_spectrum, sensor_col_means, sensor_row_means, statistic_view, tap_steps, trimmed_line_means,
                          tile_pair_covariances)

KIND = {
    "psd2d_lowfreq": "radial_spectrum",
    "row_lowfreq": "row_spectrum", "row_excess": "row_spectrum", "row_noise_spread": "row_spectrum",
    "col_lowfreq": "col_spectrum", "col_excess": "col_spectrum", "fixed_col_excess": "mean_col_spectrum",
    "fixed_row_excess": "mean_row_spectrum",
    "mean_dn": "mean_map_histogram", "fixed_std": "mean_map_histogram", "fixed_pixel_var": "mean_map_histogram",
    "flat_fixed_rel": "mean_map_histogram",
    "flat_linearity": "mean_map_histogram", "channel_linearity": "mean_map_histogram",
    "temporal_std": "temporal_histogram",
    "frame_mean_std": "frame_means", "frame_mean_common_cov": "frame_means", "frame_mean_lag1": "frame_sequence",
    "hot_fraction": "mean_map_histogram", "missing_codes": "code_histogram", "code_dnl": "code_histogram", "defect_lines": "line_means",
    "neighbour_corr": "lag_correlations", "row_tone": "row_tone_spectrum",
    "col_tone": "col_tone_spectrum", "diag_tone": "diag_tone_bins",
    "read_noise_spread": "read_noise_profile", "tile_corr": "tile_correlations", "flicker_fraction": "temporal_histogram", "noisy_fraction": "temporal_histogram",
    "stuck_fraction": "temporal_histogram", "spike_fraction": "temporal_histogram", "frame_noise_spread": "temporal_histogram",
    "col_flicker_fraction": "col_tone_spectrum", "flat_gain_spread": "frame_means_relative",
    "noisy_col_fraction": "column_noise", "row_flicker_fraction": "row_tone_spectrum", "tap_step_ratio": "tap_steps",
    "gain_step_z": "gain_steps", "frame_row_spread": "frame_row_levels",
    "row_step_z": "frame_steps",
}  # every other statistic: the histogram of the pixel values
LABEL = {
    "radial_spectrum": ("radial frequency (cycles/pixel)", "power (DN^2)", True),
    "row_spectrum": ("frequency along columns (cycles/row)", "row-mean power (DN^2)", True),
    "col_spectrum": ("frequency along rows (cycles/column)", "column-mean power (DN^2)", True),
    "mean_col_spectrum": ("frequency along rows (cycles/column)", "stack-mean column power (DN^2)", True),
    "mean_row_spectrum": ("frequency along columns (cycles/row)", "stack-mean row power (DN^2)", True),
    "pixel_histogram": ("pixel value about its frame-channel mean (DN)", "fraction of pixels", True),
    "mean_map_histogram": ("stack-mean map (DN)", "fraction of pixels", True),
    "temporal_histogram": ("per-pixel std across frames (DN)", "fraction of pixels", True),
    "frame_means": ("frame (sorted)", "frame mean about the stack's (DN)", False),
    "frame_means_relative": ("frame (sorted within its stack)", "frame mean about the stack's, over it", False),
    "frame_sequence": ("frame (in the order taken)", "frame mean about the stack's (DN)", False),
    "frame_row_levels": ("frame (sorted)", "variance of its sensor-row means, temporal (DN^2)", True),
    "frame_steps": ("frame (sorted)", "its largest step down the sensor rows over its standard error", False),
    "code_histogram": ("code (DN), one bin each, about the median", "fraction of pixels", False),
    "line_means": ("sensor line (sorted)", "line mean of the stack mean about the median (DN)", False),
    "column_noise": ("sensor column (sorted)", "its pixels' median temporal variance, column means out (DN^2)", True),
    "tap_steps": ("gap between sensor columns, then between sensor rows (16 lines from the ends left out)",
                  "temporal variance of the step between the medians either side (DN^2)", True),
    "gain_steps": ("gap between sensor columns, then between sensor rows (5 lines from the ends left out)",
                   "step of the stack mean's log line profile over its noise (a cubic plus a step, up to 32 lines a side)", False),
    "row_tone_spectrum": ("frequency (cycles per sensor row)", "temporal sensor-row-mean power (DN^2)", True),
    "col_tone_spectrum": ("frequency (cycles per sensor column)", "temporal sensor-column-mean power (DN^2)", True),
    "diag_tone_bins": ("bin of the 2-D periodogram off both axes, largest first", "power over the ring of bins around it", True),
    "read_noise_profile": ("channel 1-4, then row block 1-8, then column block 1-8", "white temporal variance (DN^2)", False),
    "tile_correlations": ("raw lag (0,1) (1,0) (1,1) (1,-1): pairs in one tile, then in adjacent tiles",
                          "correlation of the temporal residual", False),
    "lag_correlations": ("raw lag, in order " + " ".join(f"({dy},{dx})" for dy, dx in CURVE_LAGS),
                         "correlation of the temporal residual", False),
}
CODES = 24  # code_histogram: codes either side of the median
DIAG_BINS = 64  # diag_tone_bins: the largest bins of the 2-D periodogram
BINS = 48


def _centered(frames):
    return frames - frames.mean(axis=(2, 3), keepdims=True)


def _power(profiles):
    """Mean power spectrum (DC left out) of 1-D profiles along the last axis."""
    p = np.abs(np.fft.rfft(profiles - profiles.mean(axis=-1, keepdims=True), axis=-1)) ** 2 / profiles.shape[-1]
    return p.reshape(-1, p.shape[-1])[:, 1:].mean(axis=0)


def _log_binned(freq, power, lowest):
    """Mean power in log-spaced frequency bins from ``lowest`` to Nyquist (0.5), so the low
    frequencies the battery's statistics read are resolved; bins holding no frequency of
    this frame size are left out."""
    edges = np.geomspace(lowest, 0.5 * (1 + 1e-9), BINS // 2 + 1)
    idx = np.digitize(freq, edges) - 1
    keep = (freq > 0) & (idx >= 0) & (idx < len(edges) - 1)
    sums = np.bincount(idx[keep], weights=power[keep], minlength=len(edges) - 1)
    counts = np.bincount(idx[keep], minlength=len(edges) - 1)
    full = counts > 0
    return np.sqrt(edges[1:] * edges[:-1])[full], sums[full] / counts[full]


def _radial(frames):
    c = _centered(frames)
    p = (np.abs(np.fft.rfft2(c, axes=(2, 3))) ** 2).mean(axis=(0, 1)) / (c.shape[2] * c.shape[3])
    r = np.hypot(np.fft.fftfreq(c.shape[2])[:, None], np.fft.rfftfreq(c.shape[3])[None, :])
    return _log_binned(r.ravel(), p.ravel(), 1.0 / max(c.shape[2:]))


def _values(kind, frames):
    """The values a histogram kind counts."""
    if kind == "code_histogram":
        return frames.ravel()
    if kind == "mean_map_histogram":
        return frames.mean(axis=0).ravel()
    if kind == "temporal_histogram":
        return frames.std(axis=0, ddof=1).ravel()
    return _centered(frames).ravel()


def curve(kind: str, frames, edges=None):
    """(x, y) of ``kind`` for a stack (N, 4, h, w) in DN; histograms on ``edges``."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind == "radial_spectrum":
        return _radial(frames)
    if kind in ("row_spectrum", "col_spectrum", "mean_col_spectrum", "mean_row_spectrum"):
        view = frames.mean(axis=0, keepdims=True) if kind.startswith("mean_") else frames
        rows = kind in ("row_spectrum", "mean_row_spectrum")
        y = _power(view.mean(axis=3 if rows else 2))
        n = frames.shape[2 if rows else 3]
        return _log_binned(np.fft.rfftfreq(n)[1:], y, 1.0 / n)
    if kind == "line_means":  # rows and columns of the raw view: a defect line stands out of the sorted curve
        m = frames.mean(axis=0)
        lines = np.concatenate([m.mean(axis=2).ravel(), m.mean(axis=1).ravel()])
        return np.arange(1, lines.size + 1, dtype=np.float64), np.sort(lines - np.median(lines))
    if kind == "column_noise":  # a noisy column stands out of the sorted curve
        v = np.sort(column_pixel_noise(frames))
        return np.arange(1, v.size + 1, dtype=np.float64), v
    if kind == "tap_steps":  # a readout tap's edge stands out at its gap
        steps = np.concatenate([tap_steps(sensor_col_means(frames)), tap_steps(sensor_row_means(frames))])
        steps = steps[np.isfinite(steps)]
        return np.arange(1, steps.size + 1, dtype=np.float64), steps
    if kind == "gain_steps":  # a readout tap's gain steps the flat at its edge
        mosaic = flat_log_mosaic(frames)
        steps = np.concatenate([gain_steps(trimmed_line_means(mosaic, 0)), gain_steps(trimmed_line_means(mosaic, 1))])
        steps = steps[np.isfinite(steps)]
        return np.arange(1, steps.size + 1, dtype=np.float64), steps
    if kind == "row_tone_spectrum":
        return row_tone_spectrum(frames)
    if kind == "col_tone_spectrum":
        return col_tone_spectrum(frames)
    if kind == "diag_tone_bins":  # a 2-D tone stands out of the bins that stand most above their neighbours
        _, _, p, local = diag_tone_spectrum(frames)
        p = np.sort(p / np.maximum(local, 1e-30))[::-1][:DIAG_BINS]
        return np.arange(1, p.size + 1, dtype=np.float64), p
    if kind == "lag_correlations":
        var, cov = lag_covariances(frames, CURVE_LAGS)
        return np.arange(1, len(CURVE_LAGS) + 1, dtype=np.float64), cov / max(var, 1e-12)
    if kind == "read_noise_profile":
        y = read_noise_profile(frames)
        return np.arange(1, y.size + 1, dtype=np.float64), y
    if kind == "tile_correlations":
        var, within, across = tile_pair_covariances(frames)
        return np.arange(1, 9, dtype=np.float64), np.concatenate([within, across]) / max(var, 1e-12)
    if kind == "frame_means":
        m = frames.mean(axis=(1, 2, 3))
        return np.arange(1, len(m) + 1, dtype=np.float64), np.sort(m - m.mean())
    if kind == "frame_means_relative":  # a flat's frame means over its level: stacks of any level side by side
        m = frames.mean(axis=(1, 2, 3))
        return np.arange(1, len(m) + 1, dtype=np.float64), np.sort(m - m.mean()) / max(abs(float(m.mean())), 1e-12)
    if kind == "frame_row_levels":  # a frame of stronger row noise stands out of the sorted curve
        v = np.sort(frame_row_variances(frames)[0])
        return np.arange(1, v.size + 1, dtype=np.float64), v
    if kind == "frame_steps":  # a frame whose black level steps stands out of the sorted curve
        z = np.sort(row_step_scan(frames)[0])
        return np.arange(1, z.size + 1, dtype=np.float64), z
    if kind == "frame_sequence":
        m = frames.mean(axis=(1, 2, 3))
        return np.arange(1, len(m) + 1, dtype=np.float64), m - m.mean()
    values = _values(kind, frames)
    counts, _ = np.histogram(values, bins=edges)
    return 0.5 * (edges[1:] + edges[:-1]), counts / max(1, values.size)


def step_signature(statistic: str, frames, before, after) -> dict:
    """Measured curve of ``statistic``'s kind for ``frames`` (N, 4, h, w) DN, and the mean
    and spread of the same curve over the syntheses ``before`` and ``after`` a step
    (each (n_synth, N, 4, h, w)); histograms share bins spanning the measured values."""
    kind = KIND.get(statistic, "pixel_histogram")
    view = statistic_view(statistic, frames)  # as the statistic reads them (defect lines, dead pixels)
    edges = None
    if kind == "code_histogram":
        mid = float(np.rint(np.median(view)))
        edges = np.arange(mid - CODES - 0.5, mid + CODES + 1.0)
    elif kind.endswith("histogram"):
        values = _values(kind, view)
        lo, hi = float(values.min()), float(values.max())
        edges = np.linspace(lo, hi if hi > lo else lo + 1.0, BINS + 1)
    x, measured = curve(kind, view, edges)
    out = {"statistic": statistic, "kind": kind, "x": x.tolist(), "measured": measured.tolist()}
    if kind.endswith("histogram"):  # a histogram of n values resolves fractions down to one value: 1 / n
        out["floor"] = 1.0 / max(1, _values(kind, view).size)
    for name, synth in (("before", before), ("after", after)):
        ys = np.array([curve(kind, statistic_view(statistic, s), edges)[1] for s in synth])
        out[name] = ys.mean(axis=0).tolist()
        out[name + "_std"] = ys.std(axis=0, ddof=1).tolist() if len(ys) > 1 else [0.0] * len(x)
    out["xlabel"], out["ylabel"], out["log_y"] = LABEL[kind]
    out["log_x"] = kind.endswith("spectrum") and not kind.endswith("tone_spectrum")
    out["distance_before"], out["distance_after"] = distance(out, "before"), distance(out, "after")
    return out


def pooled_signature(statistic: str, parts) -> dict:
    """``step_signature`` of a pooled statistic over the stacks it was judged on (``parts``:
    (frames, before, after) of each): their curves end to end (one pair's curve is 2 points;
    twenty pairs' are 40)."""
    sigs = [step_signature(statistic, *part) for part in parts]
    if sigs[0]["kind"].endswith("histogram"):
        raise ValueError(f"a pooled signature puts curves end to end, not histograms ({statistic}: {sigs[0]['kind']})")
    out = dict(sigs[0])
    for key in ("measured", "before", "before_std", "after", "after_std"):
        out[key] = [v for sig in sigs for v in sig[key]]
    out["x"] = [float(i) for i in range(1, len(out["measured"]) + 1)]
    out["pooled_over"] = len(parts)
    out["distance_before"], out["distance_after"] = distance(out, "before"), distance(out, "after")
    return out


FLOOR = 1e-9  # log curves: values below count as this


def _nearer_tail(fractions) -> np.ndarray:
    """Each bin's cumulative fraction from the nearer end of the histogram: the fraction of
    values at or below it left of the middle, at or above it right of it (the tails)."""
    y = np.asarray(fractions, dtype=np.float64)
    return np.minimum(np.cumsum(y), np.cumsum(y[::-1])[::-1])


def distance(sig: dict, which: str) -> float:
    """Mean absolute difference between the model's curve ``which`` and the measured one, in
    decades for log curves, in the curve's unit otherwise; spectra are on log-spaced frequency
    bins, so each octave weighs alike. A histogram of values (not of codes one by one) is
    compared by its cumulative tails (``_nearer_tail``), what a tail statistic counts: bin by
    bin, a sparse tail of a few values per bin is Poisson noise (an impulse model whose tail
    matched the frames' measured farther off there than none did). Fractions count from one
    of the histogram's values (``floor``, 1 / n)."""
    floor = max(FLOOR, float(sig.get("floor", 0.0)))
    tails = sig["kind"].endswith("histogram") and sig["kind"] != "code_histogram"
    prepare = _nearer_tail if tails else (lambda v: np.asarray(v, dtype=np.float64))
    f = (lambda v: np.log10(np.maximum(prepare(v), floor))) if sig["log_y"] else prepare
    d = np.abs(f(sig[which]) - f(sig["measured"]))
    d = d[np.isfinite(d)]
    return float(d.mean()) if d.size else float("nan")
