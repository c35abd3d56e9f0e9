"""Calibration: measured frames of a camera -> per-ISO parameters (stage 1) -> NoiseProfile (stage 2)."""
from .joint import IsoParameters, fit_joint, fit_log_linear, read_parameter_table, read_parameter_tables
from .stage1 import (
    GainEstimate, ReadNoiseEstimate, RowNoiseEstimate, calibrate_iso, estimate_color_bias, estimate_gain,
    estimate_read_noise, estimate_row_noise,
)

__all__ = [
    "IsoParameters", "fit_joint", "fit_log_linear", "read_parameter_table", "read_parameter_tables",
    "GainEstimate", "ReadNoiseEstimate", "RowNoiseEstimate", "calibrate_iso", "estimate_color_bias", "estimate_gain",
    "estimate_read_noise", "estimate_row_noise",
]
