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
``p``-periodically equal to it in the map's first period is (a comb over the whole range,
or, where frames showed codes without it, from ``comb_from_dn`` up to ``comb_to_dn``).

Profile entry (per-K records)::  ``CodeMap: {k: [K, ...], lo_dn: [...], map_dn: [[c, ...], ...], split_dn: [[t, ...], ...], period_dn: [...], comb_from_dn: [...], comb_to_dn: [...], channel: [...]}``
(``map_dn[i]``: the code written for ``lo_dn + i``, DN relative to black, non-decreasing;
``split_dn``, optional: per code, the input (DN from the code, in [-0.5, 0.5]) from which it
goes up instead, 0.5 (never) by default; ``period_dn``, optional: 0, or the period of a comb
that repeats beyond the mapped range; ``comb_from_dn`` / ``comb_to_dn``, optional: the
lowest / highest code that comb reaches beyond the map (null: no bound); ``channel``, optional: the packed channel (0-3: R, G1,
B, G2) a record maps, -1 (every channel) by default; a gain has one record for every channel
or one for each).

Estimated by ``estimate`` as the ADC's transfer, not the noise's shape: every code the
camera writes maps to itself, so a signal keeps its DN (the map is measured on dark frames
but applied at every signal level); each missing code (none written, while the written codes
on both sides of its gap hold >= ``MIN_COUNT`` pixels each: ``statistics.comb_gaps``) goes
to those two neighbours, split at the input level where the current model's rounded values,
spread evenly over their cells, hold the share the lower neighbour has of the frames' pixels
of the gap (histogram matching: a differential non-linearity splits a missing code's inputs
between both neighbours; sending them all to one doubles its count and shifts the mean). Where the map's shifts repeat with a period (a digital gain, an ADC's
differential non-linearity; ``periodic_comb``), the period is stored and the comb is applied
at every signal level, not only over the codes the frames held; its written codes then take
their measured widths (``code_cells``: a digital gain of 1.25 writes 8 codes in 10, each 1.25
DN of input wide). A stack that shows codes without the comb, over MIN_PERIODS of its
periods or more beyond the maps (a bias frame under a dual gain's low-gain comb above 800 DN),
bounds it there. Where the packed channels' combs differ (a white-balance gain on red and
blue after the ADC), each channel has a map of its own.
A first version matched the whole histogram: fitted on a real dark frame it mapped 1..107 DN
onto 4..18 DN and wiped out the signal of the dark scenes it was trained on.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from ..statistics import MAX_COMB_GAP, MIN_COUNT, written_codes  # the rule for a missing code (comb_gaps there)
from .base import CLIP, NoiseEffect, register
from .k_records import record_index, validate_records

STATISTICS = ("missing_codes", "code_dnl")  # a missing code widens its neighbours: the code histogram's DNL too
MEASURED = True
ALL = -1  # a record's channel: every packed channel
UNBOUNDED = 1e30  # DN: a comb's bound where none is stored


