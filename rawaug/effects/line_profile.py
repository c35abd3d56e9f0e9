"""Measured fixed line profiles (LineMap), a measured fallback: the fixed offsets of the
sensor rows and columns that no physical effect explains, reproduced as measured.

Not a named physical effect: a reset transient (the first rows of every frame high, decaying),
a clamp that settles along the frame, a column pattern of a readout that no random pattern
describes. ``RowFix`` and ``Col`` draw fixed line offsets as white noise of one level; a
profile with structure (a ramp, a decay, a few lines apart) is not theirs. The loop tries
this component only when no physical effect explains a line residual, and the report lists
it as reproduced by measurement.

Stage (DN, with the line offsets): ``s -> s + row_dn[c, y] + col_dn[c, x]`` per packed
channel ``c``, packed row ``y`` and column ``x`` of the measured frame; an input smaller than
it is a window at an offset drawn per sample (as ``FPN`` shading), a larger one repeats it.

Profile entry (per-K records, DN; frame size in packed pixels)::

    LineMap: {k: [K, ...], row_dn: [[[H values] x 4], ...], col_dn: [[[W values] x 4], ...],
              frame_h: H, frame_w: W}

Estimated by ``estimate`` from bias and dark stacks (a fixed offset is in every frame; a
flat's line means hold its light's pattern too): each channel's row and column profile of
the stack mean less the model's (the mean over its syntheses), pooled over the stacks of one
K by ``combine`` (weights 1 / noise^2 per value, the noise being the spread of one stack's
profile about the model's, or the line's own frame-to-frame spread where that is larger: a
line that changes between frames is not a fixed offset), then the values below SureShrink's
threshold (Donoho & Johnstone 1995: Stein's unbiased risk) set to 0, so a sparse transient
is kept and noise is not copied.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from .base import BANDING, NoiseEffect, register
from .k_records import all_zero, frame_size, grid_columns, validate_records

STATISTICS = ("row_excess", "col_excess", "fixed_row_excess", "fixed_col_excess", "row_tone", "col_tone")
MEASURED = True
SIGNED = True  # offsets of either sign, which calibration counted as row noise: suggested by a line statistic the model overshoots too
SHARES_ROW_NOISE = True  # calibration's sigma_r holds the fixed rows' variance: judged with the row noise re-fitted
REFIT_Z = 3.0  # ... where the model's row variance is 3 spreads above the measured (the loop's z_min, 6, for the
# others): the profile is the measured one, whose whole row variance calibration counted in sigma_r, so the
# re-fit need not wait until 2h row means resolve it at 6 (at 6, the reset_transient probe kept row_excess at
# ISO 3200, z -6.9; for RowDrift, 3 cut sigma_r too far on the row_flicker probe)
DECIMALS = 4  # DN stored in the profile


@register
class LineProfile(NoiseEffect):
    token = "LineMap"
    order = BANDING + 5
    flag = L.LINE_MAP
    columns = ("lmap_record", "lmap_gh", "lmap_gw", "lmap_oy", "lmap_ox", "lmap_h", "lmap_w", "lmap_lh", "lmap_lw")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        out = grid_columns(ctx, self.token, p, "lmap")
        out["lmap_lh"] = torch.full_like(ctx.k, float(p["frame_h"]))
        out["lmap_lw"] = torch.full_like(ctx.k, float(p["frame_w"]))
        return out

    def tables(self):
        return {"grids": profile_grids(self.profile.effects[self.token])}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("row_dn", "col_dn"))
        size = frame_size(cls.token, params)
        if size is None:
            raise ValueError("effect 'LineMap' needs frame_h and frame_w (packed pixels of the measured profiles)")
        for key, n in (("row_dn", size[0]), ("col_dn", size[1])):
            for r, rec in enumerate(params[key]):
                try:
                    arr = np.asarray(rec, dtype=np.float64) if isinstance(rec, (list, tuple)) else None
                except (TypeError, ValueError):  # ragged or not numbers
                    arr = None
                if arr is None or arr.shape != (4, n) or not np.all(np.isfinite(arr)):
                    raise ValueError(f"effect 'LineMap': {key} record {r} must be 4 channels x {n} finite values (DN), "
                                     f"got {rec!r:.80}")


def profile_grids(params) -> torch.Tensor:
    """(records, 8, max(H, W)) table the kernels read: rows 0-3 each channel's row profile,
    rows 4-7 its column profile (zero-padded), DN."""
    h, w = params["frame_h"], params["frame_w"]
    out = torch.zeros(len(params["k"]), 8, max(h, w), dtype=torch.float64)
    out[:, :4, :h] = torch.tensor(params["row_dn"], dtype=torch.float64)
    out[:, 4:, :w] = torch.tensor(params["col_dn"], dtype=torch.float64)
    return out


def line_profiles(frames) -> tuple[np.ndarray, np.ndarray]:
    """((4, h) row, (4, w) column) profiles of a stack's mean (N, 4, h, w; DN), each channel's
    mean removed (the colour bias is another stage's)."""
    m = np.asarray(frames, dtype=np.float64).mean(axis=0)
    rows, cols = m.mean(axis=2), m.mean(axis=1)
    return rows - rows.mean(axis=1, keepdims=True), cols - cols.mean(axis=1, keepdims=True)


def sure_threshold(x, sigma) -> np.ndarray:
    """``x`` (values with white noise of std ``sigma``: one number, or one per value) with the
    values at or below a threshold set to 0. The threshold, in units of sigma, is the one in
    [0, max |x / sigma|] that minimizes Stein's unbiased risk estimate of soft thresholding,
    ``n - 2 #{|z| <= t} + sum min(z^2, t^2)`` for z = x / sigma, or, where z holds too little
    energy above the noise for that estimate, ``sqrt(2 ln n)`` (SureShrink's hybrid rule); the
    values above it are kept as they are (soft thresholding would pull a transient's peak down
    by t)."""
    x = np.asarray(x, dtype=np.float64)
    sigma = np.broadcast_to(np.asarray(sigma, dtype=np.float64), x.shape)
    if np.all(sigma <= 0):
        return x.copy()
    z = x / np.maximum(sigma, 1e-12)
    a = np.sort(np.abs(z))
    n = a.size
    candidates = np.concatenate([[0.0], a])
    below = np.arange(n + 1)  # #{|z| <= t} at t = candidates (ties aside)
    kept = np.concatenate([[0.0], np.cumsum(a**2)])  # sum of z^2 at or below t
    risk = n - 2 * below + kept + (n - below) * candidates**2
    t = candidates[int(np.argmin(risk))]
    if (np.sum(z**2) - n) / n <= np.log2(max(n, 2)) ** 1.5 / np.sqrt(n):  # sparse: SURE is unreliable
        t = np.sqrt(2.0 * np.log(max(n, 2)))  # the universal threshold (SureShrink's hybrid rule)
    return np.where(np.abs(z) > t, x, 0.0)


AXES = (("row_dn", "row_excess_dn", "row_noise_dn"), ("col_dn", "col_excess_dn", "col_noise_dn"))


def _thresholded(excess, noise) -> list:
    """Each channel's profile (4, n) thresholded for its noise (4, n) (``sure_threshold``), DN."""
    return [[round(float(v), DECIMALS) for v in sure_threshold(np.asarray(excess[c]), np.asarray(noise[c]))] for c in range(4)]


def frame_profiles(frames) -> tuple[np.ndarray, np.ndarray]:
    """((N, 4, h) row, (N, 4, w) column) profiles of each frame (N, 4, h, w; DN), each frame's
    channel means removed."""
    f = np.asarray(frames, dtype=np.float64)
    rows, cols = f.mean(axis=3), f.mean(axis=2)
    return rows - rows.mean(axis=2, keepdims=True), cols - cols.mean(axis=2, keepdims=True)


def estimate(frames, synthesized, k: float, kind: str = "bias", **_) -> dict:
    """LineMap record at gain ``k`` from a bias or dark stack (N, 4, h, w; DN) against
    syntheses of it (at least 3): the thresholded profiles, and (for ``combine``, which pools
    the stacks of one K before thresholding) the profiles less the model's and their noise."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind == "flat" or len(synthesized) < 3:
        raise ValueError("LineMap is measured on bias and dark stacks, against >= 3 syntheses")
    n = frames.shape[0]
    measured = line_profiles(frames)
    per_frame = frame_profiles(frames) if n >= 2 else None
    synth = [line_profiles(s) for s in synthesized]
    out = {"k": [float(k)], "frame_h": int(frames.shape[2]), "frame_w": int(frames.shape[3])}
    for axis, (key, excess_key, noise_key) in enumerate(AXES):
        parts = np.array([s[axis] for s in synth])  # (S, 4, n)
        excess = measured[axis] - parts.mean(axis=0)
        # per value: the spread of one stack's profile about the model's (and of the model's
        # mean), or the measured line's own frame-to-frame spread over N frames where larger:
        # a line that changes between frames (a telegraph column) is not a fixed offset
        var = np.broadcast_to(parts.var(axis=0, ddof=1).mean(axis=1, keepdims=True) * (1.0 + 1.0 / len(parts)), excess.shape)
        if per_frame is not None:
            var = np.maximum(var, per_frame[axis].var(axis=0, ddof=1) / n)
        noise = np.sqrt(var)
        out[key] = [_thresholded(excess, noise)]
        out[excess_key], out[noise_key] = [excess.tolist()], [noise.tolist()]
    return out


def combine(records: list[dict]) -> dict:
    """One record per gain: the profiles less the model's of the stacks at one K averaged with
    weights 1 / noise^2, then thresholded for the pooled noise (a transient's tail that one
    stack's noise hides shows in several); the frame size of the first (a camera's frames
    share one; records of another size are left out)."""
    first = records[0]
    same = [r for r in records if (r["frame_h"], r["frame_w"]) == (first["frame_h"], first["frame_w"])]
    by_k: dict = {}
    for r in same:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    ks = sorted(by_k)
    out: dict = {"k": ks, "frame_h": first["frame_h"], "frame_w": first["frame_w"]}
    for key, excess_key, noise_key in AXES:
        out[key] = []
        for k in ks:
            excess = np.array([r[excess_key][0] for r in by_k[k]])  # (stacks, 4, n)
            weight = 1.0 / np.maximum(np.array([r[noise_key][0] for r in by_k[k]]), 1e-12) ** 2  # (stacks, 4, n)
            pooled = np.sum(weight * excess, axis=0) / weight.sum(axis=0)
            out[key].append(_thresholded(pooled, 1.0 / np.sqrt(weight.sum(axis=0))))
    return out


def empty(params) -> bool:
    """True when every offset is 0: it would add nothing."""
    return all_zero(params, ("row_dn", "col_dn"))
