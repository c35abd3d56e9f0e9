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
the slopes' variance over frames less the model's, the stacks of a gain pooled by their degrees
of freedom (``combine``), kept where the ratio of the two passes an F test at ``P_VALUE``;
judged with ``sigma_r`` re-fitted (calibration counted the rows' ramp as row noise).
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
SHARES_ROW_NOISE = True  # calibration's sigma_r holds the rows' ramp: judged with the row noise re-fitted


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


def _slope_variances(frames, synthesized, columns: bool) -> list:
    """[measured variance of the frames' slopes, the model's (mean over its syntheses), degrees
    of freedom of each], DN^2 per sensor line^2."""
    n = frames.shape[0]
    model = [float(frame_slopes(np.asarray(s, dtype=np.float64), columns).var(ddof=1)) for s in synthesized]
    return [float(frame_slopes(frames, columns).var(ddof=1)), float(np.mean(model)) if model else 0.0,
            n - 1, len(model) * (n - 1)]


def _beyond_model(parts: list) -> float:
    """The slopes' std beyond the model's (DN per sensor line) from stacks' ``_slope_variances``
    pooled by their degrees of freedom; 0 where the F test of the pooled ratio does not pass."""
    dof, dof_model = sum(p[2] for p in parts), sum(p[3] for p in parts)
    measured = sum(p[0] * p[2] for p in parts) / dof
    base = sum(p[1] * p[3] for p in parts) / dof_model if dof_model else 0.0
    if base > 0 and stats.f.sf(measured / base, dof, dof_model) > P_VALUE:
        return 0.0
    return float(np.sqrt(max(measured - base, 0.0)))


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """BlackRamp record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w; DN) against the
    model's syntheses of it, with the variances ``combine`` pools per gain."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3 or not synthesized:
        raise ValueError("BlackRamp is measured on bias or dark stacks of >= 3 frames")
    rows, cols = _slope_variances(frames, synthesized, False), _slope_variances(frames, synthesized, True)
    return {"k": [float(k)], "row_dn": [_beyond_model([rows])], "col_dn": [_beyond_model([cols])], "rows": [rows], "cols": [cols]}


def combine(records: list[dict]) -> dict:
    """One record per gain: the stacks at that gain (bias and dark) pooled by their degrees of
    freedom, each axis kept where the pooled F test passes."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    ks = sorted(by_k)
    return {"k": ks, "row_dn": [_beyond_model([r["rows"][0] for r in by_k[k]]) for k in ks],
            "col_dn": [_beyond_model([r["cols"][0] for r in by_k[k]]) for k in ks]}


def empty(params) -> bool:
    """True when neither axis ramps."""
    return not any(float(s) > 0 for s in list(params["row_dn"]) + list(params["col_dn"]))
