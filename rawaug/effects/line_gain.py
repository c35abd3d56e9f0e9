"""Gain defect lines (LineGain): sparse sensor rows and columns converted with a gain far off.

Physics: a weak or faulty column amplifier (or a row's transfer gate or driver) multiplies
the signal of its whole sensor column (row) by a gain several per cent off: a dim or bright
line in a flat, in proportion to its signal, and next to nothing in bias frames. EMVA 1288
counts such lines among the defects of its PRNU images; ``ColGain`` and ``RowGain`` are the
Gaussian gain spread of every line, ``Lines`` a line's fixed offset (the same in bias frames).

Stage (DN, with ``TapGain``: after shot and read noise, before the rows' and black levels'
offsets): ``s -> s * max(1 + d_row[Y], 0) * max(1 + d_col[X], 0)``; sensor row ``Y``
(column ``X``) is a gain defect where a seeded U(0, 1) falls below ``row_density``
(``col_density``), with ``d = +-median * exp(log_std * z)`` (a seeded standard normal ``z``),
negative with probability ``negative``; 0 elsewhere. The same in every frame and at every gain.

Profile entry (densities per sensor line; ``median`` a fraction of the signal)::

    LineGain: {seed: 31, row_density: 0.0, col_density: 0.01, median: 0.08, log_std: 0.0, negative: 1.0}

Detected by ``defect_lines`` in flat stacks. Estimated by ``estimate`` from a flat stack as
measured (its defect lines in place): the lines ``defect_lines`` finds beyond what the model
shows whose pixels deviate alike (a row of phase-detection pixels, dim at every n-th pixel, is
``GainGrid``'s), their offsets over the stack's level; ``combine`` keeps the flat stack that
resolved the most lines (lines dimmer than the threshold are not seen at a low level).
"""
from __future__ import annotations

import math

import numpy as np

from ..engine import layout as L
from ..statistics import defect_line_residuals, without_outliers
from .base import READ, NoiseEffect, pattern_key, register
from .defect_lines import MAX_DENSITY, validate_line_pattern
from .k_records import _number, check_seed

STATISTICS = ("defect_lines",)
RAW_FRAMES = True  # estimated from the frames as measured: their defect lines are what it measures
MAX_MEDIAN = 0.9  # a gain defect of at most 90 % of the signal


@register
class LineGain(NoiseEffect):
    token = "LineGain"
    order = READ + 6  # with TapGain: the line's amplifier, after read noise, before the row offsets
    flag = L.LINE_GAIN
    columns = ("lgain_row_density", "lgain_col_density", "lgain_median", "lgain_log_std", "lgain_negative")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        full = lambda key: ctx.k.new_full((ctx.k.shape[0],), float(p[key]))  # noqa: E731
        return {"lgain_row_density": full("row_density"), "lgain_col_density": full("col_density"),
                "lgain_median": full("median"), "lgain_log_std": full("log_std"), "lgain_negative": full("negative")}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"lgain_row": pattern_key(seed, self.token, "row"), "lgain_col": pattern_key(seed, self.token, "col")}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r:.80}")
        check_seed(cls.token, params)
        validate_line_pattern(cls.token, params)
        median = _number(params.get("median"), "LineGain.median")
        if not 0.0 <= median <= MAX_MEDIAN:
            raise ValueError(f"effect 'LineGain': median (fraction of the signal) must be in [0, {MAX_MEDIAN}], got {median}")


UNIFORM = 0.5  # a gain line dims all its pixels alike: its median pixel's deviation at least half its mean's


def _uniform(m, line, axis) -> bool:
    """Whether packed line ``line`` of one channel's stack mean ``m`` (h, w) deviates from its
    two neighbours (one at an edge) at its median pixel by at least ``UNIFORM`` of its mean
    deviation: a gain defect dims the whole line; a row of phase-detection pixels, every n-th."""
    lines = m if axis == 0 else m.T  # (lines, pixels)
    nb = [lines[i] for i in (line - 1, line + 1) if 0 <= i < lines.shape[0]]
    ratio = lines[line] / np.maximum(np.mean(nb, axis=0), 1e-12) - 1.0
    return abs(float(np.median(ratio))) >= UNIFORM * abs(float(ratio.mean()))


def gain_lines(frames) -> tuple[float, float, np.ndarray]:
    """(row fraction, column fraction, relative offsets) of the gain defect lines of a flat
    stack (defect lines in place): its sensor lines ``defect_lines`` finds (a line counted once
    over its two packed channels) whose pixels deviate alike (``_uniform``), each line's
    offset over the stack's level, mean over its channels."""
    mean = without_outliers(frames).mean(axis=0)
    level = max(float(mean.mean()), 1e-12)
    rows, row_res, cols, col_res = defect_line_residuals(mean)
    found = {"row": {}, "col": {}}
    for axis, mask, res in ((0, rows, row_res), (1, cols, col_res)):
        sets = L.ROW_SET if axis == 0 else L.COLUMN_SET
        for c, j in zip(*np.nonzero(mask)):
            if _uniform(mean[c], int(j), axis):
                found["row" if axis == 0 else "col"].setdefault(2 * int(j) + sets[c], []).append(float(res[c, j]) / level)
    offsets = np.array([float(np.mean(v)) for d in found.values() for v in d.values()])
    return len(found["row"]) / (2 * mean.shape[1]), len(found["col"]) / (2 * mean.shape[2]), offsets


def estimate(frames, synthesized, k: float, level_dn=None, kind=None, seed: int = 31, **_) -> dict:
    """LineGain from a flat stack (N, 4, h, w; DN, defect lines in place), against the model's
    ``synthesized`` stacks of it: its gain lines (``gain_lines``) beyond the model's."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "flat":
        raise ValueError(f"LineGain is measured on flat stacks, got a {kind!r} stack")
    if not float(frames.mean()) > 0:
        raise ValueError(f"LineGain needs a flat stack above black, got a mean of {float(frames.mean()):.4g} DN")
    row_frac, col_frac, rel = gain_lines(frames)
    base = [gain_lines(s)[:2] for s in synthesized] if synthesized else [(0.0, 0.0)]
    row_density = min(max(row_frac - float(np.mean([b[0] for b in base])), 0.0), MAX_DENSITY)
    col_density = min(max(col_frac - float(np.mean([b[1] for b in base])), 0.0), MAX_DENSITY)
    amp = np.abs(rel[rel != 0])
    if (row_density == 0.0 and col_density == 0.0) or amp.size == 0:
        return {"seed": int(seed), "row_density": 0.0, "col_density": 0.0, "median": 0.0, "log_std": 0.0, "negative": 0.0}
    logs = np.log(amp)
    return {"seed": int(seed), "row_density": row_density, "col_density": col_density,
            "median": min(float(math.exp(logs.mean())), MAX_MEDIAN),
            "log_std": float(logs.std(ddof=1)) if amp.size > 1 else 0.0, "negative": float(np.mean(rel < 0))}


def combine(records: list[dict]) -> dict:
    """One set of lines (the sensor's, the same at every gain and level): the flat stack's
    record that resolved the most lines."""
    return max(records, key=lambda r: r["row_density"] + r["col_density"])


def empty(params) -> bool:
    """True when no line is drawn or none is off: it would change nothing."""
    return (params["row_density"] == 0.0 and params["col_density"] == 0.0) or params["median"] == 0.0
