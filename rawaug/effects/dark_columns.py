"""Leaky columns (DarkCol): a sparse set of sensor columns with a dark-current rate far above
the rest, growing with exposure, with its shot noise.

Physics: a leaky column-select transistor or a defect on a column's bus adds leakage current
to every pixel of that column while it integrates: a bright line in long exposures that bias
frames do not show, Poisson like every other electron. ``Lines`` is a fixed offset in DN, the
same at every exposure (a column amplifier's offset); ``DarkHot`` is the same physics at single
pixels.

Stage (DN, before shot noise): ``s -> s + K * t * median_e_per_s * exp(log_std * z)`` in the
sensor columns where a seeded U(0, 1) pattern falls below ``density``, ``z`` a seeded standard
normal (both keyed by the sensor column, so both packed channels of the column share them);
``t`` is the synthesis setting ``fixed={"exposure_s": t}`` (default 0: none).

Profile entry (electrons do not depend on the gain: one population)::

    DarkCol: {seed: 71, density: 0.01, median_e_per_s: 15.0, log_std: 0.3}

Detected on dark stacks by ``defect_lines`` (with ``Lines``, which the loop tries beside it: the
bias frames tell them apart). Estimated by ``estimate``: the sensor columns of a dark stack's
mean that stand out of their neighbours (``defect_line_residuals``) in excess of the model's,
their excess in electrons per second, on the frames as measured (``RAW_FRAMES``: the repair of
defect lines would remove them). Columns dimmer than the threshold are not seen: density and
median are those of the detectable population.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..engine import layout as L
from ..statistics import defect_line_residuals, without_outliers
from .base import PHOTON, NoiseEffect, pattern_key, register
from .dark_hot_pixels import combine as combine_populations, validate_population

STATISTICS = ("defect_lines",)
RAW_FRAMES = True  # the leaky columns are defect lines: estimated before their repair
_COL_SETS = tuple(tuple(c for c in range(4) if L.COLUMN_SET[c] == s) for s in (0, 1))


@register
class DarkColumns(NoiseEffect):
    token = "DarkCol"
    order = PHOTON + 7  # with the dark current, before shot noise
    flag = L.DARK_COL
    columns = ("dcol_density", "dcol_e", "dcol_log_std")
    exposure = True

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        exposure = torch.as_tensor(ctx.fixed.get("exposure_s", 0.0), dtype=torch.float64, device=ctx.device).expand(ctx.batch)
        n = ctx.k.shape[0]
        return {"dcol_density": ctx.k.new_full((n,), float(p["density"])), "dcol_e": float(p["median_e_per_s"]) * exposure,
                "dcol_log_std": ctx.k.new_full((n,), float(p["log_std"]))}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"dcol_where": pattern_key(seed, self.token, "where"), "dcol_size": pattern_key(seed, self.token, "size")}

    @classmethod
    def validate_params(cls, params):
        validate_population(cls.token, params, "sensor columns")


_ROW_SETS = tuple(tuple(c for c in range(4) if L.ROW_SET[c] == s) for s in (0, 1))


def bright_lines(frames, along: str = "columns"):
    """(fraction of sensor lines, their excess DN) of a stack (N, 4, h, w; DN): the sensor
    columns (or rows) of the stack mean brighter than their neighbours by the defect-line
    threshold, a line counted once over the two packed channels it crosses."""
    mean = without_outliers(frames).mean(axis=0)
    rows, row_res, cols, col_res = defect_line_residuals(mean)
    mask, res, sets, n = (cols, col_res, _COL_SETS, mean.shape[2]) if along == "columns" else (rows, row_res, _ROW_SETS, mean.shape[1])
    excess, count = [], 0
    for chans in sets:
        line = res[list(chans)].mean(axis=0)
        bright = mask[list(chans)].any(axis=0) & (line > 0)
        excess += line[bright].tolist()
        count += int(bright.sum())
    return count / (2 * n), np.asarray(excess)


def bright_columns(frames):
    """``bright_lines`` along the sensor columns."""
    return bright_lines(frames, "columns")


def line_population(frames, synthesized, k: float, exposure_s, kind, seed: int, token: str, along: str) -> dict:
    """Population of leaky sensor lines (``along`` "columns" or "rows") from a dark stack
    (N, 4, h, w) in DN of ``exposure_s`` seconds at gain ``k`` (DN per electron), against
    stacks of the same shape synthesized by the model."""
    if kind != "dark" or not exposure_s:
        raise ValueError(f"{token} is measured on dark stacks with their exposure_s")
    frames = np.asarray(frames, dtype=np.float64)
    fraction, excess = bright_lines(frames, along)
    base = float(np.mean([bright_lines(s, along)[0] for s in synthesized])) if synthesized else 0.0
    density = max(fraction - base, 0.0)
    if density == 0.0 or excess.size == 0:
        return {"seed": int(seed), "density": 0.0, "median_e_per_s": 0.0, "log_std": 0.0}
    logs = np.log(excess / (float(k) * float(exposure_s)))  # electrons per second above the neighbours
    return {"seed": int(seed), "density": min(density, 0.1), "median_e_per_s": float(math.exp(logs.mean())),
            "log_std": float(logs.std(ddof=1)) if excess.size > 1 else 0.0}


def estimate(frames, synthesized, k: float, exposure_s=None, kind=None, seed: int = 71, **_) -> dict:
    """DarkCol population from a dark stack (``line_population`` along the columns)."""
    return line_population(frames, synthesized, k, exposure_s, kind, seed, "DarkCol", "columns")


def combine(records: list[dict]) -> dict:
    """One population from the dark stacks (every ISO and exposure: the same columns in
    electrons), as ``DarkHot`` combines its records."""
    return combine_populations(records)


def empty(params) -> bool:
    """True when no column is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
