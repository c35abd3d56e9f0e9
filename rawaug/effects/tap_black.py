"""Readout taps with a black level each (TapBlack): the sensor read in regions (halves,
quadrants, bands), each through its own amplifier and black-level clamp, whose black levels
move from frame to frame independently.

Physics: a sensor read through several outputs (a CCD's two or four taps; a CMOS sensor
split into left and right halves, or top and bottom, each with its own column-ADC bank and
clamp) has one clamp per region, and each settles to its own value in every frame. The
frame's mean moves with their average (what ``BLE`` sees); at the edges between regions the
picture steps, by a new amount in every frame. ``Col`` is an offset of each column on its
own, ``LowFreq`` a smooth field: neither steps at one place in every frame.

Stage (DN, with the offsets): ``s -> s + sigma_dn(K) * z[frame, tap]``, ``z`` a standard
normal per frame and tap. The taps are the cells of a grid: ``col_edges`` and ``row_edges``
are the first sensor column / row of each new tap, on a measured frame of ``frame_h x
frame_w`` packed pixels; an input smaller than the frame is a window of it at an offset drawn
per sample (as ``ReadMap``), an input as large or larger has them at the same fractions.

Profile entry (up to ``MAX_EDGES`` edges per axis)::

    TapBlack: {col_edges: [512], row_edges: [], frame_h: 384, frame_w: 512, k: [K, ...], sigma_dn: [...]}

Detected on bias and dark stacks by ``tap_step_ratio`` (the largest temporal variance of the
step between the medians of the lines either side of a gap, over the median gap's) and by the
frame-mean statistics its taps' average moves. Estimated by ``estimate``: the edges are the
gaps ``tap_edges`` finds (over the stacks, those found in at least half of the stacks that
found any); the offsets' variance is the taps' frame-mean variance less their covariance
(what they share is ``BLE``'s), less the model's, from the stacks' sensor-line means.
"""
from __future__ import annotations

import math

import numpy as np

from ..engine import layout as L
from ..statistics import TAP_WINDOW, sensor_col_means, sensor_row_means, tap_edges, tap_steps
from .base import OFFSET, NoiseEffect, register
from .k_records import frame_size, validate_records, value_at_k, window_columns

STATISTICS = ("tap_step_ratio", "frame_mean_std", "frame_mean_common_cov")
SHARES_ROW_NOISE = True  # calibration's sigma_r holds the steps of taps along the rows: judged with the row noise re-fitted
MAX_EDGES = L.TAP_EDGES  # edges per axis a profile may hold (up to 8 x 8 taps)


