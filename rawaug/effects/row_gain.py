"""Row gain (RowGain): each sensor row's gain on the photo signal differs, fixed and from frame to frame.

Physics: the pixels of a sensor row are selected, reset and transferred by drivers of their
own, whose mismatch gives each row a gain of its own (fixed); a column-parallel readout
converts every column of a row at once against one shared reference, such as the ramp of
single-slope ADCs, whose slope wanders from one row conversion to the next (new in every
frame). Either multiplies the photo signal and its shot noise of the whole row: horizontal
stripes that grow in proportion to the signal, invisible in bias frames. It is ``ColGain``
along the rows; ``RowFix`` and ``R`` are the row offsets, the same at every signal.

Stage (DN, after shot noise and ``ColGain``, before read noise):
``s -> s (1 + fixed g[Y] + frame z[b, Y])`` with ``g`` a seeded standard normal per sensor row
``Y`` (both channels of the row), the same in every frame, and ``z`` one per sensor row and
frame. Neither depends on ISO.

Profile entry::  ``RowGain: {seed: 71, fixed: 0.004, frame: 0.002}``  (fractions of the signal)

Detected by ``fixed_row_excess`` and ``row_excess`` on flat stacks. Estimated by ``estimate``:
the variance of the row means relative to the level (``line_mean_variance``: from
neighbouring rows, so a smooth illumination does not count) in excess of the model's, of the
frames less their stack mean (the per-frame part) and of the stack mean (the fixed part,
less what the per-frame part leaves in a mean of N frames); ``combine`` weighs the flat
stacks by their level squared (the relative variance of a brighter flat is the sharper).
Bias and dark frames cannot show it.
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import line_rel_parts
from .base import PHOTON, NoiseEffect, pattern_key, register
from .k_records import check_gain_pattern

STATISTICS = ("fixed_row_excess", "row_excess")
KEYS = ("fixed", "frame")


@register
class RowGain(NoiseEffect):
    token = "RowGain"
    order = PHOTON + 31  # after shot noise and the column amplifiers' gain, before read noise
    flag = L.ROW_GAIN
    columns = ("rowgain_fixed", "rowgain_frame")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {col: ctx.k.new_full((ctx.k.shape[0],), float(p.get(key, 0.0))) for col, key in zip(self.columns, KEYS)}

    def pattern_streams(self):
        return {"rowgain_pattern": pattern_key(self.profile.effects[self.token]["seed"], self.token)}

    @classmethod
    def validate_params(cls, params):
        check_gain_pattern(cls.token, params, KEYS)
        unknown = sorted(set(params) - {"seed", *KEYS})
        if unknown:
            raise ValueError(f"effect {cls.token!r}: unknown keys {unknown}; known: {['seed', *KEYS]}")
        if not any(key in params for key in KEYS):
            raise ValueError(f"effect {cls.token!r} needs at least one of {list(KEYS)} (fraction of the signal)")


def row_rel_parts(frames, level_dn) -> tuple[float, float]:
    """(per-frame, stack-mean) relative variance of the sensor-row means (``line_rel_parts``)."""
    return line_rel_parts(frames, level_dn, rows=True)


def estimate(frames, synthesized, k: float, level_dn=None, seed: int = 71, **_) -> dict:
    """RowGain from a flat stack (N >= 2, 4, h, w) in DN at clean level ``level_dn`` (DN, scalar
    or per channel), against stacks of the same shape synthesized by the current model."""
    frames = np.asarray(frames, dtype=np.float64)
    if level_dn is None or not synthesized or frames.shape[0] < 2:
        raise ValueError("RowGain needs a flat stack of >= 2 frames with its clean level level_dn (DN), against syntheses")
    n = frames.shape[0]
    t_meas, f_meas = row_rel_parts(frames, level_dn)
    base = [row_rel_parts(s, level_dn) for s in synthesized]
    frame2 = max(t_meas - float(np.mean([b[0] for b in base])), 0.0)
    # a stack mean's row variance holds the fixed part and a 1/N share of the per-frame part
    fixed2 = max(f_meas - float(np.mean([b[1] for b in base])) - frame2 / n, 0.0)
    weight = float(np.mean(np.broadcast_to(np.asarray(level_dn, dtype=np.float64), (4,)))) ** 2
    return {"seed": int(seed), "fixed": float(np.sqrt(fixed2)), "frame": float(np.sqrt(frame2)), "weight": weight}


def combine(records: list[dict]) -> dict:
    """One row-gain pattern from the flat stacks (every ISO and level: the same rows): their
    variances averaged with weights ``level^2``."""
    w = np.array([r.get("weight", 1.0) for r in records], dtype=np.float64)
    w = w / w.sum()
    return {"seed": records[0]["seed"],
            **{key: float(np.sqrt(np.sum(w * np.array([r[key] ** 2 for r in records])))) for key in KEYS}}


def empty(params) -> bool:
    """True when the rows' gains do not vary (both parts 0): it would add nothing."""
    return all(float(params.get(key, 0.0)) == 0.0 for key in KEYS)
