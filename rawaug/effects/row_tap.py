"""Row noise per readout tap (RowTap): each column tap of the sensor has row noise of its own,
new in every frame.

Physics: row noise comes from what a whole row's conversions share, the reference or the
ramp of the column-ADC bank that converts it. A sensor whose columns are read through
several banks (left and right halves, top and bottom banks taking alternate halves, a CCD's
taps) has one reference per bank, so each bank's part of a row moves on its own. The ELD row
noise ``R`` is one offset per whole sensor row; calibration reads ``sigma_r`` from whole-row
means, which average the banks' offsets, so the model spreads part of them over the whole row
and misses that the row steps at the banks' edge, by a new amount in every row and frame
(``TapBlack`` is a bank's offset per frame, the same in every row).

Stage (DN): in frame ``b``, sensor row ``Y`` adds ``sigma_dn(K) * z[b, Y, tap]`` to the pixels
of each column tap, ``z`` standard normal per frame, sensor row and tap. The taps are cut by
``col_edges`` (the first sensor column of each new tap) on a measured frame of ``frame_h x
frame_w`` packed pixels; an input smaller than the frame is a window of it (as ``TapBlack``).

Profile entry (up to ``MAX_EDGES`` edges)::

    RowTap: {col_edges: [256], frame_h: 192, frame_w: 256, k: [K, ...], sigma_dn: [...]}

Detected on bias and dark stacks by ``row_tap_ratio`` (the largest variance, over frames and
rows, of the step between the levels of the columns either side of a gap, over the median
gap's). Estimated by ``estimate``: the edges are the gaps where that step variance exceeds the
median's by more than chance at one of the gaps with probability ``TAP_P`` (a chi-square
over the rows and frames), kept where at least half of the stacks that found any found them;
half the step variance at an edge, less the median gap's and the model's, is the taps' own
row variance. Judged with ``sigma_r`` re-fitted.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats as sstats

from ..engine import layout as L
from ..statistics import ROW_TAP_ROWS, TAP_P, TAP_WINDOW, row_tap_steps
from .base import BANDING, NoiseEffect, register
from .k_records import check_edges, column_edge_columns, validate_records, value_at_k
from .tap_black import _consensus

STATISTICS = ("row_tap_ratio",)
SHARES_ROW_NOISE = True  # calibration gave the taps' row offsets to sigma_r (averaged over the row)
MAX_EDGES = L.TAP_EDGES
Z = 5.0  # standard errors an edge's excess step variance must reach to count


@register
class RowTap(NoiseEffect):
    token = "RowTap"
    order = BANDING
    flag = L.ROW_TAP
    columns = ("rtap_sigma",) + tuple(f"rtap_c{i}" for i in range(MAX_EDGES)) + ("rtap_ox", "rtap_w")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {"rtap_sigma": value_at_k(p, "sigma_dn", ctx.k), **column_edge_columns(ctx, self.token, p, "rtap", MAX_EDGES)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",), nonnegative=("sigma_dn",))
        check_edges(cls.token, params, most=MAX_EDGES)


def _rows(frames) -> int:
    """Sensor rows ``row_tap_steps`` reads of a stack."""
    h = frames.shape[2]
    return len(range(0, h, max(1, -(-2 * h // ROW_TAP_ROWS)))) * 2


def edges_of(s, n: int, rows: int, window: int = TAP_WINDOW, p: float = TAP_P) -> list[int]:
    """Tap edges (gaps, ascending) of step variances ``s`` (``row_tap_steps`` of a stack of
    ``n`` frames and ``rows`` sensor rows): the gaps beyond the median's by more than a
    chi-square of (n - 1)(rows - 1) degrees does by chance at one of the gaps with probability
    ``p``, the largest within ``window`` gaps (a tap's step rises over ``window`` gaps to its edge)."""
    ok = np.isfinite(s)
    if ok.sum() < 3 or n < 3:
        return []
    dof = (n - 1) * (rows - 1)
    ratio = sstats.chi2.isf(p / ok.sum(), dof) / sstats.chi2.median(dof)
    v = np.where(ok, s, -np.inf)
    high = v > max(float(np.median(s[ok])), 1e-30) * ratio
    peaks = [g for g in np.flatnonzero(high) if v[g] >= v[max(g - window, 0) : g + window + 1].max()]
    return sorted(int(g) for g in sorted(peaks, key=lambda g: -v[g])[:MAX_EDGES])  # the largest steps


def _excess(s, edges) -> float:
    """Half the mean step variance at ``edges`` less the median gap's (DN^2)."""
    ok = np.isfinite(s)
    return 0.5 * float(np.mean([s[e] for e in edges]) - np.median(s[ok]))


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """RowTap record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w; DN) against the
    model's ``synthesized`` stacks of it (``combine`` of this stack alone; what it saw is kept
    under ``"_seen"`` for ``combine`` over stacks)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3:
        raise ValueError("RowTap is measured on bias or dark stacks of >= 3 frames")
    s, rows = row_tap_steps(frames), _rows(frames)
    seen = {"k": float(k), "frame": frames.shape[2:], "steps": s, "n": frames.shape[0], "rows": rows,
            "edges": edges_of(s, frames.shape[0], rows),
            "synth": [row_tap_steps(np.asarray(x, dtype=np.float64)) for x in synthesized]}
    return {**combine([{"_seen": seen}]), "_seen": seen}


def combine(records: list[dict]) -> dict:
    """One set of taps (the sensor's): the edges found in at least half of the stacks that
    found any, on the frame size most stacks have; per stack the taps' row variance at them
    (``_excess`` less the model's), kept where it stands ``Z`` standard errors above 0; the
    rms over the stacks of each gain."""
    seen = [r["_seen"] for r in records]
    frame = max((tuple(s["frame"]) for s in seen), key=lambda f: sum(tuple(t["frame"]) == f for t in seen))
    same = [s for s in seen if tuple(s["frame"]) == frame]
    edges = _consensus([s["edges"] for s in same if s["edges"]])
    by_k: dict = {}
    for s in same:
        var = 0.0
        if edges:
            model = float(np.mean([_excess(x, edges) for x in s["synth"]])) if s["synth"] else 0.0
            excess = _excess(s["steps"], edges) - model
            se = 0.5 * float(np.mean([s["steps"][e] for e in edges])) * math.sqrt(2.0 / ((s["n"] - 1) * (s["rows"] - 1)))
            var = excess if excess > Z * se else 0.0
        by_k.setdefault(s["k"], []).append(var)
    ks = sorted(by_k)
    return {"col_edges": edges, "frame_h": int(frame[0]), "frame_w": int(frame[1]),
            "k": ks, "sigma_dn": [math.sqrt(max(float(np.mean(by_k[k])), 0.0)) for k in ks]}


def empty(params) -> bool:
    """True when there is no edge or no row noise of the taps' own: it would add nothing."""
    return not params["col_edges"] or all(float(v) == 0.0 for v in params["sigma_dn"])