@register
class CodeMap(NoiseEffect):
    token = "CodeMap"
    order = CLIP - 5
    flag = L.CODE_MAP
    columns = tuple(f"codemap_record_c{c}" for c in range(4))

    def draw(self, ctx):
        """Per packed channel, the record nearest each K among the channel's own and those
        for every channel (``ALL``)."""
        p = self.profile.effects[self.token]
        channels = p.get("channel", [ALL] * len(p["k"]))
        out = {}
        for c in range(4):
            mine = [i for i, ch in enumerate(channels) if ch in (c, ALL)]
            if not mine:
                out[f"codemap_record_c{c}"] = ctx.k * 0.0 - 1.0  # no map: rounded only
                continue
            j = record_index({"k": [p["k"][i] for i in mine]}, ctx.k)
            out[f"codemap_record_c{c}"] = torch.tensor(mine, dtype=torch.float64)[j]
        return out

    def tables(self):
        """``code_lut`` (records, 4, n): per code the code below the split, the code above it
        (the next the map writes), the split (DN from the code); row 3 the record's first code
        (DN), its length, its period (DN; 0: none) and the comb's lowest and highest code (DN;
        +-``UNBOUNDED``: none)."""
        p = self.profile.effects[self.token]
        luts = [np.asarray(m, dtype=np.float64) for m in p["map_dn"]]
        splits = p.get("split_dn") or [[0.5] * len(t) for t in luts]
        periods = p.get("period_dn", [0.0] * len(luts))
        froms = [-UNBOUNDED if f is None else f for f in p.get("comb_from_dn", [None] * len(luts))]
        tos = [UNBOUNDED if t is None else t for t in p.get("comb_to_dn", [None] * len(luts))]
        table = np.zeros((len(luts), 4, max(5, max(len(t) for t in luts))))
        table[:, 2] = 0.5
        for i, (t, split) in enumerate(zip(luts, splits)):
            table[i, 0, : t.size] = t
            table[i, 1, : t.size] = next_above(t)
            table[i, 2, : t.size] = split
            table[i, 3, :5] = (p["lo_dn"][i], t.size, periods[i], froms[i], tos[i])
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
        for key, side in (("comb_from_dn", -1), ("comb_to_dn", 1)):
            bounds = params.get(key, [None] * len(params["k"]))
            if not isinstance(bounds, (list, tuple)) or len(bounds) != len(params["k"]):
                raise ValueError(f"effect 'CodeMap': {key} must list one bound (DN, or null for none) per k, got {bounds!r:.80}")
            for i, (b, codes) in enumerate(zip(bounds, params["map_dn"])):
                if b is None:
                    continue
                edge = params["lo_dn"][i] + (len(codes) - 1 if side > 0 else 0)
                where = "at or above the map's last" if side > 0 else "at or below the map's first"
                if isinstance(b, bool) or not isinstance(b, (int, float)) or b != np.rint(b) or (b - edge) * side < 0:
                    raise ValueError(f"effect 'CodeMap': {key}[{i}] must be null (no bound) or a whole DN {where} "
                                     f"code {edge:g}, got {b!r}")
        channels = params.get("channel", [ALL] * len(params["k"]))
        if not isinstance(channels, (list, tuple)) or len(channels) != len(params["k"]) \
                or any(isinstance(c, bool) or c not in (ALL, 0, 1, 2, 3) for c in channels):
            raise ValueError(f"effect 'CodeMap': channel must list one packed channel per record (0-3, or -1 for every "
                             f"channel), got {channels!r:.80}")
        for k in set(params["k"]):  # a gain's records: one for every channel, or one per channel
            at = sorted(c for kk, c in zip(params["k"], channels) if kk == k)
            if at not in ([ALL], [0, 1, 2, 3]):
                raise ValueError(f"effect 'CodeMap': at k {k} the records' channels must be [-1] (one map for every "
                                 f"channel) or [0, 1, 2, 3] (one each), got {at}")


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


def _clear(counts, missing, first: float) -> list:
    """The code ranges [a, b] shown without a missing code by the ``counts`` of the codes from
    ``first`` up: between the lowest and the highest code holding MIN_COUNT pixels or more
    (where a missing code would show), below the first missing code (``missing``: indices
    into ``counts``) and its written neighbour, and above the last and its neighbour; the
    whole range where none is."""
    full = np.flatnonzero(counts >= MIN_COUNT)
    if full.size == 0:
        return []
    a, b = full[0], full[-1]
    spans = [(a, b)] if missing.size == 0 else [(a, missing[0] - 2), (missing[-1] + 2, b)]
    return [[float(first + lo), float(first + hi)] for lo, hi in spans if hi >= lo]


def _channel_map(v, model):
    """(codes r, map, splits, period, clear) of one population of whole-DN values ``v`` and the
    model's values for it: identity on written codes; the inputs of each gap of missing codes
    split between the written codes bounding it (``_gap_split``); the map spans the gaps only,
    with a periodic comb's first period in front; ``clear`` the codes shown without a missing
    one (``_clear``)."""
    written = written_codes(v)
    missing = np.flatnonzero(~written)
    r = np.arange(v.min(), v.min() + written.size)
    codes, split = r.copy(), np.full(r.size, 0.5)
    counts = np.bincount((v - r[0]).astype(np.int64), minlength=r.size).astype(np.float64)  # of the codes r
    clear = _clear(counts, missing, r[0])
    if missing.size:
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
    counts = np.bincount((v - r[0]).astype(np.int64)[(v >= r[0]) & (v <= r[-1])], minlength=r.size).astype(np.float64)
    period, template, split_template = periodic_comb(r, codes, split, counts)
    if period:  # the comb's period in front: the kernel repeats the map's first period beyond its range
        phase = ((r - r[0]) % period).astype(np.int64)
        codes, split = r + template[phase], split_template[phase]  # one comb over the whole range
        r = np.concatenate([r[0] - period + np.arange(period), r])
        codes = np.concatenate([r[:period] + template, codes])
        split = np.concatenate([split_template, split])
    return r, codes, split, period, clear


