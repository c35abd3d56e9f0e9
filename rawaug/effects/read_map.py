"""Read-noise non-uniformity (ReadMap): read noise that differs by channel and by region.

Physics: a channel read through an amplifier of its own (one colour of a 2x2 tile), or a
readout split into halves or column groups, each with its own amplifier and ADC, has read
noise of its own level there. The ELD read noise has one level for the whole frame;
calibration measures the frame's average.

Synthesis: extra white read noise ``sqrt(c[ch]^2 + r[by]^2 + q[bx]^2) * z``, ``z`` standard
normal per pixel and frame, where ``by`` / ``bx`` are the row / column block of the pixel:
``READ_MAP_BLOCKS`` equal runs of the measured frame, or the runs between the measured
edges (``row_block_edges``, ``col_block_edges``: up to 7 increasing fractions of the frame;
a readout split where its amplifiers meet, a noisy edge of the array); an input smaller than
the measured frame is a window of it at an offset drawn per sample (as ``FPN`` shading).

Profile entry (per-K records; extra sigma in DN, frame size in packed pixels)::

    ReadMap: {k: [K, ...], channel_dn: [[4 values], ...], row_block_dn: [[8 values], ...],
              col_block_dn: [[8 values], ...], frame_h: H, frame_w: W,
              row_block_edges: [fractions], col_block_edges: [fractions]}  # optional

Detected by ``read_noise_spread`` (the channel, row-block and column-block main effects of the
log white temporal variance per cell: per-frame smooth fields and flickering pixels left
out). Estimated by ``estimate`` from bias stacks: per cell, the measured over the model's
white temporal variance, times the model's, less it; the channel main effect of that excess,
and along each axis the excess per packed row and column, cut by ``combine`` into the runs
of one level that fit the stacks of every gain best (``segments``: dynamic programming, the
number of runs by BIC, at most 8); each group shifted to start at 0 and kept only where an
F-test puts its block pattern beyond the model's at p < 1e-3. Judged with the read noise
re-fitted (calibration counted the extra noise in the frame's average).
"""
from __future__ import annotations

import numpy as np
import torch
from scipy import stats

from ..engine import layout as L
from ..statistics import highpass_gain, map_effects, variance_cells, variance_lines, white_variance
from .base import READ, NoiseEffect, register
from .k_records import all_zero, frame_size, record_index, validate_records, window_columns

STATISTICS = ("read_noise_spread",)
SHARES_READ_NOISE = True  # calibration counted its variance in the frame's read noise
P_VALUE = 1e-3  # a group's pattern counts where the model makes one as large less often
NB = L.READ_MAP_BLOCKS
GROUPS = (("channel_dn", "rmap_c", 4), ("row_block_dn", "rmap_y", NB), ("col_block_dn", "rmap_x", NB))
EDGES = (("row_block_edges", "rmap_ye"), ("col_block_edges", "rmap_xe"))
UNIFORM = [i / NB for i in range(1, NB)]  # the default edges: equal runs
NO_EDGE = 2.0  # an unused edge: beyond every position


@register
class ReadMap(NoiseEffect):
    token = "ReadMap"
    order = READ
    flag = L.READ_MAP
    columns = (tuple(f"{prefix}{i}" for _, prefix, n in GROUPS for i in range(n)) + ("rmap_oy", "rmap_ox", "rmap_h", "rmap_w")
               + tuple(f"{prefix}{i}" for _, prefix in EDGES for i in range(NB - 1)))

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        idx = record_index(p, ctx.k)
        out = {}
        for key, prefix, n in GROUPS:
            table = ctx.k.new_tensor(np.asarray(p[key], dtype=np.float64).reshape(len(p["k"]), n))
            for i in range(n):
                out[f"{prefix}{i}"] = table[idx, i]
        out.update(window_columns(ctx, self.token, p, ("rmap_oy", "rmap_ox", "rmap_h", "rmap_w")))
        for key, prefix in EDGES:
            edges = list(p.get(key, UNIFORM))
            for i, e in enumerate(edges + [NO_EDGE] * (NB - 1 - len(edges))):
                out[f"{prefix}{i}"] = torch.full_like(ctx.k, float(e))
        return out

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, tuple(key for key, _, _ in GROUPS))
        for key, _, n in GROUPS:
            for r, values in enumerate(params[key]):
                if not isinstance(values, (list, tuple)) or len(values) != n:
                    raise ValueError(f"effect 'ReadMap': {key} record {r} must list {n} values (extra sigma, DN), got {values!r:.80}")
                for v in values:
                    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                        raise ValueError(f"effect 'ReadMap': {key} values must be finite and >= 0 (DN), got {v!r}")
        frame_size(cls.token, params)
        for key, _ in EDGES:
            if key in params:
                e = params[key]
                if (not isinstance(e, (list, tuple)) or len(e) > NB - 1
                        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 < v < 1.0 for v in e)
                        or any(b <= a for a, b in zip(e, e[1:]))):
                    raise ValueError(f"effect 'ReadMap': {key} must list up to {NB - 1} increasing fractions of the frame "
                                     f"in (0, 1), got {e!r:.80}")


