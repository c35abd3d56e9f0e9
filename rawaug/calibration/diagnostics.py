"""Anomalies of real bias frames that the noise model does not describe, reported as
warnings (never errors): black clipping, missing ADC codes, hot pixels and columns,
constant (dead) rows, column banding, non-Gaussian row offsets."""
from __future__ import annotations

import warnings

import numpy as np

from ..io import Frame
from .stage1 import (banding_ratios, centered_spectrum, estimate_color_bias, estimate_quantization_step,
                     estimate_read_noise, estimate_row_noise, missing_code_fraction, read_residual)


class CalibrationWarning(UserWarning):
    """Something in the measured frames that biases the calibration or is outside the model."""


def frame_anomalies(frame: Frame) -> list[str]:
    """Human-readable anomalies of one bias frame (raw codes), without warning."""
    where = frame.path or "bias frame"
    codes = np.asarray(frame.mosaic)
    black = np.asarray(frame.black_packed())
    notes = []
    low = float(codes.min())
    at_low = float(np.mean(codes == low))
    if at_low > 1e-3 and low <= float(black.min()):
        notes.append(f"{where}: {100 * at_low:.1f}% of pixels sit at code {low:g} (<= black {float(black.min()):g}): "
                     "the frame is black-clipped: the negative half of the read noise is lost (a clip found in the bias "
                     "frames is fitted around: censored read-noise fit, report section on clipped bias frames)")
    at_white = float(np.mean(codes >= frame.white_level))
    if at_white > 0:
        notes.append(f"{where}: {100 * at_white:.3f}% of pixels at or above white {frame.white_level:g}")
    missing = missing_code_fraction(codes)
    if missing > 0.05:
        notes.append(f"{where}: {100 * missing:.0f}% of the codes between the 1st and 99th percentile never occur "
                     "(missing ADC codes or a digital gain); quantization is not uniform")
    med = float(np.median(codes))
    mad = float(np.median(np.abs(codes - med))) * 1.4826 or 1.0
    hot = float(np.mean(codes > med + 20 * mad))
    if hot > 1e-4:
        notes.append(f"{where}: {100 * hot:.2f}% hot pixels (> median + 20 robust sigma)")
    cols = codes.mean(axis=0)
    cmed = float(np.median(cols))
    cmad = float(np.median(np.abs(cols - cmed))) * 1.4826 or 1e-6
    bad_cols = np.flatnonzero(np.abs(cols - cmed) > 10 * cmad)
    if bad_cols.size:
        notes.append(f"{where}: {bad_cols.size} column(s) with an outlying mean (> 10 robust sigma), e.g. x = "
                     f"{bad_cols[:8].tolist()}: fixed-pattern column defects are not in the model")
    const_rows = np.flatnonzero(codes.std(axis=1) == 0)
    if const_rows.size:
        notes.append(f"{where}: {const_rows.size} constant row(s) (no noise at all), e.g. y = {const_rows[:8].tolist()}")
    return notes


def analyse_bias_frame(frame: Frame, *, max_samples: int | None = 200_000, emit: bool = True) -> dict:
    """Stage-1 statistics of one real bias/dark frame (no flats needed: no K), plus anomalies.

    Returns a dict with sigma_r, shapiro_p, lambda, sigma_tl, sigma_g, R^2 of both probability
    plots, colour bias (DN), quantization step (DN), banding ratios, the centralized spectrum
    (``spectrum``, log10 power) and ``warnings`` (also emitted as :class:`CalibrationWarning`
    when ``emit``). Defective pixels stay in: the numbers describe the frame as it is.
    """
    notes = frame_anomalies(frame)
    bias = frame.packed_dn()
    row = estimate_row_noise(bias)
    read = estimate_read_noise(read_residual(bias, row.row_means), max_samples=max_samples)
    band = banding_ratios(frame.mosaic.astype(np.float64))
    if band["column"] > 3:
        notes.append(f"{frame.path or 'bias frame'}: column banding (power on the column axis {band['column']:.1f}x "
                     "white noise): column noise is not in the ELD model")
    if row.shapiro_p < 1e-3:
        notes.append(f"{frame.path or 'bias frame'}: row means are not Gaussian (Shapiro-Wilk p = {row.shapiro_p:.2g})")
    if read.r2_tukey < 0.99:
        notes.append(f"{frame.path or 'bias frame'}: Tukey-lambda probability plot fits poorly (R^2 = {read.r2_tukey:.4f})")
    if read.lam <= -0.5 + 1e-9 or read.lam >= 1.0 - 1e-9:
        notes.append(f"{frame.path or 'bias frame'}: Tukey lambda at the edge of the search range ({read.lam:g}): "
                     "the residual is not Tukey-lambda shaped (defects or clipping dominate)")
    if emit:
        for note in notes:
            warnings.warn(note, CalibrationWarning, stacklevel=2)
    return {
        "sigma_r": row.sigma_r, "shapiro_p": row.shapiro_p, "read_variance_dn2": row.read_variance_dn2,
        "lambda": read.lam, "sigma_tl": read.sigma_tl, "sigma_g": read.sigma_g, "r2_tukey": read.r2_tukey,
        "r2_gauss": read.r2_gauss, "color_bias_dn": estimate_color_bias(bias).tolist(),
        "quantization_step_dn": estimate_quantization_step(frame.mosaic), "banding": band,
        "spectrum": centered_spectrum(frame.mosaic, max_size=512), "ppcc_grid": [list(p) for p in read.ppcc_grid],
        "warnings": notes,
    }
