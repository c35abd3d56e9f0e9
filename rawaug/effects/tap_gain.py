"""Readout taps with a gain each (TapGain): the sensor read in regions (halves, quadrants,
bands), each through its own amplifier, whose gains differ.

Physics: a sensor read through several outputs (a CCD's two or four taps; a CMOS sensor
split into left and right halves, or top and bottom, each with a column-ADC bank and ramp of
its own) converts each region with a gain of its own, matched to a fraction of a per cent. A
flat steps at the edges between the regions, in proportion to its signal; bias frames do
not. ``ColGain`` is a gain of each column on its own; a light's shape (``illumination``)
is smooth: neither steps at one place. ``TapBlack`` is the same taps' black levels.

Stage (DN, after shot and read noise, before the rows' and the black levels' offsets):
``s -> s * gain[tap]``: the tap's chain amplifies the pixel's signal and its noise alike.
The taps are the cells of a grid: ``col_edges`` and ``row_edges`` are the first sensor
column / row of each new tap, on a measured frame of ``frame_h x frame_w`` packed pixels; an
input smaller than the frame is a window of it at an offset drawn per sample (as
``ReadMap``), an input as large or larger has them at the same fractions. The gains are
read from the kernels' grids table (one record, taps' rows x taps' columns).

Profile entry (up to ``MAX_EDGES`` edges per axis; gains of mean 1 over the frame's pixels)::

    TapGain: {col_edges: [512], row_edges: [], frame_h: 384, frame_w: 512, gain: [[0.9926, 1.0075]]}

Detected on flat stacks by ``gain_step_z`` (the largest step of a local fit of a cubic
plus a step to the log line profiles of the stack mean, over its noise). Estimated by
``estimate``: the edges are the gaps ``gain_edges`` finds, against the stack's white and
coloured temporal noise (``stack_step_excess``), over the stacks ``consensus_edges``; the
gains are the steps at the edges in each band of taps (``tap_log_gains``), less the
model's, averaged over the stacks by their noise.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from ..statistics import GAIN_WINDOW, flat_gain_edges, flat_log_mosaic, stack_step_excess, tap_log_gains
from .base import READ, NoiseEffect, register
from .tap_black import _bands, _consensus, tap_grid_columns, validate_edges

STATISTICS = ("gain_step_z",)
MAX_EDGES = L.TAP_EDGES  # edges per axis a profile may hold (up to 8 x 8 taps)
DECIMALS = 6


@register
class TapGain(NoiseEffect):
    token = "TapGain"
    order = READ + 5  # the tap's chain amplifies the pixel's signal and noise: after read noise, before the row offsets
    flag = L.TAP_GAIN
    columns = (("tgain_record",) + tuple(f"tgain_c{i}" for i in range(MAX_EDGES))
               + tuple(f"tgain_r{i}" for i in range(MAX_EDGES)) + ("tgain_oy", "tgain_ox", "tgain_h", "tgain_w"))

    def draw(self, ctx):
        first, _, _ = ctx.grid_slot(self.token)
        p = self.profile.effects[self.token]
        return {"tgain_record": ctx.k.new_full((ctx.k.shape[0],), float(first)), **tap_grid_columns(ctx, self.token, p, "tgain")}

    def tables(self):
        return {"grids": torch.tensor([self.profile.effects[self.token]["gain"]], dtype=torch.float64)}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r:.80}")
        known = {"col_edges", "row_edges", "frame_h", "frame_w", "gain"}
        unknown = sorted(set(params) - known)
        if unknown:
            raise ValueError(f"effect {cls.token!r}: unknown keys {unknown}; known: {sorted(known)}")
        validate_edges(cls.token, params)
        shape = (len(params["row_edges"]) + 1, len(params["col_edges"]) + 1)
        try:
            gain = np.asarray(params.get("gain"), dtype=np.float64)
        except (TypeError, ValueError):
            gain = None
        if gain is None or gain.shape != shape or not np.all(np.isfinite(gain)) or np.any(gain <= 0):
            raise ValueError(f"effect {cls.token!r}: gain must be {shape[0]} x {shape[1]} (row taps x column taps) finite "
                             f"gains > 0, got {params.get('gain')!r:.80}")


def gain_map(col_edges, row_edges, gain, h: int, w: int) -> np.ndarray:
    """(4, h, w) gain of each packed pixel of taps cut by ``col_edges`` and ``row_edges``
    (sensor lines) with gains ``gain`` (taps' rows x taps' columns)."""
    gain = np.asarray(gain, dtype=np.float64)
    ty, tx = _bands(row_edges, 2 * h), _bands(col_edges, 2 * w)  # the tap of each sensor row, column
    return np.stack([gain[ty[L.ROW_SET[ch]::2][:, None], tx[L.COLUMN_SET[ch]::2][None, :]] for ch in range(4)])


def shown_gains(mean_dn, edges=None, excess=None) -> np.ndarray:
    """(4, h, w) gains of the readout taps a flat's mean frame (4, h, w; DN above black) shows
    at ``edges`` ({"col": gaps, "row": gaps}: the sensor's, ``consensus_edges``; None: its
    own, ``flat_gain_edges`` with ``excess``, its stack's ``stack_step_excess``): the taps'
    gains there (``tap_log_gains``); 1 where there is no edge. What a light's smooth shape is
    fitted to once divided out."""
    mean_dn = np.asarray(mean_dn, dtype=np.float64)
    _, h, w = mean_dn.shape
    if min(h, w) < GAIN_WINDOW + 2:
        return np.ones_like(mean_dn)
    mosaic = flat_log_mosaic(mean_dn[None])
    if edges is None:
        edges = flat_gain_edges(mosaic, excess)
    if not edges["col"] and not edges["row"]:
        return np.ones_like(mean_dn)
    log_gain, _ = tap_log_gains(mosaic, edges["col"], edges["row"])
    return gain_map(edges["col"], edges["row"], np.exp(log_gain), h, w)


def consensus_edges(found: list[dict]) -> dict:
    """{"col": gaps, "row": gaps}: a sensor's readout-tap edges from the edges of its flats
    (``flat_gain_edges`` of each, of one frame size): along each axis those found in at least
    half of the flats that found any, and in two flats where there are two. A tap is the
    sensor's, the same at every gain and level (a brighter flat shows it better); a flat's
    noise steps at a gap of its own."""
    return {axis: _consensus([f[axis] for f in found if f[axis]], at_least=min(2, len(found))) for axis in ("col", "row")}


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """TapGain from a flat stack (N >= 1, 4, h, w; DN), against the model's ``synthesized``
    stacks of it (``combine`` of this stack alone; what it saw is kept under ``"_seen"`` for
    ``combine`` over stacks)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "flat":
        raise ValueError(f"TapGain is measured on flat stacks, got a {kind!r} stack")
    if frames.ndim != 4 or frames.shape[1] != 4 or min(frames.shape[2:]) < GAIN_WINDOW + 2:
        raise ValueError(f"TapGain needs a flat stack (N, 4, h, w) at least {GAIN_WINDOW + 2} packed pixels a side, "
                         f"got {frames.shape}")
    mosaic = flat_log_mosaic(frames)
    edges = flat_gain_edges(mosaic, stack_step_excess(frames))
    model = np.mean([flat_log_mosaic(s) for s in synthesized], axis=0) if synthesized else np.zeros_like(mosaic)
    seen = {"frame": frames.shape[2:], "mosaic": mosaic.astype(np.float32), "model": model.astype(np.float32), "edges": edges}
    return {**combine([{"_seen": seen}]), "_seen": seen}


def combine(records: list[dict]) -> dict:
    """One set of taps (the sensor's, the same at every gain and level): the edges of
    ``consensus_edges`` over the stacks of the frame size most stacks have; the log gains
    of each stack at those edges less its model's (``tap_log_gains``), averaged per tap with
    weights 1 / standard error^2; their mean over the frame's pixels 1."""
    seen = [r["_seen"] for r in records]
    frame = max((tuple(s["frame"]) for s in seen), key=lambda f: sum(tuple(t["frame"]) == f for t in seen))
    same = [s for s in seen if tuple(s["frame"]) == frame]
    edges = consensus_edges([s["edges"] for s in same])
    shape = (len(edges["row"]) + 1, len(edges["col"]) + 1)
    total, weight = np.zeros(shape), np.zeros(shape)
    for s in same:
        g, se = tap_log_gains(s["mosaic"], edges["col"], edges["row"])
        g0, _ = tap_log_gains(s["model"], edges["col"], edges["row"])
        w = np.where(np.isfinite(se) & (se > 0), 1.0 / np.maximum(se, 1e-12) ** 2, 0.0)
        total += w * (g - g0)
        weight += w
    gain = np.exp(np.where(weight > 0, total / np.maximum(weight, 1e-300), 0.0))
    # the taps' pixel-weighted mean 1: a flat keeps its level (the taps' plain mean, before, put a
    # band of 40 rows at 0.97 between two taps at 1.010 and the flats 0.7 % too bright)
    rows = np.bincount(_bands(edges["row"], 2 * int(frame[0])), minlength=shape[0])
    cols = np.bincount(_bands(edges["col"], 2 * int(frame[1])), minlength=shape[1])
    gain /= float(np.sum(np.outer(rows, cols) * gain) / (rows.sum() * cols.sum()))
    return {"col_edges": edges["col"], "row_edges": edges["row"], "frame_h": int(frame[0]), "frame_w": int(frame[1]),
            "gain": np.round(gain, DECIMALS).tolist()}


def empty(params) -> bool:
    """True when there is no edge or every gain is 1: it would change nothing."""
    return (not params["col_edges"] and not params["row_edges"]) or bool(np.all(np.asarray(params["gain"]) == 1.0))
