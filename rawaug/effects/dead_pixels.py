"""Dead pixels (Dead): a few pixels, or lines of them, read a fixed level whatever the light and the noise.

Physics: a broken photodiode, transfer gate or source follower leaves a pixel's output
stuck: at the black clip (code 0), at white (stuck high), or at some level of its own. The
level is a code, the same at every gain, and it does not move from frame to frame. ``Hot``
pixels add an offset to a pixel that still has noise and responds to light; a dead pixel has
neither. A broken column (row) bus or an open contact cuts every pixel beyond the break off
its amplifier: a dead line, whole or from the break to one end of the line (a partial
column defect in EMVA 1288's terms).

Synthesis: positions are the pixels where a seeded U(0, 1) pattern falls below ``density``;
each reads one of ``levels_dn`` (DN, black-subtracted; equally likely, chosen by a second
seeded U(0, 1)) in place of everything before it (after the code map, before the clips).
Sensor column ``j`` (row ``i``) is dead where a seeded U(0, 1) of the line falls below
``col_density`` (``row_density``); with probability ``partial`` it is dead only from a
break at a seeded U(cut_lo, cut_hi) fraction along the line to the line's end (with
probability ``to_end``: the last sensor row or column of the input) or from its start to
there; a dead line's pixels read one level of ``levels_dn``, the line's own.

Profile entry::

    Dead: {seed: 47, density: 0.002, levels_dn: [-40.0, ...],    # 1 to 8 levels
           col_density: 0.0, row_density: 0.0, partial: 0.0, to_end: 1.0,   # optional: dead lines
           cut_lo: 0.0, cut_hi: 1.0}

Detected by ``stuck_fraction`` (pixels with the same value in every frame of a stack of 2 or more, more
than 5 robust sigma from their channel's median, but for those at a clip that moving pixels
reach too; a pixel stuck within the noise is chance where codes are coarse; a line stuck
over more than half its length counts as a defect line), ``defect_lines`` (a dead line's
mean stands out) and ``hot_fraction`` (a pixel stuck high sits high in the stack mean).
Estimated by ``estimate``: the stuck pixels of a stack, line pixels included, arranged
along each sensor line; a line is dead over the segment (whole, or from a position to one
end) that holds the most stuck pixels less live ones, where that is at least LINE_MIN
pixels long and LINE_SHARE stuck. The lines and the remaining isolated pixels beyond the
model's; the partial lines' breaks give the range of a uniform law (``cut_range``); their
levels as 8 octile medians, a line counting as one value. Every kind of stack shows them (a flat best: a pixel stuck at the black clip, or at black itself, is left
out of a bias stack).
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import stuck_outliers, temporal_range
from .base import OFFSET, NoiseEffect, pattern_key, register
from .k_records import _number, check_density, check_seed

STATISTICS = ("stuck_fraction", "defect_lines", "hot_fraction")
RAW_FRAMES = True  # estimated from the frames as measured (every other estimator reads them without dead pixels)
# dead lines: optional keys of the entry and their kernel columns
LINE_KEYS = {"col_density": "dead_col_density", "row_density": "dead_row_density", "partial": "dead_partial",
             "to_end": "dead_to_end", "cut_lo": "dead_cut_lo", "cut_hi": "dead_cut_hi"}
LINE_DEFAULTS = {"col_density": 0.0, "row_density": 0.0, "partial": 0.0, "to_end": 1.0, "cut_lo": 0.0, "cut_hi": 1.0}
LINE_MEANING = {"col_density": "fraction of sensor columns", "row_density": "fraction of sensor rows",
                "partial": "share of the dead lines dead over a part", "to_end": "share of the partial lines dead to their end",
                "cut_lo": "lowest break of a partial line, a fraction of the line",
                "cut_hi": "highest break of a partial line, a fraction of the line"}
MAX_LINE_DENSITY = 0.1


def _levels(params) -> list[float]:
    levels = params.get("levels_dn")
    if not isinstance(levels, (list, tuple)) or not 1 <= len(levels) <= L.DEAD_LEVELS:
        raise ValueError(f"effect 'Dead': levels_dn must be a list of 1 to {L.DEAD_LEVELS} levels (DN), got {levels!r}")
    return [_number(x, "Dead.levels_dn") for x in levels]


@register
class DeadPixels(NoiseEffect):
    token = "Dead"
    order = OFFSET + 5  # after the offsets and the code map, before the clips
    flag = L.DEAD
    columns = ("dead_density", *(f"dead_l{i}" for i in range(L.DEAD_LEVELS)), *LINE_KEYS.values())

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        n = ctx.k.shape[0]
        levels = _levels(p)
        out = {"dead_density": ctx.k.new_full((n,), float(p["density"]))}
        for key, column in LINE_KEYS.items():
            out[column] = ctx.k.new_full((n,), float(p.get(key, LINE_DEFAULTS[key])))
        for i in range(L.DEAD_LEVELS):  # 1 to 8 levels spread over the 8 equally likely slots
            out[f"dead_l{i}"] = ctx.k.new_full((n,), levels[i * len(levels) // L.DEAD_LEVELS])
        return out

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"dead_where": pattern_key(seed, self.token, "where"), "dead_level": pattern_key(seed, self.token, "level"),
                "dead_col": pattern_key(seed, self.token, "col"), "dead_row": pattern_key(seed, self.token, "row")}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect 'Dead' parameters must be a mapping {{seed, density, levels_dn}}, got {params!r}")
        check_seed(cls.token, params)
        check_density(cls.token, params)
        _levels(params)
        for key in LINE_KEYS:
            if key in params:
                value = _number(params[key], f"Dead.{key}")
                most = MAX_LINE_DENSITY if key.endswith("density") else 1.0
                if not 0.0 <= value <= most:
                    raise ValueError(f"effect 'Dead': {key} ({LINE_MEANING[key]}) must be in [0, {most:g}], got {value}")
        lo, hi = (float(params.get(key, LINE_DEFAULTS[key])) for key in ("cut_lo", "cut_hi"))
        if lo > hi:
            raise ValueError(f"effect 'Dead': cut_lo ({lo}) must not exceed cut_hi ({hi})")


def octiles(values) -> list[float]:
    """Median of each eighth of the sorted ``values``: 8 equally likely levels."""
    v = np.sort(np.asarray(values, dtype=np.float64))
    return [float(np.median(part)) for part in np.array_split(v, L.DEAD_LEVELS)] if v.size >= L.DEAD_LEVELS \
        else [float(v[i * v.size // L.DEAD_LEVELS]) for i in range(L.DEAD_LEVELS)]


LINE_MIN = 8  # stuck pixels in a row along a sensor line that make a dead line (8 dead pixels in a row of 1 % random ones: p ~ 1e-16)
LINE_SHARE = 0.9  # of the pixels of a dead line's part that are stuck (a few may be hit by impulses)


def dead_segments(mask):
    """Per line of a (lines, n) mask of stuck pixels: (dead, partial, to_end, start, stop) arrays.
    A line is dead over the segment, whole or from a position to one end, that holds the most
    stuck pixels less live ones, where it is at least LINE_MIN long and LINE_SHARE stuck."""
    g = np.where(mask, 1, -1).cumsum(axis=1)
    n = mask.shape[1]
    total = g[:, -1]
    before = np.concatenate([np.zeros((mask.shape[0], 1), dtype=g.dtype), g[:, :-1]], axis=1)  # sum before each start
    start = np.argmin(before, axis=1)  # suffix [start, n): total - before
    stop = np.argmax(g, axis=1) + 1  # prefix [0, stop)
    suffix, prefix = total - before[np.arange(len(g)), start], g[np.arange(len(g)), stop - 1]
    to_end = suffix >= prefix
    lo, hi = np.where(to_end, start, 0), np.where(to_end, n, stop)
    length = hi - lo
    stuck = np.where(to_end, suffix, prefix)  # stuck - live over the segment
    dead = (length >= LINE_MIN) & ((stuck + length) / np.maximum(2 * length, 1) >= LINE_SHARE)
    partial = dead & (length < n)
    return dead, partial, to_end, lo, hi


def dead_lines(stuck):
    """Dead lines of a (4, h, w) mask of stuck pixels (line pixels included), looked for along
    the sensor rows and columns of its mosaic: (column fraction, row fraction, partial count,
    partial to the end count, line count, (4, h, w) mask of their dead parts, the partial lines'
    breaks as fractions of their lines)."""
    _, h, w = stuck.shape
    mosaic = np.zeros((2 * h, 2 * w), dtype=bool)
    for c in range(4):
        mosaic[L.ROW_SET[c]::2, L.COLUMN_SET[c]::2] = stuck[c]
    found, cuts = [], []
    covered = np.zeros_like(mosaic)
    for lines, dead_part in ((mosaic.T, covered.T), (mosaic, covered)):  # sensor columns, then rows (views)
        dead, partial, to_end, lo, hi = dead_segments(lines)
        found.append((dead, partial, to_end))
        cuts += (np.where(to_end, lo, hi)[partial] / lines.shape[1]).tolist()
        for i in np.flatnonzero(dead):
            dead_part[i, lo[i]:hi[i]] = True
    part = np.stack([covered[L.ROW_SET[c]::2, L.COLUMN_SET[c]::2] for c in range(4)])
    (cd, cp, ce), (rd, rp, re) = found
    partial = int(cp.sum() + rp.sum())
    return (float(cd.mean()), float(rd.mean()), partial, int((cp & ce).sum() + (rp & re).sum()),
            int(cd.sum() + rd.sum()), part, np.asarray(cuts))


def dead_parts(frames):
    """Of a stack (N >= 3, 4, h, w; DN): (isolated stuck pixels' fraction, their values,
    ``dead_lines``' result, the lines' levels: as many as lines, quantiles of their pixels' values)."""
    lo, hi = temporal_range(frames)
    stuck = stuck_outliers(lo, hi, frames[0], lines=False) if (lo == hi).any() else np.zeros(lo.shape, dtype=bool)
    cols, rows, partial, to_end, n_lines, part, cuts = dead_lines(stuck)
    alone = stuck & ~part
    values = lo[part]  # a level per line (its pixels' quantiles), so that long lines do not outweigh the pixels
    line_levels = np.quantile(values, (np.arange(n_lines) + 0.5) / n_lines) if n_lines else values[:0]
    return float(alone.mean()), lo[alone], (cols, rows, partial, to_end, n_lines, cuts), line_levels


def estimate(frames, synthesized, k: float, seed: int = 47, **_) -> dict:
    """Dead-pixel parameters from a stack (N >= 2, 4, h, w) in DN: the isolated stuck pixels'
    fraction over the model's (its syntheses ``synthesized``), the dead lines' fractions of the
    sensor columns and rows over the model's, the share of them dead over a part only (and of
    those, the share dead to the line's end), the stuck levels. Where the model's own pixels
    stick by chance (read noise well under a DN), some of the measured levels are theirs; the
    lines draw their levels from the same 8 levels as the pixels. ValueError where the stack
    shows neither more stuck pixels nor more dead lines than the model's."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.shape[0] < 2:  # a pair is enough: the estimate is over the model's own pixels stuck by chance
        raise ValueError(f"dead pixels are measured on stacks of >= 2 frames, got {frames.shape[0]}")
    alone, levels, (cols, rows, partial, to_end, n_lines, cuts), line_levels = dead_parts(frames)
    base = [dead_parts(np.asarray(s, dtype=np.float64)) for s in synthesized]
    mean = lambda f: float(np.mean([f(b) for b in base])) if base else 0.0  # noqa: E731
    density = max(alone - mean(lambda b: b[0]), 0.0)
    col_density = max(cols - mean(lambda b: b[2][0]), 0.0)
    row_density = max(rows - mean(lambda b: b[2][1]), 0.0)
    if (density == 0.0 or levels.size == 0) and col_density == 0.0 and row_density == 0.0:
        raise ValueError("no more stuck pixels or dead lines than the model's: this stack shows no dead pixels")
    values = np.concatenate([levels if density > 0.0 else levels[:0], line_levels if n_lines else line_levels[:0]])
    out = {"seed": int(seed), "density": min(density, 0.1), "levels_dn": octiles(values)}
    if col_density > 0.0 or row_density > 0.0:
        out.update({"col_density": min(col_density, MAX_LINE_DENSITY), "row_density": min(row_density, MAX_LINE_DENSITY),
                    "partial": partial / n_lines, "to_end": to_end / partial if partial else 1.0, **cut_range(cuts)})
    return out


def cut_range(cuts) -> dict:
    """``cut_lo``, ``cut_hi``: the range of a uniform law of the breaks from the measured ones
    (their least and greatest, each widened by the range / (n - 1): the unbiased estimate of a
    uniform law's ends), within [0, 1]; the whole line below 2 breaks."""
    if len(cuts) < 2:
        return {"cut_lo": 0.0, "cut_hi": 1.0}
    lo, hi = float(np.min(cuts)), float(np.max(cuts))
    pad = (hi - lo) / (len(cuts) - 1)
    return {"cut_lo": max(lo - pad, 0.0), "cut_hi": min(hi + pad, 1.0)}


def combine(records) -> dict:
    """One entry from the records of the stacks that saw dead pixels (a bias stack that clips
    where they are stuck sees none): the median density, the levels pooled; the lines' medians
    of fractions and mean shares over the records that saw dead lines."""
    levels = np.concatenate([r["levels_dn"] for r in records])
    out = {"seed": int(records[0]["seed"]), "density": float(np.median([r["density"] for r in records])),
           "levels_dn": octiles(levels)}
    lined = [r for r in records if "col_density" in r]
    if lined:
        out.update({key: float(np.median([r[key] for r in lined])) for key in ("col_density", "row_density")})
        out.update({key: float(np.mean([r[key] for r in lined])) for key in ("partial", "to_end")})
        out.update({key: float(np.median([r.get(key, LINE_DEFAULTS[key]) for r in lined])) for key in ("cut_lo", "cut_hi")})
    return out


def empty(params) -> bool:
    """True when no pixel and no line is drawn (densities 0): it would add nothing."""
    return all(float(params.get(key, 0.0)) == 0.0 for key in ("density", "col_density", "row_density"))