@register
class TapBlack(NoiseEffect):
    token = "TapBlack"
    order = OFFSET
    flag = L.TAP_BLACK
    columns = (("tap_sigma",) + tuple(f"tap_c{i}" for i in range(MAX_EDGES))
               + tuple(f"tap_r{i}" for i in range(MAX_EDGES)) + ("tap_oy", "tap_ox", "tap_h", "tap_w"))

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {"tap_sigma": value_at_k(p, "sigma_dn", ctx.k), **tap_grid_columns(ctx, self.token, p, "tap")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",), nonnegative=("sigma_dn",))
        validate_edges(cls.token, params)


def tap_grid_columns(ctx, token: str, params: dict, prefix: str) -> dict:
    """Kernel columns of a tap grid: ``{prefix}_c0..``, ``{prefix}_r0..`` (each edge as a
    fraction of the frame's sensor lines; 2: no edge) and the input's window of the measured
    frame (``{prefix}_oy``, ``_ox``, ``_h``, ``_w``: ``window_columns``)."""
    n = ctx.k.shape[0]
    h, w = frame_size(token, params)
    out = {}
    for axis, size in (("c", w), ("r", h)):
        edges = params["col_edges" if axis == "c" else "row_edges"]
        for i in range(MAX_EDGES):
            out[f"{prefix}_{axis}{i}"] = ctx.k.new_full((n,), edges[i] / (2.0 * size) if i < len(edges) else 2.0)
    out.update(window_columns(ctx, token, params, tuple(f"{prefix}_{s}" for s in ("oy", "ox", "h", "w"))))
    return out


def validate_edges(token: str, params: dict) -> None:
    """A tap grid's ``frame_h``/``frame_w`` and its ``col_edges``/``row_edges``: at most
    ``MAX_EDGES`` whole sensor lines each, strictly increasing, inside the frame."""
    size = frame_size(token, params)
    if size is None:
        raise ValueError(f"effect {token!r} needs frame_h and frame_w (packed pixels of the frame its edges are on)")
    for key, lines in (("col_edges", 2 * size[1]), ("row_edges", 2 * size[0])):
        edges = params.get(key)
        if not isinstance(edges, (list, tuple)) or len(edges) > MAX_EDGES:
            raise ValueError(f"effect {token!r}: {key} must be a list of at most {MAX_EDGES} sensor lines, got {edges!r:.80}")
        for e in edges:
            if isinstance(e, bool) or not isinstance(e, int) or not 0 < e < lines:
                raise ValueError(f"effect {token!r}: {key} values must be whole sensor lines in (0, {lines}), got {e!r}")
        if list(edges) != sorted(set(edges)):
            raise ValueError(f"effect {token!r}: {key} must be strictly increasing, got {list(edges)}")


def _bands(edges, lines: int) -> np.ndarray:
    """(lines,) tap index of each sensor line."""
    return np.searchsorted(np.asarray(edges, dtype=np.int64), np.arange(lines), side="right")


def offset_variance(m, edges) -> float:
    """Of sensor-line means ``m`` (N, L; DN) and the taps' ``edges`` along them: the mean over
    the taps of their frame means' variance less the mean covariance between two taps (DN^2):
    an independent offset per tap and frame counts once, one shared by all taps not at all."""
    band = _bands(edges, m.shape[1])
    means = np.stack([m[:, band == t].mean(axis=1) for t in range(len(edges) + 1)], axis=1)  # (N, T)
    c = np.cov(means.T)
    t = c.shape[0]
    return float(np.trace(c) / t - (c.sum() - np.trace(c)) / (t * (t - 1)))


def _line_means(frames) -> dict:
    return {"col": sensor_col_means(frames), "row": sensor_row_means(frames)}


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """TapBlack record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w; DN), against
    the model's ``synthesized`` stacks of it (``combine`` of this stack alone; what it saw is
    kept under ``"_seen"`` for ``combine`` over stacks)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3:
        raise ValueError("TapBlack is measured on bias or dark stacks of >= 3 frames")
    lines = _line_means(frames)
    edges = {}
    for axis, m in lines.items():
        s = tap_steps(m)
        found = tap_edges(m)
        edges[axis] = sorted(sorted(found, key=lambda g: -s[g])[:MAX_EDGES])  # the largest steps
    seen = {"k": float(k), "frame": frames.shape[2:], "lines": lines, "edges": edges,
            "synth": [_line_means(np.asarray(s, dtype=np.float64)) for s in synthesized]}
    return {**combine([{"_seen": seen}]), "_seen": seen}


def _consensus(found: list[list[int]], at_least: int = 1) -> list[int]:
    """Edges found in at least half of ``found`` (lists of edges of the stacks that found
    any), and in ``at_least`` of them: those within ``TAP_WINDOW`` lines of each other are
    one edge, at their median."""
    if not found:
        return []
    points = sorted(e for edges in found for e in edges)
    groups: list[list[int]] = []
    for e in points:
        if groups and e - groups[-1][-1] <= TAP_WINDOW:
            groups[-1].append(e)
        else:
            groups.append([e])
    need = max(math.ceil(len(found) / 2), at_least)
    return [int(np.median(g)) for g in groups if len(g) >= need][:MAX_EDGES]


def combine(records: list[dict]) -> dict:
    """One set of taps (the sensor's): the edges found in at least half of the stacks that
    found any, on the frame size most stacks have; then per stack, the offsets' variance
    (``offset_variance`` along each axis with edges, times the other axis's taps, which
    a line mean averages) less the model's, averaged per gain."""
    seen = [r["_seen"] for r in records]
    frame = max((tuple(s["frame"]) for s in seen), key=lambda f: sum(tuple(t["frame"]) == f for t in seen))
    same = [s for s in seen if tuple(s["frame"]) == frame]
    edges = {axis: _consensus([s["edges"][axis] for s in same if s["edges"][axis]]) for axis in ("col", "row")}
    by_k: dict = {}
    for s in same:
        parts = []
        for axis, other in (("col", "row"), ("row", "col")):
            if edges[axis]:
                model = np.mean([offset_variance(x[axis], edges[axis]) for x in s["synth"]]) if s["synth"] else 0.0
                parts.append((offset_variance(s["lines"][axis], edges[axis]) - model) * (len(edges[other]) + 1))
        by_k.setdefault(s["k"], []).append(float(np.mean(parts)) if parts else 0.0)
    ks = sorted(by_k)
    return {"col_edges": edges["col"], "row_edges": edges["row"], "frame_h": int(frame[0]), "frame_w": int(frame[1]),
            "k": ks, "sigma_dn": [math.sqrt(max(float(np.mean(by_k[k])), 0.0)) for k in ks]}


def empty(params) -> bool:
    """True when there is no edge or no offset: it would add nothing."""
    return (not params["col_edges"] and not params["row_edges"]) or all(float(v) == 0.0 for v in params["sigma_dn"])