def _agree(maps) -> bool:
    """True when per-channel maps move the same codes between the first and the last code
    that every one of them moves (one comb in every channel: a digital gain, an ADC shared by
    all); False where they differ or do not meet (channels at levels apart)."""
    spans = [m[0][m[1] != m[0]] for m in maps]
    if any(sp.size == 0 for sp in spans):
        return False
    period = maps[0][3]
    if period and all(m[3] == period for m in maps):  # periodic combs: the same codes moved in a period
        phases = [tuple(np.roll(m[1][:period] != m[0][:period], int(m[0][0] % period)).tolist()) for m in maps]
        return len(set(phases)) == 1
    lo, hi = max(sp[0] for sp in spans), min(sp[-1] for sp in spans)
    moved = [(m[1] != m[0])[(m[0] >= lo) & (m[0] <= hi)] for m in maps]
    return hi >= lo and all(np.array_equal(moved[0], m) for m in moved[1:])


def _record(k, maps, channels) -> dict:
    """A stack's record; ``clear_dn`` (per map, the code ranges its values show without a
    missing code, ``_clear``) is for ``combine``, which bounds a periodic comb by them, and is
    not a profile entry."""
    out = {"k": [float(k)] * len(maps), "lo_dn": [float(m[0][0]) for m in maps],
           "map_dn": [[float(c) for c in m[1]] for m in maps], "split_dn": [[float(t) for t in m[2]] for m in maps],
           "period_dn": [float(m[3]) for m in maps], "clear_dn": [m[4] for m in maps]}
    if channels != [ALL]:
        out["channel"] = channels
    return out


def estimate(frames, synthesized, k: float, **_) -> dict:
    """Code map at gain ``k`` from a stack of whole-DN values (N, 4, h, w) and stacks the
    current model synthesized for it (rounded): one map for every channel (``_channel_map``),
    or, where the channels' combs differ (a white-balance gain on red and blue after the ADC,
    a converter per colour), one per packed channel, the identity where a channel has none."""
    v = np.asarray(frames, dtype=np.float64)
    if not np.all(v == np.rint(v)):
        raise ValueError("CodeMap needs frames of whole DN (real raw codes)")
    model = np.rint(np.asarray(synthesized, dtype=np.float64))
    whole = _channel_map(v.ravel(), model.ravel())
    if v.ndim < 3 or v.shape[-3] != 4:
        return _record(k, [whole], [ALL])
    per_model = model.shape[-3:] == v.shape[-3:]
    maps = [_channel_map(v[..., c, :, :].ravel(), (model[..., c, :, :] if per_model else model).ravel()) for c in range(4)]
    combed = [bool(np.any(m[1] != m[0])) for m in maps]
    if not any(combed) or (all(combed) and _agree(maps)):
        return _record(k, [whole], [ALL])
    # a channel without a comb: rounded only (the codes it showed bound the others' comb)
    identity = [(np.zeros(1), np.zeros(1), np.full(1, 0.5), 0, m[4]) for m in maps]
    return _record(k, [m if has else ident for m, ident, has in zip(maps, identity, combed)], list(range(4)))


SNAP = 0.1  # DN: a code's measured boundary this close to a cell's edge is taken to be on it
MIN_PERIODS = 3  # a comb is periodic where its pattern repeats this many times over the measured range
PERIODIC = 0.98  # ... at this share of its codes or more (a sparse tail's gaps do not count as missing)


def periodic_comb(r, codes, split=None, counts=None):
    """(period, shifts of one period, splits of one period) of a code map ``codes`` (with its
    ``split``) over codes ``r``: where the moved (missing) codes repeat with a period p up to
    2 (MAX_COMB_GAP + 1) over PERIODIC of the range, which spans MIN_PERIODS periods or more, p and each
    phase's most common shift and median split (phase j: the codes r[0] + j + n p), or, given
    the measured ``counts`` of the codes ``r``, the shifts and splits of the written codes'
    measured widths (``code_cells``); else (0, None, None). A digital gain or an ADC's
    differential non-linearity makes such a comb over the whole code range, not only where the
    frames had pixels."""
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
                values, times = np.unique(shift[j::p], return_counts=True)
                template.append(values[np.argmax(times)])
                same = split[j::p][shift[j::p] == template[-1]]
                splits.append(float(np.median(same)) if template[-1] != 0 else 0.5)
            if counts is not None:  # the written codes' widths measured: a digital gain's codes are equally wide
                cells = code_cells(r, np.asarray(counts, dtype=np.float64), np.asarray(template) != 0, p)
                if cells is not None:
                    return p, cells[0], cells[1]
            return p, np.asarray(template), np.asarray(splits)
    return 0, None, None


