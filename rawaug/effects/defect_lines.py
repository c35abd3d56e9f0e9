"""Defect lines (Lines): sparse sensor rows and columns with a large fixed offset.

Physics: a faulty column amplifier or ADC, or a row driver, offsets a whole sensor column
or row by far more than the column or row noise: a bright or dark line at a fixed position
in every frame (a stuck or dead line is the extreme, clipped at the ADC's ends). EMVA 1288
counts such lines as defects and leaves them out of every noise estimate; a synthesis that
must look like the sensor puts them back.

Synthesis: sensor row ``i`` (packed channel set and row, as for row noise) is defective
where a seeded U(0, 1) pattern falls below ``row_density``, sensor column ``j`` below
``col_density``; each defective line has the offset ``+-median_dn * exp(log_std * z)``
with a seeded standard-normal ``z``, negative with probability ``negative``. The offset is
the same in every frame and in both packed channels of the line; the amplitude scale is a
per-K record.

Profile entry::

    Lines: {seed: 23, row_density: 0.0, col_density: 5.0e-4, log_std: 0.0, negative: 0.0,
            k: [K, ...], median_dn: [...]}

Detected by ``defect_lines`` (rows and columns whose mean stands out from a running median
of its neighbours by 8 robust sigma). Estimated by ``estimate`` from the stack mean of the
frames *with* their defect lines (``RAW_FRAMES``): densities are the detected lines per
sensor row / column beyond what the current model already shows, amplitudes those of the
detected lines. Lines dimmer than the threshold are not seen, so densities and median are
those of the detectable population.
"""
from __future__ import annotations

import math

import numpy as np

from ..engine import layout as L
from ..statistics import defect_line_residuals, without_outliers
from .base import BANDING, NoiseEffect, pattern_key, register
from .k_records import _number, check_seed, validate_records, value_at_k

STATISTICS = ("defect_lines",)
RAW_FRAMES = True  # estimated from the frames as measured, not with their defect lines repaired (dead pixels are)
MAX_DENSITY = 0.1


@register
class DefectLines(NoiseEffect):
    token = "Lines"
    order = BANDING
    flag = L.LINES
    columns = ("lines_row_density", "lines_col_density", "lines_median", "lines_log_std", "lines_negative")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        full = lambda key: ctx.k.new_full((ctx.k.shape[0],), float(p[key]))  # noqa: E731
        return {"lines_row_density": full("row_density"), "lines_col_density": full("col_density"),
                "lines_median": value_at_k(p, "median_dn", ctx.k), "lines_log_std": full("log_std"),
                "lines_negative": full("negative")}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"lines_row": pattern_key(seed, self.token, "row"), "lines_col": pattern_key(seed, self.token, "col")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("median_dn",), nonnegative=("median_dn",))
        check_seed(cls.token, params)
        validate_line_pattern(cls.token, params)


def validate_line_pattern(token: str, params: dict) -> None:
    """A seeded line pattern's ``row_density`` and ``col_density`` (fractions of sensor lines,
    up to ``MAX_DENSITY``), ``log_std`` (>= 0) and ``negative`` (the share of dark lines)."""
    for key in ("row_density", "col_density"):
        value = _number(params.get(key), f"{token}.{key}")
        if not 0.0 <= value <= MAX_DENSITY:
            raise ValueError(f"effect {token!r}: {key} (fraction of sensor lines) must be in [0, {MAX_DENSITY}], got {value}")
    validate_spread(token, params, "lines")


def validate_spread(token: str, params: dict, of: str) -> None:
    """A seeded defect pattern's ``log_std`` (>= 0) and ``negative`` (the share of dark ``of``, in [0, 1])."""
    if _number(params.get("log_std"), f"{token}.log_std") < 0:
        raise ValueError(f"effect {token!r}: log_std must be >= 0, got {params.get('log_std')}")
    negative = _number(params.get("negative"), f"{token}.negative")
    if not 0.0 <= negative <= 1.0:
        raise ValueError(f"effect {token!r}: negative (fraction of dark {of}) must be in [0, 1], got {negative}")


# packed channels (R, G1, B, G2) on each sensor row set and column set
_ROW_SETS = tuple(tuple(c for c in range(4) if L.ROW_SET[c] == s) for s in (0, 1))
_COL_SETS = tuple(tuple(c for c in range(4) if L.COLUMN_SET[c] == s) for s in (0, 1))


def sensor_lines(frames):
    """Defect lines of a stack's mean: (row fraction, column fraction, signed offsets DN),
    a sensor line counted once over the two packed channels it crosses; dead pixels and
    impulses (``without_outliers``) are not lines."""
    mean = without_outliers(frames).mean(axis=0)
    rows, row_res, cols, col_res = defect_line_residuals(mean)
    offsets = []
    for mask, res, sets in ((rows, row_res, _ROW_SETS), (cols, col_res, _COL_SETS)):
        for chans in sets:
            bad = mask[list(chans)].any(axis=0)
            offsets += res[list(chans)][:, bad].mean(axis=0).tolist()
    n_rows = sum(int(rows[list(c)].any(axis=0).sum()) for c in _ROW_SETS)
    n_cols = sum(int(cols[list(c)].any(axis=0).sum()) for c in _COL_SETS)
    return n_rows / (2 * mean.shape[1]), n_cols / (2 * mean.shape[2]), np.asarray(offsets)


def estimate(frames, synthesized, k: float, seed: int = 23, **_) -> dict:
    """Defect-line parameters at gain ``k`` from measured frames (N, 4, h, w) in DN, as
    measured (defect lines in place)."""
    row_frac, col_frac, offsets = sensor_lines(frames)
    base = [sensor_lines(s)[:2] for s in synthesized] if synthesized else [(0.0, 0.0)]
    row_density = max(row_frac - float(np.mean([b[0] for b in base])), 0.0)
    col_density = max(col_frac - float(np.mean([b[1] for b in base])), 0.0)
    amp = np.abs(offsets[offsets != 0])
    if (row_density == 0.0 and col_density == 0.0) or amp.size == 0:
        return {"seed": int(seed), "row_density": 0.0, "col_density": 0.0, "log_std": 0.0, "negative": 0.0,
                "k": [float(k)], "median_dn": [0.0]}
    logs = np.log(amp)
    return {"seed": int(seed), "row_density": min(row_density, MAX_DENSITY), "col_density": min(col_density, MAX_DENSITY),
            "log_std": float(logs.std(ddof=1)) if amp.size > 1 else 0.0, "negative": float(np.mean(offsets < 0)),
            "k": [float(k)], "median_dn": [float(math.exp(logs.mean()))]}
