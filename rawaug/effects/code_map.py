"""Measured code mapping (CodeMap), a measured fallback: the raw codes the camera actually
writes.

Not a named physical effect: digital gain after the ADC, a non-linear or dithered
re-quantization in firmware or a lossy raw compression leave some codes unused (a comb in
the histogram, ``missing_codes``, which also widens the codes beside each gap: ``code_dnl``) that no noise stage reproduces. The loop tries this
component only when no physical effect explains the comb; the report lists it as
reproduced by measurement.

Stage (DN, after every offset): ``s`` is rounded to a whole DN ``c`` and, inside the mapped
range ``[lo_dn, lo_dn + n)``, replaced by the code the camera writes for it: ``map[c - lo]``,
or, where ``s - c`` is at or above ``split[c - lo]``, the next code the map writes above that
one (an ADC's decision level inside a missing code's cell: its inputs go to both
neighbours); outside it is left rounded, or, with a period ``p``, shifted as the code
``p``-periodically equal to it in the map's first period is (a comb over the whole range).

Profile entry (per-K records)::  ``CodeMap: {k: [K, ...], lo_dn: [...], map_dn: [[c, ...], ...], split_dn: [[t, ...], ...], period_dn: [...]}``
(``map_dn[i]``: the code written for ``lo_dn + i``, DN relative to black, non-decreasing;
``split_dn``, optional: per code, the input (DN from the code, in [-0.5, 0.5]) from which it
goes up instead, 0.5 (never) by default; ``period_dn``, optional: 0, or the period of a comb
that repeats beyond the mapped range).

Estimated by ``estimate`` as the ADC's transfer, not the noise's shape: every code the
camera writes maps to itself, so a signal keeps its DN (the map is measured on dark frames
but applied at every signal level); each missing code (none written, while the written codes
on both sides of its gap hold >= ``MIN_COUNT`` pixels each: ``statistics.comb_gaps``) goes
to those two neighbours, split at the input level where the current model's rounded values,
spread evenly over their cells, hold the share the lower neighbour has of the frames' pixels
of the gap (histogram matching: a differential non-linearity splits a missing code's inputs
between both neighbours; sending them all to one doubles its count and shifts the mean). Where the map's shifts repeat with a period (a digital gain, an ADC's
differential non-linearity; ``periodic_comb``), the period is stored and the comb is applied
at every signal level, not only over the codes the frames held.
A first version matched the whole histogram: fitted on a real dark frame it mapped 1..107 DN
onto 4..18 DN and wiped out the signal of the dark scenes it was trained on.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from ..statistics import MAX_COMB_GAP, written_codes  # the rule for a missing code (comb_gaps there)
from .base import CLIP, NoiseEffect, register
from .k_records import record_index, validate_records, value_at_k

STATISTICS = ("missing_codes", "code_dnl")  # a missing code widens its neighbours: the code histogram's DNL too
MEASURED = True


@register
class CodeMap(NoiseEffect):
    token = "CodeMap"
    order = CLIP - 5
    flag = L.CODE_MAP
    columns = ("codemap_record", "codemap_lo", "codemap_n", "codemap_period")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        lengths = {"k": p["k"], "n": [float(len(m)) for m in p["map_dn"]],
                   "period": [float(x) for x in p.get("period_dn", [0.0] * len(p["k"]))]}
        return {"codemap_record": record_index(p, ctx.k).to(torch.float64), "codemap_lo": value_at_k(p, "lo_dn", ctx.k),
                "codemap_n": value_at_k(lengths, "n", ctx.k), "codemap_period": value_at_k(lengths, "period", ctx.k)}

    def tables(self):
        """``code_lut`` (records, 3, n): per code the code below the split, the code above it
        (the next the map writes), the split (DN from the code)."""
        p = self.profile.effects[self.token]
        luts = [np.asarray(m, dtype=np.float64) for m in p["map_dn"]]
        splits = p.get("split_dn") or [[0.5] * len(t) for t in luts]
        table = np.zeros((len(luts), 3, max(len(t) for t in luts)))
        table[:, 2] = 0.5
        for i, (t, split) in enumerate(zip(luts, splits)):
            table[i, 0, : t.size] = t
            table[i, 1, : t.size] = next_above(t)
            table[i, 2, : t.size] = split
        return {"code_lut": torch.from_numpy(table)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("lo_dn", "map_dn"))
        for i, codes in enumerate(params["map_dn"]):
            arr = np.asarray(codes, dtype=np.float64) if isinstance(codes, (list, tuple)) else None
            if arr is None or arr.ndim != 1 or not 1 <= arr.size <= 65536 or not np.all(np.isfinite(arr)) \
                    or np.any(arr != np.rint(arr)) or np.any(np.diff(arr) < 0):
                raise ValueError(f"effect 'CodeMap': map_dn[{i}] must be 1 to 65536 non-decreasing whole DN, got {codes!r:.80}")
            if params["lo_dn"][i] != np.rint(params["lo_dn"][i]):
                raise ValueError(f"effect 'CodeMap': lo_dn must be whole DN, got {params['lo_dn'][i]}")
        splits = params.get("split_dn")
        if splits is not None:
            if not isinstance(splits, (list, tuple)) or len(splits) != len(params["k"]):
                raise ValueError(f"effect 'CodeMap': split_dn must list one split per code of each map, got {splits!r:.80}")
            for i, (split, codes) in enumerate(zip(splits, params["map_dn"])):
                arr = np.asarray(split, dtype=np.float64) if isinstance(split, (list, tuple)) else None
                if arr is None or arr.shape != (len(codes),) or not np.all((arr >= -0.5) & (arr <= 0.5)):
                    raise ValueError(f"effect 'CodeMap': split_dn[{i}] must hold {len(codes)} values in [-0.5, 0.5] "
                                     f"(DN from the code), got {split!r:.80}")
        periods = params.get("period_dn", [0] * len(params["k"]))
        if not isinstance(periods, (list, tuple)) or len(periods) != len(params["k"]):
            raise ValueError(f"effect 'CodeMap': period_dn must list one period per k, got {periods!r:.80}")
        for i, (per, codes) in enumerate(zip(periods, params["map_dn"])):
            if isinstance(per, bool) or not isinstance(per, (int, float)) or per != int(per) or not 0 <= per <= len(codes):
                raise ValueError(f"effect 'CodeMap': period_dn[{i}] must be 0 (none) or a whole DN up to the map's "
                                 f"length {len(codes)}, got {per!r}")


def next_above(codes) -> np.ndarray:
    """Per entry of a non-decreasing map, the next larger code it writes (itself at the top)."""
    codes = np.asarray(codes, dtype=np.float64)
    values = np.unique(codes)
    j = np.searchsorted(values, codes, side="right")
    return np.where(j < values.size, values[np.minimum(j, values.size - 1)], codes)


def _gap_split(counts, model_counts, a: int, b: int) -> float:
    """The input level (index units) splitting the cells ``a .. b`` (written codes ``a`` and
    ``b``, missing ones between) as the frames split their pixels between ``a`` and ``b``:
    where the model's counts, spread evenly over their cells, reach the lower code's share;
    within the gap's cells (a written code keeps its own)."""
    share = counts[a] / (counts[a] + counts[b])
    m = model_counts[a : b + 1]
    if m.sum() > 0:
        cum = np.concatenate([[0.0], np.cumsum(m)]) / m.sum()
        theta = float(np.interp(share, cum, a - 0.5 + np.arange(m.size + 1)))
    else:
        theta = 0.5 * (a + b)
    return float(np.clip(theta, a + 0.5, b - 0.5))


