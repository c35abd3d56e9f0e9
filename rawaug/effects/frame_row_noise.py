"""Intermittent row noise (FrameRow): in a share of the frames the row noise is stronger than in
the others.

Physics: row noise is the noise of the reference and the column-parallel circuits, sampled
while a row is read. Interference that comes and goes over seconds (a switching regulator
that changes mode with its load, a motor, a radio link that transmits in bursts) couples
into that reference in some frames and not in others, so one frame's rows are quiet and the
next one's are striped. ``R`` gives every frame of a setting the same row-noise level,
``FrameNoise`` scales a frame's white read noise, ``RowBurst`` adds noise to a few rows of a
frame; here the whole frame's row offsets take one of two levels.

Stage: none of its own. ``R``'s per-sample ``sigma_r`` times ``sqrt(strong)`` in a frame whose
uniform draw falls below ``share``, else ``sqrt(weak)``: the two levels' row variances over
``sigma_r^2`` (calibration may have read either level, or their mean, as ``sigma_r``).

Profile entry (per-K records: interference of a fixed size in DN is a larger share of the row
noise at low gain)::

    FrameRow: {k: [K, ...], share: [...], weak: [...], strong: [...]}

Detected on bias and dark stacks of >= 3 frames by ``frame_row_spread`` (the spread over frames
of the log of each frame's robust row-mean variance). Estimated by ``estimate``: each frame's
row-noise variance (its row-mean variance less the white noise the row means hold, both from
``frame_row_variances``, unmixed from the stack mean's share of the other frames), where their
log's variance over the frames exceeds the syntheses' (what one level leaves through
sampling); the frames split in two at the cut of their sorted logs that leaves the least
variance within the groups: ``share`` the high group's share of the frames, ``weak`` and
``strong`` the groups' mean levels over the syntheses' mean level; ``combine`` pools a gain's
stacks by their frames.
"""
from __future__ import annotations

import numpy as np
import torch

from ..statistics import frame_row_variances
from .base import BANDING, NoiseEffect, register
from .k_records import validate_records, value_at_k

STATISTICS = ("frame_row_spread",)
MAX_FACTOR = 1e4  # a level's row variance over sigma_r^2, at most


@register
class FrameRowNoise(NoiseEffect):
    token = "FrameRow"
    order = BANDING + 1  # after R: it scales the sigma_r R drew
    flag = 0  # no stage: R's stage with this frame's sigma_r
    columns = ("sigma_r",)

    @classmethod
    def check(cls, profile, fixed):
        if profile.row_scale is None and "sigma_r" not in fixed:
            raise ValueError(f"effect {cls.token!r} scales the row noise of each frame, but profile {profile.camera!r} "
                             "has no row-noise fit (row_noise.scale): fix sigma_r or calibrate the row noise")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        share, weak, strong = (value_at_k(p, key, ctx.k) for key in ("share", "weak", "strong"))
        factor = torch.sqrt(torch.where(ctx.uniform("frame_row") < share, strong, weak))
        return {"sigma_r": ctx.scale(self.profile.row_scale, "sigma_r") * factor}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("share", "weak", "strong"))
        for share, weak, strong in zip(params["share"], params["weak"], params["strong"]):
            if not 0.0 <= share <= 1.0:
                raise ValueError(f"effect {cls.token!r}: share (of the frames with the stronger row noise) must be in "
                                 f"[0, 1], got {share}")
            if not 0.0 <= weak <= strong <= MAX_FACTOR:
                raise ValueError(f"effect {cls.token!r}: weak and strong (the two levels' row variance over sigma_r^2) "
                                 f"must satisfy 0 <= weak <= strong <= {MAX_FACTOR:g}, got {weak} and {strong}")


def frame_row_levels(frames) -> np.ndarray:
    """(N,) each frame's row-noise variance in a stack (N >= 3, 4, h, w; DN), DN^2: its row-mean
    variance less the white noise's (``frame_row_variances``), unmixed from the stack mean (a
    frame's rows less the stack's hold (1 - 2/N) of its own variance and 1/N^2 of every frame's),
    floored at a tenth of their median (a frame's level is positive)."""
    whole, white = frame_row_variances(frames)
    n = len(whole)
    mix = (1.0 - 2.0 / n) * np.eye(n) + np.full((n, n), 1.0 / n**2)
    v = np.linalg.solve(mix, whole - white)
    return np.maximum(v, 0.1 * max(float(np.median(v)), 1e-12))


def log_spread(frames) -> float:
    """Variance over the frames of the log of their row-noise variances (``frame_row_levels``)."""
    return float(np.var(np.log(frame_row_levels(frames)), ddof=1))


def two_states(levels) -> tuple[float, float, float]:
    """(share of the high group, the low group's mean, the high group's) of frame levels (N >= 2):
    split at the cut of their sorted logs that leaves the least sum of squares within the groups."""
    v = np.sort(np.asarray(levels, dtype=np.float64))
    lv = np.log(v)
    cuts = range(1, len(v))
    cut = min(cuts, key=lambda c: np.sum((lv[:c] - lv[:c].mean()) ** 2) + np.sum((lv[c:] - lv[c:].mean()) ** 2))
    return (len(v) - cut) / len(v), float(v[:cut].mean()), float(v[cut:].mean())


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """FrameRow record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w; DN) against
    stacks of the same shape synthesized by the model (nothing where the frames' levels vary
    no more than the syntheses')."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3 or not synthesized:
        raise ValueError("FrameRow is measured on bias and dark stacks of >= 3 frames, against the model's syntheses")
    none = {"k": [float(k)], "share": [0.0], "weak": [1.0], "strong": [1.0], "frames": frames.shape[0]}
    if log_spread(frames) <= float(np.mean([log_spread(s) for s in synthesized])):
        return none
    model = float(np.mean([frame_row_levels(s).mean() for s in synthesized]))
    share, weak, strong = two_states(frame_row_levels(frames))
    return {**none, "share": [share], "weak": [min(weak / model, MAX_FACTOR)], "strong": [min(strong / model, MAX_FACTOR)]}


def combine(records: list[dict]) -> dict:
    """One record per gain: the share averaged over its stacks by their frames, the levels the
    geometric means of those that found two, by their frames."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append((r["share"][0], r["weak"][0], r["strong"][0], r.get("frames", 1)))
    ks = sorted(by_k)
    out: dict = {"k": ks, "share": [], "weak": [], "strong": []}
    for k in ks:
        s, weak, strong, n = (np.array(c, dtype=np.float64) for c in zip(*by_k[k]))
        found = s > 0.0
        out["share"].append(float(np.sum(s * n) / n.sum()))
        for key, level in (("weak", weak), ("strong", strong)):
            out[key].append(float(np.exp(np.sum(np.log(level[found]) * n[found]) / n[found].sum())) if found.any() else 1.0)
    return out


def empty(params) -> bool:
    """True when every record is one level, sigma_r's: it would change nothing."""
    return all((s == 0.0 and w == 1.0) or w == q == 1.0 for s, w, q in zip(params["share"], params["weak"], params["strong"]))