def code_cells(r, counts, moved, p: int):
    """(shifts, splits) of one period (phase j: code r[0] + j) of a periodic comb from the
    widths of its written codes: each written phase's width (DN of input) is its count over the
    local count per DN (the counts' mean over the p codes about it), averaged over the periods
    and scaled to fill the period; the codes' input cells laid end to end and placed so that
    their centres sit on their codes in the mean (a signal keeps its level). A digital gain of
    1.25 writes 8 codes in 10, each 1.25 DN of input wide: sending each missing code's inputs
    to its neighbours made those 1.5 DN wide and the others 1. None where no width is measured
    or a written code would be narrower than the cell split can hold (0.5 DN)."""
    written = np.flatnonzero(~moved)
    if written.size == 0 or r.size < 3 * p:
        return None
    density = np.convolve(counts, np.ones(p) / p, mode="same")
    inner = np.zeros(r.size, dtype=bool)
    inner[p : r.size - p] = True  # full windows only
    phase = ((r - r[0]) % p).astype(np.int64)
    width = np.zeros(p)
    for j in written:
        at = inner & (phase == j) & (density > 0)
        if not at.any() or density[at].sum() <= 0:
            return None
        width[j] = counts[at].sum() / density[at].sum()
    if width[written].min() <= 0:
        return None
    width *= p / width.sum()
    if width[written].min() < 0.5:
        return None
    upper = np.cumsum(width[written])  # each written code's upper edge, from the period's first lower edge at 0
    lower = upper - width[written]
    anchor = float(np.mean(written - 0.5 * (lower + upper)))  # centres on their codes in the mean
    codes = np.concatenate([written + q * p for q in (-1, 0, 1)]).astype(np.float64)
    lo = np.concatenate([lower + q * p for q in (-1, 0, 1)]) + anchor
    edge = np.floor(lo) + 0.5  # the nearest cell edge at or below (cells [c - 0.5, c + 0.5))
    edge = np.where(lo - edge > 0.5, edge + 1.0, edge)
    lo = np.where(np.abs(lo - edge) < SNAP, edge, lo)  # a boundary within SNAP of a cell's edge is on it (the widths' noise)
    hi = np.r_[lo[1:], lo[-1] + width[written][0]]
    shifts, splits = np.zeros(p), np.full(p, 0.5)
    for j in range(p):  # cell j: inputs [j - 0.5, j + 0.5) about code j of the period
        below = int(np.searchsorted(lo, j - 0.5, side="right") - 1)  # the code whose cell holds the cell's lower end
        shifts[j] = codes[below] - j
        if hi[below] < j + 0.5:  # its cell ends inside: the inputs above go to the next code
            splits[j] = hi[below] - j
    return shifts, np.clip(splits, -0.5, 0.5)


def _single(records):
    """(K, channel, one-record dict) for every record of ``records``."""
    for r in records:
        n = len(r["k"])
        channels = r.get("channel", [ALL] * n)
        splits = r.get("split_dn") or [[0.5] * len(m) for m in r["map_dn"]]
        periods = r.get("period_dn", [0.0] * n)
        clear = r.get("clear_dn", [[]] * n)
        for i in range(n):
            yield float(r["k"][i]), int(channels[i]), {"k": [r["k"][i]], "lo_dn": [r["lo_dn"][i]], "map_dn": [r["map_dn"][i]],
                                                      "split_dn": [splits[i]], "period_dn": [periods[i]], "clear_dn": clear[i]}


def _is_identity(part) -> bool:
    return len(part["map_dn"][0]) == 1 and part["map_dn"][0][0] == part["lo_dn"][0]


def combine(records: list[dict]) -> dict:
    """One map per gain (and, where the stacks found the channels' combs to differ, one per
    packed channel, the maps for every channel joined into each): the maps of the stacks at
    one K (bias, dark, flats cover different code ranges) joined over their union (``_join``)."""
    by_k: dict = {}
    for k, channel, part in _single(records):
        by_k.setdefault(k, {}).setdefault(channel, []).append(part)
    keys = ("k", "lo_dn", "map_dn", "split_dn", "period_dn", "comb_from_dn", "comb_to_dn", "channel")
    out: dict = {key: [] for key in keys}
    for k in sorted(by_k):
        groups = by_k[k]
        wanted = [ALL] if set(groups) == {ALL} else list(range(4))
        for channel in wanted:
            parts = groups.get(channel, []) + (groups.get(ALL, []) if channel != ALL else [])
            combed = [p for p in parts if not _is_identity(p)]
            lo, codes, split, period = _join(combed or parts[:1] or [{"lo_dn": [0.0], "map_dn": [[0.0]], "split_dn": [[0.5]],
                                                                       "period_dn": [0.0]}])
            if period:  # a periodic comb stops at the codes a stack showed without it
                lo, codes, split, below, above = bounded(parts, lo, codes, split, period)
            else:
                below = above = None
            for key, value in zip(keys, (k, lo, codes, split, period, below, above, channel)):
                out[key].append(value)
    if set(out["channel"]) == {ALL}:
        del out["channel"]
    for key in ("comb_from_dn", "comb_to_dn"):
        if all(b is None for b in out[key]):
            del out[key]
    return out


