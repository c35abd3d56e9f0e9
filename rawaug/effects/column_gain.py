"""Column gain non-uniformity (ColGain): each sensor column's amplifier has its own gain.

Physics: a column-parallel readout amplifies (and converts) every column through circuits of
its own, whose gains differ by a fraction of a per cent. The photo signal and its shot noise
are multiplied by the column's gain: vertical stripes that grow in proportion to the signal,
invisible in bias frames. EMVA 1288 (Release 4) splits PRNU into this column part, a row part
and the pixel part (``PRNU``); ``Col`` is the column offsets, the same at every signal.

Stage (DN, after shot noise and ``NonLin``, before read noise): ``s -> s (1 + sigma g[X])``
with ``g`` a seeded standard normal per sensor column ``X`` (both channels of the column),
the same in every frame. ``sigma`` does not depend on ISO.

Profile entry::  ``ColGain: {seed: 67, sigma: 0.005}``  (fraction of the signal)

Detected by ``fixed_col_excess`` on flat stacks (the stack mean's column means vary more than
pixels alone make them). Estimated by ``estimate``: the variance of the flat stack mean's
column means relative to the level (``line_mean_variance``: from neighbouring columns, so a
smooth illumination does not count) in excess of the model's. Bias and dark frames cannot
show it.
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import line_mean_variance
from .base import PHOTON, NoiseEffect, pattern_key, register
from .k_records import _number, check_gain_pattern

STATISTICS = ("fixed_col_excess",)


@register
class ColumnGain(NoiseEffect):
    token = "ColGain"
    order = PHOTON + 30  # after shot noise (its column's amplifier), before read noise
    flag = L.COL_GAIN
    columns = ("colgain_sigma",)

    def draw(self, ctx):
        return {"colgain_sigma": ctx.k.new_full((ctx.k.shape[0],), float(self.profile.effects[self.token]["sigma"]))}

    def pattern_streams(self):
        return {"colgain_pattern": pattern_key(self.profile.effects[self.token]["seed"], self.token)}

    @classmethod
    def validate_params(cls, params):
        if isinstance(params, dict):
            _number(params.get("sigma"), f"{cls.token}.sigma")  # required
        check_gain_pattern(cls.token, params, ("sigma",))


def column_rel_var(frames, level_dn) -> float:
    """Variance of the stack mean's column means relative to each channel's level
    (``line_mean_variance``, neighbouring columns), mean over the channels: the squared
    relative column pattern, plus what pixels and temporal noise leave in a column mean."""
    level = np.broadcast_to(np.asarray(level_dn, dtype=np.float64), (4,))
    var = line_mean_variance(np.asarray(frames, dtype=np.float64).mean(axis=0), axis=1)  # (4,) DN^2
    return float(np.mean(var / np.maximum(level, 1e-12) ** 2))


def estimate(frames, synthesized, k: float, level_dn=None, seed: int = 67, **_) -> dict:
    """ColGain from a flat stack (N, 4, h, w) in DN at clean level ``level_dn`` (DN, scalar or
    per channel), against stacks of the same shape synthesized by the current model."""
    if level_dn is None or not synthesized:
        raise ValueError("ColGain needs a flat stack with its clean level level_dn (DN), against syntheses")
    base = float(np.mean([column_rel_var(s, level_dn) for s in synthesized]))
    return {"seed": int(seed), "sigma": float(np.sqrt(max(column_rel_var(frames, level_dn) - base, 0.0)))}


def combine(records: list[dict]) -> dict:
    """One gain pattern from the flat stacks (every ISO and level: the same columns): their
    variances averaged."""
    return {"seed": records[0]["seed"], "sigma": float(np.sqrt(np.mean([r["sigma"] ** 2 for r in records])))}


def empty(params) -> bool:
    """True when the gains do not vary (sigma 0): it would add nothing."""
    return float(params["sigma"]) == 0.0