def pattern_beyond(measured, synth, p_value: float = P_VALUE) -> bool:
    """Is a measured pattern (n,) beyond the model's, its syntheses' (S, n)? An F-test: the
    measured pattern's deviation from the syntheses' mean, over the syntheses' own spread."""
    m = np.asarray(synth)
    s, n = m.shape
    spread = np.sum((m - m.mean(axis=0)) ** 2) / ((s - 1) * (n - 1)) * (1.0 + 1.0 / s)
    f = np.sum((measured - m.mean(axis=0)) ** 2) / (n - 1) / max(spread, 1e-300)
    return bool(stats.f.sf(f, n - 1, (s - 1) * (n - 1)) < p_value)


def _significant(measured, synth) -> list[bool]:
    """Per group (channel, row block, column block): is the measured main-effect pattern of the
    log cell variances beyond the model's (``pattern_beyond``, family-wise ``P_VALUE`` per group)?"""
    meas = map_effects(np.log(np.maximum(measured, 1e-12)))
    parts = [map_effects(np.log(np.maximum(c, 1e-12))) for c in synth]
    return [pattern_beyond(meas[g], np.array([p[g] for p in parts])) for g in range(len(GROUPS))]


MIN_RUN = 4  # packed lines of the shortest run: a single noisy line is NoisyCol's, not a readout block's
LINES = (("row_block_dn", "row_block_edges", "row_excess", "row_noise", "row_keep"),
         ("col_block_dn", "col_block_edges", "col_excess", "col_noise", "col_keep"))


