"""Noise effects, one physical stage per module; importing this package registers them."""
from .base import EFFECTS, DrawContext, NoiseEffect, register  # noqa: F401
from . import color_bias, quantization, read_noise, row_noise, shot_noise  # noqa: F401
from .read_noise import tukey_lambda_icdf, tukey_lambda_variance  # noqa: F401
from . import black_clip, column_noise, dark_shading, frame_black_level, hot_pixels, prnu  # noqa: F401
