"""Black ramps (BlackRamp): the black level ramps linearly across the frame, by a new amount in
every frame.

Physics: a black clamp or a reference line that droops while the frame is read out (its hold
capacitor leaks, the load of the column ADCs pulls it) shifts each row by an amount that grows
with the row's readout time: a ramp down the sensor rows whose slope changes from frame to
frame; a reference that droops along a serial readout does the same across the columns.
``RowDrift`` (1/f row noise) holds some of it, but no ramp: its power is spread over all low
frequencies, and ``TapBlack``'s steps sit at edges.

Stage (DN): in frame ``b``, ``row_dn(K) z_b (Y - (H - 1) / 2) + col_dn(K) z'_b (X - (W - 1) /
2)`` at sensor row Y and column X of an H x W mosaic, ``z``, ``z'`` standard normals per frame:
slopes in DN per sensor line, so a crop sees the same slope.

Profile entry (per-K records)::

    BlackRamp: {k: [K, ...], row_dn: [DN per sensor row, ...], col_dn: [DN per sensor column, ...]}

Detected on bias and dark stacks of >= 3 frames by ``row_ramp_std`` and ``col_ramp_std`` (the
spread over frames of each frame's fitted slope, over the frame). Estimated by ``estimate``:
the slopes' variance over frames less the model's, kept where the ratio of the two passes an F
test at ``P_VALUE``.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import frame_slopes
from .base import OFFSET, NoiseEffect, register
from .k_records import validate_records, value_at_k

STATISTICS = ("row_ramp_std", "col_ramp_std")
P_VALUE = 1e-3  # the measured slopes' variance over the model's: an F ratio beyond this chance


@register
class BlackRamp(NoiseEffect):
    token = "BlackRamp"
    order = OFFSET
    flag = L.BLACK_RAMP
    columns = ("ramp_row", "ramp_col")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {"ramp_row": value_at_k(p, "row_dn", ctx.k), "ramp_col": value_at_k(p, "col_dn", ctx.k)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("row_dn", "col_dn"), nonnegative=("row_dn", "col_dn"))


def _slope_std(frames, synthesized, columns: bool) -> float:
    """The slopes' std (DN per sensor line) beyond the model's, 0 where the F test does not pass."""
    n = frames.shape[0]
    measured = float(frame_slopes(frames, columns).var(ddof=1))
    model = [float(frame_slopes(np.asarray(s, dtype=np.float64), columns).var(ddof=1)) for s in synthesized]
    base = float(np.mean(model)) if model else 0.0
    dof_model = len(model) * (n - 1)
    if base > 0 and stats.f.sf(measured / base, n - 1, max(dof_model, 1)) > P_VALUE:
        return 0.0
    return float(np.sqrt(max(measured - base, 0.0)))


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """BlackRamp record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w; DN) against the
    model's syntheses of it."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3:
        raise ValueError("BlackRamp is measured on bias or dark stacks of >= 3 frames")
    return {"k": [float(k)], "row_dn": [_slope_std(frames, synthesized, False)], "col_dn": [_slope_std(frames, synthesized, True)]}


def empty(params) -> bool:
    """True when neither axis ramps."""
    return not any(float(s) > 0 for s in list(params["row_dn"]) + list(params["col_dn"]))
