"""Noise effects, one physical stage per module; importing this package registers them
(in this order: the paper's stages, then the effects the closed loop can add)."""
from .base import EFFECTS, DrawContext, NoiseEffect, register  # noqa: F401
from . import color_bias, quantization, read_noise, row_noise, shot_noise  # noqa: F401
from . import column_noise, dark_shading, hot_pixels, dark_hot_pixels, dark_clusters, dark_columns, dark_rows, defect_lines, black_clip, frame_black_level, tap_black, black_drift, bank_offset, bank_noise, dark_offset, dark_noise, gain_noise, gain_defects, prnu, charge_sharing, column_gain, row_gain, tap_gain, line_gain, frame_gain, dark_current, amp_glow, dark_drift, charge_trap, gain_nonlinearity, crosstalk, frame_noise, banding, column_banding, diagonal_banding, row_pattern, row_tail, row_channel, read_map, shared_pixel, telegraph, dark_telegraph, noisy_pixels, noisy_columns, column_telegraph, row_telegraph, impulses, dead_pixels, row_drift, column_drift, row_repeat, row_burst, adc_dnl, stuck_bit  # noqa: F401
from . import low_frequency, fixed_field, code_map, read_distribution, line_profile, gain_grid  # noqa: F401  (measured fallbacks, tried last)