def estimate(frames, synthesized, k: float, **_) -> dict:
    """Code map at gain ``k`` from a stack of whole-DN values (N, 4, h, w) and stacks the
    current model synthesized for it (rounded): identity on written codes; the inputs of each
    gap of missing codes split between the written codes bounding it (``_gap_split``). The
    map spans the gaps only (outside it a value is just rounded)."""
    v = np.asarray(frames, dtype=np.float64)
    if not np.all(v == np.rint(v)):
        raise ValueError("CodeMap needs frames of whole DN (real raw codes)")
    v = v.ravel()
    written = written_codes(v)
    missing = np.flatnonzero(~written)
    r = np.arange(v.min(), v.min() + written.size)
    codes, split = r.copy(), np.full(r.size, 0.5)
    if missing.size:
        counts = np.bincount((v - r[0]).astype(np.int64), minlength=r.size).astype(np.float64)
        model = np.rint(np.asarray(synthesized, dtype=np.float64)).ravel()
        model = model[(model >= r[0]) & (model <= r[-1])]
        model_counts = np.bincount((model - r[0]).astype(np.int64), minlength=r.size).astype(np.float64)
        starts = missing[np.r_[True, np.diff(missing) > 1]]
        stops = missing[np.r_[np.diff(missing) > 1, True]]
        for first, last in zip(starts, stops):  # a gap: codes first .. last, written first - 1 and last + 1
            lo, hi = first - 1, last + 1
            theta = _gap_split(counts, model_counts, lo, hi)
            codes[first : last + 1] = r[lo]
            split[first : last + 1] = np.clip(theta - np.arange(first, last + 1), -0.5, 0.5)
        first, last = missing[0] - 1, missing[-1] + 1  # the written codes bounding the gaps
        r, codes, split = r[first : last + 1], codes[first : last + 1], split[first : last + 1]
    else:
        r, codes, split = r[:1], codes[:1], split[:1]
    period, template, split_template = periodic_comb(r, codes, split)
    if period:  # the comb's period in front: the kernel repeats the map's first period beyond its range
        moved = codes != r
        split = np.where(moved, split_template[((r - r[0]) % period).astype(np.int64)], split)
        r = np.concatenate([r[0] - period + np.arange(period), r])
        codes = np.concatenate([r[:period] + template, codes])
        split = np.concatenate([split_template, split])
    return {"k": [float(k)], "lo_dn": [float(r[0])], "map_dn": [[float(c) for c in codes]],
            "split_dn": [[float(t) for t in split]], "period_dn": [float(period)]}