def bounded(parts, lo: float, codes, split, period: int):
    """(lo, map, splits, lowest code, highest code) of a periodic comb mapped over ``lo ..``:
    its codes in a range a stack showed without a missing code (``clear_dn``, over MIN_PERIODS
    periods or more: a bias stack under a dual gain's low-gain comb above 800 DN, a flat's
    codes below it) map to themselves, and its extension beyond the map stops at those ranges
    (None: it goes on)."""
    clear = [(a, b) for part in parts for a, b in part.get("clear_dn") or [] if b - a + 1 >= MIN_PERIODS * period]
    codes, split = np.asarray(codes, dtype=np.float64), np.asarray(split, dtype=np.float64)
    r = lo + np.arange(codes.size)
    inside = np.zeros(r.size, dtype=bool)
    for a, b in clear:
        inside |= (r >= a) & (r <= b)
    if inside.all():
        return lo, [float(c) for c in codes], [float(t) for t in split], lo, lo + codes.size - 1.0
    # clear codes at the map's ends leave it (its first period stays the comb the kernels repeat);
    # those inside it map to themselves
    first, last = np.flatnonzero(~inside)[[0, -1]]
    r, codes, split, inside = r[first : last + 1], codes[first : last + 1], split[first : last + 1], inside[first : last + 1]
    codes[inside], split[inside] = r[inside], 0.5
    codes = np.maximum.accumulate(codes)  # non-decreasing where a clear range ends inside the map
    lo, hi = float(r[0]), float(r[-1])
    below = [b for a, b in clear if a < lo]
    above = [a for a, b in clear if b > hi]
    lowest = min(max(below) + 1.0, lo) if below else None
    highest = max(min(above) - 1.0, hi) if above else None
    return lo, [float(c) for c in codes], [float(t) for t in split], lowest, highest


def _join(parts):
    """(lo, map, splits, period) of one gain's (and channel's) maps joined over their union;
    where two overlap the first stack's holds, and codes between them map to themselves, or,
    where all share one periodic comb, follow the widest map's (its shifts and splits, over
    every code)."""
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
        first = max((p for p in parts if int(p.get("period_dn", [0])[0]) == period), key=lambda p: len(p["map_dn"][0]))
        shift = np.asarray(first["map_dn"][0][:period]) - (first["lo_dn"][0] + np.arange(period))
        first_split = np.asarray((first.get("split_dn") or [[0.5] * period])[0][:period], dtype=np.float64)
        codes = np.arange(lo, hi + 1.0)
        phase = ((codes - first["lo_dn"][0]) % period).astype(np.int64)
        joined, split = codes + shift[phase], first_split[phase]
    kept = np.maximum.accumulate(joined)  # non-decreasing where ranges meet
    return (float(lo), [float(c) for c in kept], [float(t) if c == j else 0.5 for c, j, t in zip(kept, joined, split)],
            float(period))


def _missing(part) -> tuple[np.ndarray, np.ndarray]:
    """(codes, missing) of a map: each code of its range and whether the map never writes it."""
    m = np.asarray(part["map_dn"][0], dtype=np.float64)
    r = part["lo_dn"][0] + np.arange(m.size)
    return r, ~np.isin(r, m)


def _common_period(parts) -> int:
    """The period of one gain's periodic maps where they all have one and the same missing
    codes in it, and every map without one (a bias stack's few codes cannot show a period)
    misses codes only where that pattern does (0 where they disagree or none is periodic)."""
    periods = {int(p.get("period_dn", [0])[0]) for p in parts} - {0}
    if len(periods) != 1:
        return 0
    period = periods.pop()
    pattern = None
    for part in parts:
        if int(part.get("period_dn", [0])[0]) != period:
            continue
        r, missing = _missing(part)
        mine = np.zeros(period, dtype=bool)
        mine[(r[missing] % period).astype(np.int64)] = True
        if pattern is not None and not np.array_equal(pattern, mine):
            return 0
        pattern = mine
    for part in parts:  # the maps without a period: inside their range (not its bounding codes), as the pattern
        r, missing = _missing(part)
        inner = slice(1, max(r.size - 1, 1))
        if not np.array_equal(missing[inner], pattern[(r[inner] % period).astype(np.int64)]):
            return 0
    return period