def estimate(frames, synthesized, k: float, level_dn=None, kind: str = "bias", **_) -> dict:
    """ReadMap record at gain ``k`` from a bias stack (N >= 2, 4, h, w) in DN, against
    syntheses of it (at least 3): the channel part, and per packed row and column the white
    variance the model lacks with its noise (``combine`` cuts them into blocks). Dark stacks are
    left out: a dark current of uneven rate (glow) makes temporal noise uneven too."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "bias" or level_dn is not None or frames.shape[0] < 2 or len(synthesized) < 3:
        raise ValueError("ReadMap is measured on bias stacks of >= 2 frames, against >= 3 syntheses")
    gain = highpass_gain(*frames.shape[2:])
    white = [white_variance(frames)] + [white_variance(s) for s in synthesized]  # once per stack: cells and lines
    measured = variance_cells(*white[0])
    synth = np.array([variance_cells(*w) for w in white[1:]])
    model = synth.mean(axis=0)
    # per cell, the white variance the model lacks (the high pass kept highpass_gain of it), DN^2
    excess = model.mean() * (measured / np.maximum(model, 1e-12) - 1.0) / gain
    keep = _significant(measured, synth)
    channel = map_effects(excess)[0]
    channel = channel - channel.min() if keep[0] else np.zeros_like(channel)
    out = {"k": [float(k)], "frame_h": int(frames.shape[2]), "frame_w": int(frames.shape[3]),
           "channel_dn": [[float(v) for v in np.sqrt(channel)]]}
    lines_measured = variance_lines(*white[0])
    lines_synth = [variance_lines(*w) for w in white[1:]]
    for axis, (_, _, excess_key, noise_key, keep_key) in enumerate(LINES):
        parts = np.array([ls[axis] for ls in lines_synth])  # (S, n)
        model = parts.mean(axis=0)
        level = model.mean() / gain
        ratio = lines_measured[axis] / np.maximum(model, 1e-12)
        spread = parts / np.maximum(model, 1e-12) - 1.0  # each synthesis's own, about the model
        # a line's relative noise is the model's (a mean variance over its pixels); a noisier line's is as much larger
        noise = level * ratio * np.sqrt(spread.var(axis=0, ddof=1).mean() * (1.0 + 1.0 / len(parts)))
        out[excess_key], out[noise_key] = [(level * (ratio - 1.0)).tolist()], [noise.tolist()]
        out[keep_key] = [bool(keep[axis + 1])]
    return out


def segments(profiles, noise, max_runs: int = NB, min_runs: int = 1, min_run: int = MIN_RUN) -> list[int]:
    """Edges (the first line of each run but the first) of the runs of one level, common to
    the ``profiles`` (K, n), each with its own levels, that fit them best: the least squares
    over the profiles weighed by 1 / ``noise``^2 ((K,), or (K, n): one per line), by dynamic
    programming over runs of ``min_run`` lines or more; the number of runs in [min_runs,
    max_runs] by a BIC whose edges count as two parameters each (an edge placed where it fits
    best gains more than a level: plain BIC cuts white noise into runs)."""
    y = np.atleast_2d(np.asarray(profiles, dtype=np.float64))
    n_prof, n = y.shape
    w = 1.0 / np.maximum(np.broadcast_to(np.asarray(noise, dtype=np.float64).reshape(n_prof, -1), y.shape), 1e-12) ** 2
    zero = np.zeros((n_prof, 1))
    sw, s1, s2 = (np.concatenate([zero, np.cumsum(v, axis=1)], axis=1) for v in (w, w * y, w * y * y))
    a, b = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    d = lambda c: c[:, None, :] - c[:, :, None]  # noqa: E731  (K, a, b): the sum over lines a .. b - 1
    weight = d(sw)
    cost = (d(s2) - d(s1) ** 2 / np.where(weight > 0, weight, 1.0)).sum(axis=0)
    cost = np.where(b - a >= min_run, cost, np.inf)  # cost[a, b]: the run of lines a .. b - 1
    best = [cost[0]]  # best[m - 1][b]: lines 0 .. b - 1 in m runs
    back = [np.zeros(n + 1, dtype=np.int64)]
    for _ in range(1, max(1, min(max_runs, n // min_run))):
        total = best[-1][:, None] + cost
        back.append(np.argmin(total, axis=0))
        best.append(total[back[-1], np.arange(n + 1)])
    score = [best[m][n] + m * (n_prof + 2) * np.log(n * n_prof) if m + 1 >= min_runs else np.inf for m in range(len(best))]
    m = int(np.argmin(score))
    edges, end = [], n
    for runs in range(m, 0, -1):
        end = int(back[runs][end])
        edges.append(end)
    return sorted(edges)


def combine(records: list[dict]) -> dict:
    """One record per gain: the channel part averaged over the stacks at one K in variance; along
    each axis the stacks' line excesses averaged at each K, cut into the runs that fit every
    gain whose stacks show a pattern (``segments``, 2 runs at least), each run's level its mean
    excess less the lowest run's."""
    first = records[0]
    same = [r for r in records if (r["frame_h"], r["frame_w"]) == (first["frame_h"], first["frame_w"])]
    by_k: dict = {}
    for r in same:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    ks = sorted(by_k)
    out: dict = {"k": ks}
    out["channel_dn"] = [[float(v) for v in np.sqrt(np.mean([np.square(r["channel_dn"][0]) for r in by_k[k]], axis=0))] for k in ks]
    for key, edge_key, excess_key, noise_key, keep_key in LINES:
        excess = [np.mean([r[excess_key][0] for r in by_k[k]], axis=0) for k in ks]
        noise = [np.sqrt(np.mean([np.square(r[noise_key][0]) for r in by_k[k]], axis=0) / len(by_k[k])) for k in ks]
        keep = [any(r[keep_key][0] for r in by_k[k]) for k in ks]
        shown = [i for i in range(len(ks)) if keep[i]]
        edges = segments([excess[i] for i in shown], [noise[i] for i in shown], min_runs=2) if shown else []
        bounds = [0, *edges, len(excess[0])]
        out[key] = []
        for i in range(len(ks)):
            levels = np.array([excess[i][lo:hi].mean() for lo, hi in zip(bounds, bounds[1:])]) if keep[i] else np.zeros(1)
            var = np.concatenate([levels - levels.min(), np.zeros(NB - len(levels))])
            out[key].append([float(v) for v in np.sqrt(var)])
        if shown:
            out[edge_key] = [e / len(excess[0]) for e in edges]
    out["frame_h"], out["frame_w"] = first["frame_h"], first["frame_w"]
    return out


def empty(params) -> bool:
    """True when every amplitude is 0: it would add nothing."""
    return all_zero(params, tuple(g[0] for g in GROUPS))
