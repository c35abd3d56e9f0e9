"""Column noise (Col): offsets shared by every pixel of a sensor column.

Physics: each column of a CMOS sensor has its own amplifier and ADC; their offsets add
a fixed column pattern (the same in every frame) and a temporal part (new in every
frame). Packed channels (R, G2) share one sensor column, (G1, B) the other.

Synthesis: ``fixed_dn * c_fixed[col] + sigma_dn * c_frame[col]`` with standard-normal
``c_fixed`` drawn once from ``seed`` (fixed pattern) and ``c_frame`` drawn per frame.

Profile entry (per-K records, nearest record in log K)::

    Col: {seed: 7, k: [K, ...], sigma_dn: [temporal std, ...], fixed_dn: [fixed std, ...]}

Detected by the statistics ``col_excess`` (per-frame column-mean variance over what
independent pixels give) and ``fixed_col_excess`` (the same on the stack mean), see
``rawaug.statistics``.
Estimated by ``estimate``: the excess of those two statistics over the current model.
With a single frame the fixed and temporal parts cannot be told apart; all of the
excess is then recorded as temporal (``sigma_dn``).
"""
from __future__ import annotations

import numpy as np
from ..engine import layout as L
from ..statistics import line_mean_variance
from .base import BANDING, NoiseEffect, pattern_key, register
from .k_records import check_seed, validate_records, value_at_k

STATISTICS = ("col_excess", "fixed_col_excess")
AMPLITUDES = ("sigma_dn", "fixed_dn")  # corrected by simulation under a clip (rawaug.loop.clip_correction)
SHARES_READ_NOISE_UNDER_CLIP = True  # the censored read-noise fit took the pattern's spread (rawaug.loop.frames_loop)


@register
class ColumnNoise(NoiseEffect):
    token = "Col"
    order = BANDING
    flag = L.COL
    columns = ("col_sigma", "col_fixed")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {"col_sigma": value_at_k(p, "sigma_dn", ctx.k), "col_fixed": value_at_k(p, "fixed_dn", ctx.k)}

    def pattern_streams(self):
        return {"col_pattern": pattern_key(self.profile.effects[self.token]["seed"], self.token)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn", "fixed_dn"), nonnegative=("sigma_dn", "fixed_dn"))
        check_seed(cls.token, params)


def _column_parts(frames):
    """(temporal variance, fixed variance) of column means, DN^2, averaged over channels,
    from neighbouring-column differences (smooth shading does not count)."""
    mean_map = frames.mean(axis=0)
    fixed_var = float(line_mean_variance(mean_map, 1).mean())
    if frames.shape[0] < 2:
        return float(line_mean_variance(frames, 2).mean()), 0.0
    n = frames.shape[0]
    temporal_var = float(line_mean_variance(frames - mean_map[None], 2).mean()) * n / (n - 1)
    # the fixed part of a stack mean still holds temporal / N
    return temporal_var, fixed_var


def estimate(frames, synthesized, k: float, seed: int = 7, **_) -> dict:
    """Column-noise record at gain ``k`` from measured frames (N, 4, h, w), DN.

    ``synthesized`` is a list of stacks of the same shape from the current model; the
    column variance it already explains is subtracted. With N = 1 everything is temporal.
    """
    frames = np.asarray(frames, dtype=np.float64)
    t_meas, f_meas = _column_parts(frames)
    base = [_column_parts(np.asarray(s, dtype=np.float64)) for s in synthesized]
    t_base = float(np.mean([b[0] for b in base]))
    f_base = float(np.mean([b[1] for b in base]))
    n = frames.shape[0]
    if n < 2:
        return {"seed": int(seed), "k": [float(k)], "sigma_dn": [float(np.sqrt(max(t_meas - t_base, 0.0)))], "fixed_dn": [0.0]}
    sigma2 = max(t_meas - t_base, 0.0)
    # stack-mean column variance = fixed^2 + (temporal column variance) / N
    fixed2 = max(f_meas - f_base - sigma2 / n, 0.0)
    return {"seed": int(seed), "k": [float(k)], "sigma_dn": [float(np.sqrt(sigma2))], "fixed_dn": [float(np.sqrt(fixed2))]}
