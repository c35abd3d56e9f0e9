"""Black steps (BlackStep): the black level steps at a row of the frame, a new row and size in
every frame.

Physics: a rolling readout reads the rows one after another, so whatever moves the black
level while a frame is read moves it from the row read at that moment on: a clamp that
re-triggers during readout, a load switched on the same supply (a flash charging, a motor
starting, a radio link keying up), a reference that settles to a new level after a glitch.
The frame's rows above the event sit at one level and those below at another. ``BlackRamp``
is a level that moves steadily over the whole readout, ``TapBlack`` steps at fixed edges,
``RowSpikes`` moves single rows.

Stage (DN): in frame ``b`` a step of ``mean_dn(K) + sd_dn(K) z_b`` at every sensor row from
``u_b 2H`` on (``u_b`` uniform, so a crop sees a step anywhere in it), in a share ``share(K)``
of the frames (none in the others); drawn per sample on the host: no random stream of its own.

Profile entry (per-K records)::

    BlackStep: {k: [K, ...], share: [...], mean_dn: [...], sd_dn: [...]}

Detected on bias and dark stacks of >= 3 frames by ``row_step_z`` (the mean over frames of each
frame's largest standardized step down its sensor rows). Estimated by ``estimate``: the frames
whose largest step stands a quarter above the largest of the model's syntheses carry a step
(``share``); the rows and sizes of the steps by ``locate_steps`` (the scan of
``row_step_z`` on each frame less the stack's shared profile, and least squares of the
frames' row profiles on a step each and that profile, in turns); ``mean_dn`` their mean,
``sd_dn`` their spread less what the rows' noise gives a size (n / (t (n - t)) of the row
variance); ``combine`` pools a gain's stacks by their frames and steps. Judged with
``sigma_r`` re-fitted (calibration counted the steps' rows as row noise).
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from ..statistics import frame_row_means, step_scan
from .base import OFFSET, NoiseEffect, register
from .k_records import validate_records, value_at_k

STATISTICS = ("row_step_z",)
SHARES_ROW_NOISE = True  # calibration's sigma_r holds the steps: judged with the row noise re-fitted


@register
class BlackStep(NoiseEffect):
    token = "BlackStep"
    order = OFFSET
    flag = L.BLACK_STEP
    columns = ("bstep_at", "bstep_dn")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        share, mean, sd = (value_at_k(p, key, ctx.k) for key in ("share", "mean_dn", "sd_dn"))
        size = mean + sd * ctx.normal("bstep_dn").to(torch.float64)
        return {"bstep_at": ctx.uniform("bstep_at"),
                "bstep_dn": torch.where(ctx.uniform("bstep") < share, size, torch.zeros_like(size))}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("share", "mean_dn", "sd_dn"), nonnegative=("sd_dn",))
        for share in params["share"]:
            if not 0.0 <= share <= 1.0:
                raise ValueError(f"effect {cls.token!r}: share (of the frames with a step) must be in [0, 1], got {share}")


NULL_MARGIN = 1.25  # a frame's step counts where its z passes this times the model's largest
LOCATE_ROUNDS = 3  # alternations of the stack's shared row profile and the frames' steps


def locate_steps(frames) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(z, first stepped sensor row, step DN, row noise DN) of each frame of a stack (N, 4, h, w;
    DN): each frame's sensor-row means (its mean out) are the stack's shared profile plus a step;
    the profile (the mean of the frames less their steps) and each frame's largest step (its
    CUSUM scan, ``statistics.step_scan``; the sizes by least squares with the profile,
    ``joint_sizes``) found in turn, ``LOCATE_ROUNDS`` times."""
    r = frame_row_means(np.asarray(frames, dtype=np.float64))
    steps = np.zeros_like(r)
    rows = np.arange(r.shape[1])
    for _ in range(LOCATE_ROUNDS):
        e = r - (r - steps).mean(axis=0, keepdims=True)
        z, at, noise = step_scan(e)
        s = (rows[None, :] >= at[:, None]).astype(np.float64)
        size = joint_sizes(r, at)
        steps = size[:, None] * (s - s.mean(axis=1, keepdims=True))
    return z, at, size, noise


def joint_sizes(r, at) -> np.ndarray:
    """(N,) the steps of row profiles ``r`` (N, rows; each frame's mean out) from rows ``at`` on,
    with one profile shared by the frames, by least squares at once (in turns the steps'
    common part passes into the profile slowly: the mean of steps at many rows is nearly a ramp)."""
    n, rows = r.shape
    s = (np.arange(rows)[None, :] >= np.asarray(at)[:, None]).astype(np.float64)
    s -= s.mean(axis=1, keepdims=True)
    design = np.zeros((n, rows, n))  # the frames less their mean: each step less 1/N of every step
    for g in range(n):
        design[:, :, g] = -s[g] / n
        design[g, :, g] += s[g]
    e = r - r.mean(axis=0, keepdims=True)
    return np.linalg.lstsq(design.reshape(n * rows, n), e.ravel(), rcond=None)[0]


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """BlackStep record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w; DN) against the
    model's syntheses of it, with the counts ``combine`` pools by."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3 or not synthesized:
        raise ValueError("BlackStep is measured on bias or dark stacks of >= 3 frames, against the model's syntheses")
    z, at, size, noise = locate_steps(frames)
    # a quarter beyond the largest of the model's: the largest of N new frames passes the
    # largest of S N with chance 1 / (S + 1), too often for a stack without steps
    stepped = z > NULL_MARGIN * max(float(locate_steps(s)[0].max()) for s in synthesized)
    n = frames.shape[0]
    if not stepped.any():
        return {"k": [float(k)], "share": [0.0], "mean_dn": [0.0], "sd_dn": [0.0], "frames": n, "steps": 0, "var": 0.0}
    d, rows = size[stepped], frames.shape[2] * 2
    size_var = float(np.mean(noise[stepped] ** 2 * rows / (at[stepped] * (rows - at[stepped]))))
    var = float(np.var(d, ddof=1)) - size_var if len(d) > 1 else 0.0
    return {"k": [float(k)], "share": [float(stepped.mean())], "mean_dn": [float(d.mean())],
            "sd_dn": [float(np.sqrt(max(var, 0.0)))], "frames": n, "steps": len(d), "var": max(var, 0.0)}


def combine(records: list[dict]) -> dict:
    """One record per gain: the share over its stacks' frames, the mean and the spread over
    their steps."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    ks = sorted(by_k)
    out: dict = {"k": ks, "share": [], "mean_dn": [], "sd_dn": []}
    for k in ks:
        rs = by_k[k]
        steps = sum(r.get("steps", 1) for r in rs)
        out["share"].append(float(sum(r["share"][0] * r.get("frames", 1) for r in rs) / sum(r.get("frames", 1) for r in rs)))
        w = [r.get("steps", 1) / max(steps, 1) for r in rs]
        out["mean_dn"].append(float(sum(wi * r["mean_dn"][0] for wi, r in zip(w, rs))) if steps else 0.0)
        out["sd_dn"].append(float(np.sqrt(sum(wi * r.get("var", r["sd_dn"][0] ** 2) for wi, r in zip(w, rs)))) if steps else 0.0)
    return out


def empty(params) -> bool:
    """True when no frame steps."""
    return all(s == 0.0 or (m == 0.0 and d == 0.0) for s, m, d in zip(params["share"], params["mean_dn"], params["sd_dn"]))
