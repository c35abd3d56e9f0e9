"""Fixed row pattern (RowFix): one offset per sensor row, the same in every frame.

Physics: each sensor row is reset and read through its own row driver; their mismatch gives
every row a fixed offset (row fixed-pattern noise). The ELD row noise ``R`` is new in every
frame; calibration reads sigma_r from each frame's row means, so it counts a fixed row
pattern as temporal row noise.

Synthesis: ``fixed_dn * r[row]`` on both channels of a sensor row, ``r`` standard normal,
keyed by the profile's seed, the sample's sensor instance and the row.

Profile entry (per-K records)::  ``RowFix: {seed: 31, k: [K, ...], fixed_dn: [...]}``

Detected by ``fixed_row_excess`` (``row_excess`` of the stack mean) and ``row_tone`` (a fixed
pattern's periodogram does not average out over the frames). Estimated by ``estimate``: the
stack mean's sensor-row variance over the model's, less what the temporal row variance the
model over- or under-states leaves in a mean of N frames. Judged with sigma_r re-fitted.
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import difference_scale, sensor_row_means
from .base import BANDING, NoiseEffect, pattern_key, register
from .k_records import all_zero, check_seed, combine_sigma, validate_records, value_at_k

STATISTICS = ("fixed_row_excess", "row_tone")
AMPLITUDES = ("fixed_dn",)  # corrected by simulation under a clip (rawaug.loop.clip_correction)
SHARES_ROW_NOISE = True  # calibration gave the fixed rows' variance to sigma_r


@register
class RowPattern(NoiseEffect):
    token = "RowFix"
    order = BANDING
    flag = L.ROW_FIX
    columns = ("rowfix_sigma",)

    def draw(self, ctx):
        return {"rowfix_sigma": value_at_k(self.profile.effects[self.token], "fixed_dn", ctx.k)}

    def pattern_streams(self):
        return {"row_pattern": pattern_key(self.profile.effects[self.token]["seed"], self.token)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("fixed_dn",), nonnegative=("fixed_dn",))
        check_seed(cls.token, params)


def _row_variance(rows) -> float:
    """Variance across sensor rows of (..., 2h) row means from neighbouring-row differences
    (robust: ``difference_scale``^2 / 2; smooth shading does not count), mean over the leading axes, DN^2."""
    return float(np.mean(difference_scale(np.diff(rows, axis=-1)) ** 2) / 2.0)


def _row_parts(frames):
    """(temporal, stack-mean) sensor-row variance of a stack (N >= 2), DN^2."""
    n = frames.shape[0]
    mean_map = frames.mean(axis=0, keepdims=True)
    temporal = _row_variance(sensor_row_means(frames - mean_map)) * n / (n - 1)
    return temporal, _row_variance(sensor_row_means(mean_map))


def estimate(frames, synthesized, k: float, seed: int = 31, **_) -> dict:
    """RowFix record at gain ``k`` from a stack (N >= 2, 4, h, w) in DN."""
    frames = np.asarray(frames, dtype=np.float64)
    n = frames.shape[0]
    if n < 2 or not synthesized:
        raise ValueError("RowFix needs a stack of >= 2 frames and syntheses of it")
    t_meas, f_meas = _row_parts(frames)
    base = [_row_parts(np.asarray(s, dtype=np.float64)) for s in synthesized]
    t_base, f_base = float(np.mean([b[0] for b in base])), float(np.mean([b[1] for b in base]))
    # stack-mean row variance = fixed^2 + temporal / N
    fixed2 = max(f_meas - f_base - (t_meas - t_base) / n, 0.0)
    return {"seed": int(seed), "k": [float(k)], "fixed_dn": [float(np.sqrt(fixed2))]}


def combine(records: list[dict]) -> dict:
    """One record per gain: the stacks at one K (bias, darks, flats) averaged in variance."""
    return {"seed": int(records[0]["seed"]), **combine_sigma(records, "fixed_dn")}


def empty(params) -> bool:
    """True when every amplitude is 0: it would add nothing."""
    return all_zero(params, ("fixed_dn",))
