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

import torch

from ..engine import layout as L
from .base import PHOTON, NoiseEffect, pattern_key, register
from .dark_columns import bright_lines, line_population
from .dark_hot_pixels import combine as combine_populations, validate_population

STATISTICS = ("defect_lines",)
RAW_FRAMES = True  # the leaky rows are defect lines: estimated before their repair


@register
class DarkRows(NoiseEffect):
    token = "DarkRow"
    order = PHOTON + 8  # with the dark current, before shot noise
    flag = L.DARK_ROW
    columns = ("drow_density", "drow_e", "drow_log_std")
    exposure = True

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
    """``bright_lines`` along the sensor rows."""
    return bright_lines(frames, "rows")


def estimate(frames, synthesized, k: float, exposure_s=None, kind=None, seed: int = 79, **_) -> dict:
    """DarkRow population from a dark stack (``line_population`` along the rows)."""
    return line_population(frames, synthesized, k, exposure_s, kind, seed, "DarkRow", "rows")


def combine(records: list[dict]) -> dict:
    """One population from the dark stacks (every ISO and exposure: the same rows in
    electrons), as ``DarkCol`` combines its records."""
    return combine_populations(records)


def empty(params) -> bool:
    """True when no row is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
