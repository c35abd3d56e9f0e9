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
per-K record. With probability ``partial`` a line is offset over a part only: from a break at
U(cut_lo, cut_hi) of its length to its end (with probability ``to_end``) or from its start to
there (a leak from a defect point that flows one way along the column, a row driver that
fails part way).

Profile entry::

    Lines: {seed: 23, row_density: 0.0, col_density: 5.0e-4, log_std: 0.0, negative: 0.0,
            k: [K, ...], median_dn: [...],
            partial: 0.0, to_end: 1.0, cut_lo: 0.0, cut_hi: 1.0}  # optional: lines over a part

Detected by ``defect_lines`` (rows and columns whose mean stands out from a running median
of its neighbours by 8 robust sigma). Estimated by ``estimate`` from the stack mean of the
frames *with* their defect lines (``RAW_FRAMES``): densities are the detected lines per
sensor row / column beyond what the current model already shows, amplitudes those of the
detected lines (of a partial line, its part's: ``line_part`` finds a break along the line
where an offset over a prefix or a suffix fits its profile better than one over the whole
line by more than the best of its breaks would in noise). Lines dimmer than the threshold
are not seen, so densities and median are those of the detectable population.
"""
from __future__ import annotations

import math

import numpy as np

from ..engine import layout as L
from ..statistics import MAD_TO_SIGMA, defect_line_residuals, without_outliers
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
    columns = ("lines_row_density", "lines_col_density", "lines_median", "lines_log_std", "lines_negative",
               "lines_partial", "lines_to_end", "lines_cut_lo", "lines_cut_hi")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        full = lambda key, default=None: ctx.k.new_full((ctx.k.shape[0],), float(p.get(key, default)))  # noqa: E731
        return {"lines_row_density": full("row_density"), "lines_col_density": full("col_density"),
                "lines_median": value_at_k(p, "median_dn", ctx.k), "lines_log_std": full("log_std"),
                "lines_negative": full("negative"), **{f"lines_{key}": full(key, d) for key, d in PART_DEFAULTS.items()}}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"lines_row": pattern_key(seed, self.token, "row"), "lines_col": pattern_key(seed, self.token, "col"),
                "lines_row_cut": pattern_key(seed, self.token, "row_cut"), "lines_col_cut": pattern_key(seed, self.token, "col_cut")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("median_dn",), nonnegative=("median_dn",))
        check_seed(cls.token, params)
        validate_line_pattern(cls.token, params)
        for key, default in PART_DEFAULTS.items():
            value = _number(params.get(key, default), f"{cls.token}.{key}")
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"effect {cls.token!r}: {key} ({PART_MEANING[key]}) must be in [0, 1], got {value}")
        if float(params.get("cut_lo", 0.0)) > float(params.get("cut_hi", 1.0)):
            raise ValueError(f"effect {cls.token!r}: cut_lo ({params['cut_lo']}) must not exceed cut_hi ({params['cut_hi']})")


PART_DEFAULTS = {"partial": 0.0, "to_end": 1.0, "cut_lo": 0.0, "cut_hi": 1.0}
PART_MEANING = {"partial": "share of the lines offset over a part", "to_end": "share of the partial lines offset to their end",
                "cut_lo": "lowest break of a partial line, a fraction of the line",
                "cut_hi": "highest break of a partial line, a fraction of the line"}


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


MIN_PART = 8  # sensor pixels on each side of a partial line's break
PART_Z2 = 16.0  # a part's gain over the whole line, in noise variances, beyond 4 log n


def line_part(profile) -> tuple[bool, bool, float, float]:
    """(partial, to the end, break as a fraction of the line, offset DN) of a defect line's
    residual ``profile`` along it (its values less its neighbours'): the offset over a prefix or
    a suffix of the line, where that fits the profile better than one offset over the whole
    line by more than the best of n breaks in noise does (``PART_Z2`` + 4 log n noise variances,
    the noise from the profile's successive differences); else the whole line's mean."""
    r = np.asarray(profile, dtype=np.float64)
    n = r.size
    whole = (False, True, 0.0, float(r.mean()))
    if n < 2 * MIN_PART + 1:
        return whole
    d = np.diff(r)
    noise = (MAD_TO_SIGMA * float(np.median(np.abs(d - np.median(d))))) ** 2 / 2.0
    c = np.cumsum(r)
    total = c[-1]
    cut = np.arange(MIN_PART, n - MIN_PART + 1)
    head = c[cut - 1]  # the sum over [0, cut)
    suffix, prefix = (total - head) ** 2 / (n - cut), head**2 / cut
    best_s, best_p = int(np.argmax(suffix)), int(np.argmax(prefix))
    to_end = suffix[best_s] >= prefix[best_p]
    gain = (suffix[best_s] if to_end else prefix[best_p]) - total**2 / n
    if gain <= (PART_Z2 + 4.0 * np.log(n)) * max(noise, 1e-12):
        return whole
    at = int(cut[best_s] if to_end else cut[best_p])
    part = r[at:] if to_end else r[:at]
    return True, bool(to_end), at / n, float(part.mean())


def _profile(m, axis_rows: bool, chans, i) -> np.ndarray:
    """Residual of sensor line ``i`` (packed index) of the channels ``chans`` of a (4, h, w) mean
    map, along it: its values less the median of the same colour's 4 nearest lines (another
    defect line among them does not count), placed at their sensor positions (2 per packed
    position)."""
    a = m if axis_rows else m.transpose(0, 2, 1)  # (4, lines, along)
    n = a.shape[1]
    near = [j for j in (i - 2, i - 1, i + 1, i + 2) if 0 <= j < n]
    out = np.empty(2 * a.shape[2])
    for ch in chans:
        pos = L.COLUMN_SET[ch] if axis_rows else L.ROW_SET[ch]
        out[pos::2] = a[ch, i] - np.median(a[ch, near], axis=0)
    return out


def sensor_lines(frames):
    """Defect lines of a stack's mean: (row fraction, column fraction, signed offsets DN, parts),
    a sensor line counted once over the two packed channels it crosses; dead pixels and
    impulses (``without_outliers``) are not lines. ``parts``: per line, ``line_part``'s
    (partial, to the end, break) where it is offset over a part of its length; its offset is
    then that part's."""
    mean = without_outliers(frames).mean(axis=0)
    rows, row_res, cols, col_res = defect_line_residuals(mean)
    offsets, parts = [], []
    for mask, sets, axis_rows in ((rows, _ROW_SETS, True), (cols, _COL_SETS, False)):
        for chans in sets:
            for i in np.flatnonzero(mask[list(chans)].any(axis=0)):
                partial, to_end, at, offset = line_part(_profile(mean, axis_rows, chans, i))
                offsets.append(offset)
                parts.append((partial, to_end, at))
    n_rows = sum(int(rows[list(c)].any(axis=0).sum()) for c in _ROW_SETS)
    n_cols = sum(int(cols[list(c)].any(axis=0).sum()) for c in _COL_SETS)
    return n_rows / (2 * mean.shape[1]), n_cols / (2 * mean.shape[2]), np.asarray(offsets), parts


def estimate(frames, synthesized, k: float, seed: int = 23, **_) -> dict:
    """Defect-line parameters at gain ``k`` from measured frames (N, 4, h, w) in DN, as
    measured (defect lines in place): densities and amplitudes, and the share of lines offset
    over a part only (of those, the share reaching the line's end, and the range of the breaks)."""
    from .dead_pixels import cut_range

    row_frac, col_frac, offsets, parts = sensor_lines(frames)
    base = [sensor_lines(s)[:2] for s in synthesized] if synthesized else [(0.0, 0.0)]
    row_density = max(row_frac - float(np.mean([b[0] for b in base])), 0.0)
    col_density = max(col_frac - float(np.mean([b[1] for b in base])), 0.0)
    amp = np.abs(offsets[offsets != 0])
    if (row_density == 0.0 and col_density == 0.0) or amp.size == 0:
        return {"seed": int(seed), "row_density": 0.0, "col_density": 0.0, "log_std": 0.0, "negative": 0.0,
                "k": [float(k)], "median_dn": [0.0]}
    logs = np.log(amp)
    out = {"seed": int(seed), "row_density": min(row_density, MAX_DENSITY), "col_density": min(col_density, MAX_DENSITY),
           "log_std": float(logs.std(ddof=1)) if amp.size > 1 else 0.0, "negative": float(np.mean(offsets < 0)),
           "k": [float(k)], "median_dn": [float(math.exp(logs.mean()))]}
    partial = [p for p in parts if p[0]]
    if partial:
        out.update({"partial": len(partial) / len(parts), "to_end": float(np.mean([p[1] for p in partial])),
                    **cut_range([p[2] for p in partial])})
    return out
