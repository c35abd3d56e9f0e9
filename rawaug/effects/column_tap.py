"""Column noise per readout tap (ColTap): each column tap of the sensor has temporal column
noise of its own level.

Physics: temporal column noise comes from each column's amplifier and ADC, whose offsets move
from frame to frame with the reference and ramp of the ADC bank that converts them. A sensor
whose columns are read through several banks (left and right halves, a CCD's taps, two
stitched dies) has banks of different noise: one half's column offsets may move by a DN while
the other's stay. The ``Col`` stage has one level for every column, so a model fitted to the
whole frame spreads the noisy bank's column noise over the quiet one (``RowTap`` is row noise
per tap, ``ReadMap`` white pixel noise per block).

Stage (DN): in frame ``b``, sensor column ``X`` adds ``sigma_dn(K)[tap(X)] * z[b, X]`` to its
pixels, ``z`` standard normal per frame and sensor column; the taps are cut by ``col_edges``
(the first sensor column of each new tap) on a measured frame of ``frame_h x frame_w`` packed
pixels; an input smaller than the frame is a window of it (as ``RowTap``).

Profile entry (up to ``MAX_EDGES`` edges; per gain one std per tap)::

    ColTap: {col_edges: [256], frame_h: 192, frame_w: 256, k: [K, ...], sigma_dn: [[s_0, s_1], ...]}

Detected on bias and dark stacks by ``col_noise_spread`` (the blocks of columns' column noise,
largest over smallest) and ``col_excess``. Estimated by ``estimate``: each sensor column's
temporal variance of its mean over the model's (``column_temporal_variance``), cut where its
scale changes (binary segmentation of a gamma scale, each cut a likelihood-ratio test at
``TAP_P`` over the gaps, taps of ``TAP_WINDOW`` columns or more), kept where at least half of
the stacks that found any found them and the taps either side differ by ``Z`` standard errors;
each tap's variance less the model's is its own column variance.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats as sstats

from ..engine import layout as L
from ..statistics import TAP_P, TAP_WINDOW, column_temporal_variance
from .base import BANDING, NoiseEffect, register
from .k_records import check_edges, column_edge_columns, validate_records, value_at_k
from .tap_black import _consensus

STATISTICS = ("col_noise_spread", "col_excess")
RAW_FRAMES = True  # the defect-line repair would replace a noisy tap's columns in the frames where they stand out from a quiet tap's
MAX_EDGES = L.TAP_EDGES
Z = 5.0  # standard errors a tap's column variance must stand from its neighbour's, and above 0
NOISY = 4.0  # a column this many times the median one's variance counts as that much in the search for edges


@register
class ColumnTap(NoiseEffect):
    token = "ColTap"
    order = BANDING
    flag = L.COL_TAP
    columns = tuple(f"ctap_s{i}" for i in range(MAX_EDGES + 1)) + tuple(f"ctap_c{i}" for i in range(MAX_EDGES)) + ("ctap_ox", "ctap_w")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        taps = len(p["col_edges"]) + 1
        out = {f"ctap_s{i}": _value_at_k(p, i, ctx.k) if i < taps else ctx.k.new_zeros(ctx.k.shape) for i in range(MAX_EDGES + 1)}
        return {**out, **column_edge_columns(ctx, self.token, p, "ctap", MAX_EDGES)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",))
        check_edges(cls.token, params, most=MAX_EDGES)
        edges = params["col_edges"]
        for r, rec in enumerate(params["sigma_dn"]):
            arr = np.asarray(rec, dtype=np.float64) if isinstance(rec, (list, tuple)) else None
            if arr is None or arr.shape != (len(edges) + 1,) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ValueError(f"effect 'ColTap': sigma_dn record {r} must hold {len(edges) + 1} values >= 0 (DN, one per "
                                 f"tap), got {rec!r:.80}")


def _value_at_k(params, tap: int, k):
    """(B,) the std of tap ``tap`` at the record nearest each K, DN."""
    return value_at_k({"k": params["k"], "v": [rec[tap] for rec in params["sigma_dn"]]}, "v", k)


def _split(u, lo: int, hi: int, dof: int, width: int):
    """(gap, 2 x log-likelihood ratio) of the best cut of ``u[lo:hi]`` into two runs each with a
    gamma scale of its own (``dof`` degrees of freedom per value), runs of ``width`` or more."""
    x = u[lo:hi]
    n = x.size
    if n < 2 * width:
        return None, 0.0
    c = np.concatenate([[0.0], np.cumsum(x)])
    j = np.arange(width, n - width + 1)
    left, right = c[j] / j, (c[-1] - c[j]) / (n - j)
    whole = c[-1] / n
    lr = dof * (n * np.log(whole) - j * np.log(left) - (n - j) * np.log(right))
    best = int(np.argmax(lr))
    return lo + int(j[best]), float(lr[best])


def edges_of(v, synth, n: int, width: int = TAP_WINDOW, p: float = TAP_P) -> list[int]:
    """Tap edges (sensor columns, ascending) of a stack's column variances ``v`` (2w,) over the
    model's ``synth`` (2w,), ``n`` frames: binary segmentation of their ratio (clipped at
    ``NOISY`` x its median: one noisy column is not a tap) while a cut's likelihood ratio
    passes the chi-square of 1 degree at ``p`` over the gaps."""
    u = v / np.maximum(synth, 1e-30)
    if n < 3 or u.size < 2 * width or not np.all(np.isfinite(u)):
        return []
    u = np.clip(u, 1e-6 * max(float(np.median(u)), 1e-30), NOISY * max(float(np.median(u)), 1e-30))
    limit = sstats.chi2.isf(p / u.size, 1)
    edges, runs = [], [(0, u.size)]
    while runs and len(edges) < MAX_EDGES:
        lo, hi = runs.pop()
        g, lr = _split(u, lo, hi, n - 1, width)
        if g is not None and lr > limit:
            edges.append(g)
            runs += [(lo, g), (g, hi)]
    return sorted(edges)


def _taps(edges, size: int) -> list[slice]:
    cuts = [0, *edges, size]
    return [slice(a, b) for a, b in zip(cuts[:-1], cuts[1:])]


def _tap_parts(s: dict, edges) -> tuple[np.ndarray, np.ndarray]:
    """(each tap's column variance less the model's (DN^2), its standard error) of one stack."""
    v, synth = s["v"], s["synth"]
    parts = _taps(edges, v.size)
    excess = np.array([float(v[t].mean() - synth[t].mean()) for t in parts])
    se = np.array([float(v[t].mean()) * math.sqrt(2.0 / ((s["n"] - 1) * (t.stop - t.start))) for t in parts])
    return excess, se


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """ColTap record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w; DN) against the
    model's ``synthesized`` stacks of it (``combine`` of this stack alone; what it saw is kept
    under ``"_seen"`` for ``combine`` over stacks)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3 or not len(synthesized):
        raise ValueError("ColTap is measured on bias or dark stacks of >= 3 frames, against syntheses")
    v = column_temporal_variance(frames)
    synth = np.mean([column_temporal_variance(np.asarray(x, dtype=np.float64)) for x in synthesized], axis=0)
    seen = {"k": float(k), "frame": frames.shape[2:], "v": v, "synth": synth, "n": frames.shape[0],
            "edges": edges_of(v, synth, frames.shape[0])}
    return {**combine([{"_seen": seen}]), "_seen": seen}


