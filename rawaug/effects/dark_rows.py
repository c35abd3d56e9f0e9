"""Leaky rows (DarkRow): a sparse set of sensor rows with a dark-current rate far above the
rest, growing with exposure, with its shot noise.

Physics: a leaky row-select or transfer-gate line adds leakage current to every pixel of its
row while it integrates: a bright row in long exposures that bias frames do not show, Poisson
like every other electron. ``DarkCol`` is the same physics along a column; ``Lines`` a fixed
offset in DN, the same at every exposure.

Stage (DN, before shot noise): ``s -> s + K * t * median_e_per_s * exp(log_std * z)`` in the
sensor rows where a seeded U(0, 1) pattern falls below ``density``, ``z`` a seeded standard
normal (both keyed by the sensor row, so both packed channels of the row share them); ``t`` is
the synthesis setting ``fixed={"exposure_s": t}`` (default 0: none).

Profile entry (electrons do not depend on the gain: one population)::

    DarkRow: {seed: 79, density: 0.01, median_e_per_s: 12.0, log_std: 0.3}

Detected on dark stacks by ``defect_lines`` (with ``Lines`` and ``DarkCol``: the bias frames
and the line's direction tell them apart). Estimated by ``estimate``: the sensor rows of a dark
stack's mean that stand out of their neighbours (``defect_line_residuals``) in excess of the
model's, their excess in electrons per second, on the frames as measured.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..engine import layout as L
from ..statistics import defect_line_residuals, without_stuck
from .base import PHOTON, NoiseEffect, pattern_key, register
from .dark_hot_pixels import combine as combine_populations, validate_population

STATISTICS = ("defect_lines",)
RAW_FRAMES = True  # the leaky rows are defect lines: estimated before their repair
_ROW_SETS = tuple(tuple(c for c in range(4) if L.ROW_SET[c] == s) for s in (0, 1))


@register
class DarkRows(NoiseEffect):
    token = "DarkRow"
    order = PHOTON + 8  # with the dark current, before shot noise
    flag = L.DARK_ROW
    columns = ("drow_density", "drow_e", "drow_log_std")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        exposure = torch.as_tensor(ctx.fixed.get("exposure_s", 0.0), dtype=torch.float64, device=ctx.device).expand(ctx.batch)
        n = ctx.k.shape[0]
        return {"drow_density": ctx.k.new_full((n,), float(p["density"])), "drow_e": float(p["median_e_per_s"]) * exposure,
                "drow_log_std": ctx.k.new_full((n,), float(p["log_std"]))}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"drow_where": pattern_key(seed, self.token, "where"), "drow_size": pattern_key(seed, self.token, "size")}

    @classmethod
    def validate_params(cls, params):
        validate_population(cls.token, params, "sensor rows")


def bright_rows(frames):
    """(fraction of sensor rows, their excess DN) of a stack (N, 4, h, w; DN): the sensor rows
    of the stack mean brighter than their neighbours by the defect-line threshold, a row
    counted once over the two packed channels it crosses."""
    mean = without_stuck(frames).mean(axis=0)
    rows, res, _, _ = defect_line_residuals(mean)
    excess, n = [], 0
    for chans in _ROW_SETS:
        line = res[list(chans)].mean(axis=0)
        bright = rows[list(chans)].any(axis=0) & (line > 0)
        excess += line[bright].tolist()
        n += int(bright.sum())
    return n / (2 * mean.shape[1]), np.asarray(excess)


def estimate(frames, synthesized, k: float, exposure_s=None, kind=None, seed: int = 79, **_) -> dict:
    """DarkRow population from a dark stack (N, 4, h, w) in DN of ``exposure_s`` seconds at
    gain ``k`` (DN per electron), against stacks of the same shape synthesized by the model."""
    if kind != "dark" or not exposure_s:
        raise ValueError("DarkRow is measured on dark stacks with their exposure_s")
    frames = np.asarray(frames, dtype=np.float64)
    fraction, excess = bright_rows(frames)
    base = float(np.mean([bright_rows(s)[0] for s in synthesized])) if synthesized else 0.0
    density = max(fraction - base, 0.0)
    if density == 0.0 or excess.size == 0:
        return {"seed": int(seed), "density": 0.0, "median_e_per_s": 0.0, "log_std": 0.0}
    logs = np.log(excess / (float(k) * float(exposure_s)))  # electrons per second above the neighbours
    return {"seed": int(seed), "density": min(density, 0.1), "median_e_per_s": float(math.exp(logs.mean())),
            "log_std": float(logs.std(ddof=1)) if excess.size > 1 else 0.0}


def combine(records: list[dict]) -> dict:
    """One population from the dark stacks (every ISO and exposure: the same rows in
    electrons), as ``DarkCol`` combines its records."""
    return combine_populations(records)


def empty(params) -> bool:
    """True when no row is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