MIN_PERIODS = 3  # a comb is periodic where its pattern repeats this many times over the measured range
PERIODIC = 0.98  # ... at this share of its codes or more (a sparse tail's gaps do not count as missing)


def periodic_comb(r, codes, split=None):
    """(period, shifts of one period, splits of one period) of a code map ``codes`` (with its
    ``split``) over codes ``r``: where the moved (missing) codes repeat with a period p up to
    2 (MAX_COMB_GAP + 1) over PERIODIC of the range, which spans MIN_PERIODS periods or more, p and each
    phase's most common shift and median split (phase j: the codes r[0] + j + n p); else (0,
    None, None). A digital gain or an ADC's differential non-linearity makes such a comb over
    the whole code range, not only where the frames had pixels."""
    r = np.asarray(r, dtype=np.float64)
    shift = np.asarray(codes, dtype=np.float64) - r
    split = np.full(r.size, 0.5) if split is None else np.asarray(split, dtype=np.float64)
    moved = shift != 0
    if not moved.any():
        return 0, None, None
    for p in range(2, 2 * (MAX_COMB_GAP + 1) + 1):
        if moved.size >= MIN_PERIODS * p and np.mean(moved[p:] == moved[:-p]) >= PERIODIC:
            template, splits = [], []
            for j in range(p):
                values, counts = np.unique(shift[j::p], return_counts=True)
                template.append(values[np.argmax(counts)])
                same = split[j::p][shift[j::p] == template[-1]]
                splits.append(float(np.median(same)) if template[-1] != 0 else 0.5)
            return p, np.asarray(template), np.asarray(splits)
    return 0, None, None


def combine(records: list[dict]) -> dict:
    """One map per gain: the maps of the stacks at one K (bias, dark, flats cover different
    code ranges) joined over their union; where two overlap the first stack's holds, and
    codes between them map to themselves, or, where all share one periodic comb, follow the
    widest map's (its shifts and splits, over every code)."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(r["k"][0], []).append(r)
    ks, los, maps, splits, periods = sorted(by_k), [], [], [], []
    for k in ks:
        parts = by_k[k]
        lo = min(p["lo_dn"][0] for p in parts)
        hi = max(p["lo_dn"][0] + len(p["map_dn"][0]) - 1 for p in parts)
        joined = np.arange(lo, hi + 1.0)
        split = np.full(joined.size, 0.5)
        filled = np.zeros(joined.size, dtype=bool)
        for p in parts:
            start = int(p["lo_dn"][0] - lo)
            m = np.asarray(p["map_dn"][0], dtype=np.float64)
            t = np.asarray((p.get("split_dn") or [[0.5] * m.size])[0], dtype=np.float64)
            free = ~filled[start : start + m.size]
            joined[start : start + m.size][free] = m[free]
            split[start : start + m.size][free] = t[free]
            filled[start : start + m.size] = True
        period = _common_period(parts)
        if period:  # one periodic comb: its pattern fills the codes between the stacks' ranges too
            # the widest map's pattern: its splits are medians over the most gaps (a bias stack
            # of low read noise spans a few, and its model's spread is the least certain there)
            first = max(parts, key=lambda p: len(p["map_dn"][0]))
            shift = np.asarray(first["map_dn"][0][:period]) - (first["lo_dn"][0] + np.arange(period))
            first_split = np.asarray((first.get("split_dn") or [[0.5] * period])[0][:period], dtype=np.float64)
            codes = np.arange(lo, hi + 1.0)
            phase = ((codes - first["lo_dn"][0]) % period).astype(np.int64)
            joined, split = codes + shift[phase], first_split[phase]
        los.append(float(lo))
        kept = np.maximum.accumulate(joined)  # non-decreasing where ranges meet
        maps.append([float(c) for c in kept])
        splits.append([float(t) if c == j else 0.5 for c, j, t in zip(kept, joined, split)])
        periods.append(float(period))
    return {"k": ks, "lo_dn": los, "map_dn": maps, "split_dn": splits, "period_dn": periods}


def _common_period(parts) -> int:
    """The period all of one gain's maps share, with the same missing codes (0 if any is not
    periodic or they disagree; which neighbour a missing code goes to may differ)."""
    periods = {int(p.get("period_dn", [0])[0]) for p in parts}
    if len(periods) != 1 or 0 in periods:
        return 0
    period = periods.pop()
    pattern = set()
    for p in parts:
        lo, m = p["lo_dn"][0], np.asarray(p["map_dn"][0][:period])
        pattern.add(tuple(np.roll(m != lo + np.arange(period), int(lo % period)).tolist()))
    return period if len(pattern) == 1 else 0