def combine(records: list[dict]) -> dict:
    """One set of taps (the sensor's): the edges found in at least half of the stacks that
    found any, on the frame size most stacks have, each kept where the taps either side of it
    differ by ``Z`` standard errors in at least half of those stacks; per stack each tap's
    column variance less the model's, kept where it stands ``Z`` standard errors above 0; the
    rms over the stacks of each gain."""
    seen = [r["_seen"] for r in records]
    frame = max((tuple(s["frame"]) for s in seen), key=lambda f: sum(tuple(t["frame"]) == f for t in seen))
    same = [s for s in seen if tuple(s["frame"]) == frame]
    edges = _consensus([s["edges"] for s in same if s["edges"]])
    while edges:  # the edge whose taps differ least, dropped until every one stands
        votes = np.zeros(len(edges))
        for s in same:
            excess, se = _tap_parts(s, edges)
            votes += np.abs(np.diff(excess)) > Z * np.hypot(se[:-1], se[1:])
        weakest = int(np.argmin(votes))
        if votes[weakest] >= len(same) / 2:
            break
        edges = edges[:weakest] + edges[weakest + 1:]
    by_k: dict = {}
    for s in same:
        if edges:
            excess, se = _tap_parts(s, edges)
            var = np.where(excess > Z * se, excess, 0.0)
        else:
            var = np.zeros(1)
        by_k.setdefault(s["k"], []).append(var)
    ks = sorted(by_k)
    return {"col_edges": [int(e) for e in edges], "frame_h": int(frame[0]), "frame_w": int(frame[1]), "k": ks,
            "sigma_dn": [[round(math.sqrt(max(float(v), 0.0)), 4) for v in np.mean(by_k[k], axis=0)] for k in ks]}


def empty(params) -> bool:
    """True when there is no edge or no column noise of the taps' own: it would add nothing."""
    return not params["col_edges"] or all(float(v) == 0.0 for rec in params["sigma_dn"] for v in rec)
