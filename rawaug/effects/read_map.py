"""Read-noise non-uniformity (ReadMap): read noise that differs by channel and by region.

Physics: a channel read through an amplifier of its own (one colour of a 2x2 tile), or a
readout split into halves or column groups, each with its own amplifier and ADC, has read
noise of its own level there. The ELD read noise has one level for the whole frame;
calibration measures the frame's average.

Synthesis: extra white read noise ``sqrt(c[ch]^2 + r[by]^2 + q[bx]^2 + cell[by, bx]^2) * z``,
``z`` standard normal per pixel and frame, where ``by`` / ``bx`` are the row / column block of the pixel:
``READ_MAP_BLOCKS`` equal runs of the measured frame, or the runs between the measured
edges (``row_block_edges``, ``col_block_edges``: up to 7 increasing fractions of the frame;
a readout split where its amplifiers meet, a noisy edge of the array); an input smaller than
the measured frame is a window of it at an offset drawn per sample (as ``FPN`` shading). The
cells are the blocks' crossings: a region read through an amplifier of its own (a quadrant, a
damaged patch) is noisier in one cell, not along a whole row block and column block.

Profile entry (per-K records; extra sigma in DN, frame size in packed pixels)::

    ReadMap: {k: [K, ...], channel_dn: [[4 values], ...], row_block_dn: [[8 values], ...],
              col_block_dn: [[8 values], ...], frame_h: H, frame_w: W,
              row_block_edges: [fractions], col_block_edges: [fractions],  # optional
              cell_dn: [[[8 values] x 8], ...]}  # optional: per record, row blocks x column blocks

Detected by ``read_noise_spread`` (the channel, row-block and column-block main effects of the
log white temporal variance per cell: per-frame smooth fields and flickering pixels left
out). Estimated by ``estimate`` from bias stacks: per cell, the measured over the model's
white temporal variance, times the model's, less it; the channel main effect of that excess,
and along each axis the excess per packed row and column, cut by ``combine`` into the runs
of one level that fit the stacks of every gain best (``segments``: dynamic programming, the
number of runs by BIC, at most 8); each group shifted to start at 0 and kept only where an
F-test puts its block pattern beyond the model's at p < 1e-3. Where the excess per cell of
those blocks departs from the row and column levels' sum (a chi-square of the interaction at
p < 1e-3; ``cell_levels``), the cells take it whole and the blocks none. Judged with the read
noise re-fitted (calibration counted the extra noise in the frame's average).
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
               + tuple(f"{prefix}{i}" for _, prefix in EDGES for i in range(NB - 1)) + ("rmap_cell_record",))

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
        out["rmap_cell_record"] = ((ctx.grid_slot(self.token)[0] + idx).to(torch.float64) if "cell_dn" in p
                                   else torch.full_like(ctx.k, -1.0))
        return out

    def tables(self):
        p = self.profile.effects[self.token]
        if "cell_dn" not in p:
            return {}
        return {"grids": torch.tensor(p["cell_dn"], dtype=torch.float64) ** 2}  # extra variance per cell, DN^2

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
        if "cell_dn" in params:
            cells = params["cell_dn"]
            arr = np.asarray(cells, dtype=np.float64) if isinstance(cells, (list, tuple)) else None
            if arr is None or arr.shape != (len(params["k"]), NB, NB) or not np.isfinite(arr).all() or (arr < 0).any():
                raise ValueError(f"effect 'ReadMap': cell_dn must hold one {NB} x {NB} grid of extra sigma (DN, finite, "
                                 f">= 0) per record of k, got {cells!r:.80}")
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
        excess, noise = excess_over_model(lines_measured[axis], np.array([ls[axis] for ls in lines_synth]), gain)
        out[excess_key], out[noise_key] = [excess.tolist()], [noise.tolist()]
        out[keep_key] = [bool(keep[axis + 1])]
    excess, noise = excess_over_model(tile_variance(*white[0]), np.array([tile_variance(*w) for w in white[1:]]), gain)
    out["tile_excess"], out["tile_noise"] = [excess], [noise]  # (h // TILE, w // TILE) DN^2: for the cells at the edges combine finds
    return out


def excess_over_model(measured, parts, gain: float) -> tuple[np.ndarray, np.ndarray]:
    """(excess, its noise), DN^2, of the white variance per line or tile ``measured`` over the
    model's, from its syntheses' ``parts`` (S, ...): the measured over the model's times the
    model's mean level (the high pass kept ``gain`` of it), less that level. A unit's relative
    noise is the model's (a mean variance over its pixels); a noisier unit's is as much larger."""
    model = parts.mean(axis=0)
    level = model.mean() / gain
    ratio = measured / np.maximum(model, 1e-12)
    spread = parts / np.maximum(model, 1e-12) - 1.0  # each synthesis's own, about the model
    noise = level * ratio * np.sqrt(spread.var(axis=0, ddof=1).mean() * (1.0 + 1.0 / len(parts)))
    return level * (ratio - 1.0), noise


TILE = MIN_RUN  # packed lines per side of a tile of the excess map


def tile_variance(var, keep):
    """(h // TILE, w // TILE) mean over each tile of TILE x TILE packed pixels (every channel)
    of the kept pixels' variance (``white_variance``)."""
    _, h, w = var.shape
    th, tw = h // TILE, w // TILE
    cut = lambda a: a[:, : th * TILE, : tw * TILE].reshape(4, th, TILE, tw, TILE)  # noqa: E731
    kept = cut(np.where(keep, var, 0.0)).sum(axis=(0, 2, 4))
    return kept / np.maximum(cut(keep.astype(np.float64)).sum(axis=(0, 2, 4)), 1.0)


def cell_levels(excess, noise, row_edges, col_edges, p_value: float = P_VALUE):
    """(NB, NB) excess variance per cell (DN^2) of the blocks between ``row_edges`` and
    ``col_edges`` (packed lines), from a tile map of the excess (``tile_excess``, its ``noise``
    per tile), or None where the cells' excess is the sum of a row level and a column level
    (the interaction's chi-square, weighed by the cells' noise, below its p_value quantile)."""
    th, tw = excess.shape
    by = np.searchsorted(np.asarray(row_edges), np.arange(th) * TILE + TILE / 2.0, side="right")
    bx = np.searchsorted(np.asarray(col_edges), np.arange(tw) * TILE + TILE / 2.0, side="right")
    nr, nc = len(row_edges) + 1, len(col_edges) + 1
    cell = (by[:, None] * nc + bx[None, :]).ravel()
    count = np.bincount(cell, minlength=nr * nc).reshape(nr, nc)
    if (count == 0).any() or nr * nc < 4 or min(nr, nc) < 2:
        return None
    mean = np.bincount(cell, excess.ravel(), minlength=nr * nc).reshape(nr, nc) / count
    var = np.bincount(cell, (noise**2).ravel(), minlength=nr * nc).reshape(nr, nc) / count**2
    weight = 1.0 / np.maximum(var, 1e-300)
    # weighted additive fit mean ~ a + r[i] + q[j], by alternating least squares
    r, q = np.zeros(nr), np.zeros(nc)
    for _ in range(50):
        r = np.sum(weight * (mean - q[None, :]), axis=1) / weight.sum(axis=1)
        q = np.sum(weight * (mean - r[:, None]), axis=0) / weight.sum(axis=0)
    chi2 = float(np.sum(weight * (mean - r[:, None] - q[None, :]) ** 2))
    if stats.chi2.sf(chi2, (nr - 1) * (nc - 1)) >= p_value:
        return None
    out = np.zeros((NB, NB))
    out[:nr, :nc] = mean - mean.min()
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
    found = []  # per axis: the edges (packed lines) and the gains whose stacks show a pattern
    for key, edge_key, excess_key, noise_key, keep_key in LINES:
        excess = [np.mean([r[excess_key][0] for r in by_k[k]], axis=0) for k in ks]
        noise = [np.sqrt(np.mean([np.square(r[noise_key][0]) for r in by_k[k]], axis=0) / len(by_k[k])) for k in ks]
        keep = [any(r[keep_key][0] for r in by_k[k]) for k in ks]
        shown = [i for i in range(len(ks)) if keep[i]]
        edges = segments([excess[i] for i in shown], [noise[i] for i in shown], min_runs=2) if shown else []
        found.append((edges, keep))
        bounds = [0, *edges, len(excess[0])]
        out[key] = []
        for i in range(len(ks)):
            levels = np.array([excess[i][lo:hi].mean() for lo, hi in zip(bounds, bounds[1:])]) if keep[i] else np.zeros(1)
            var = np.concatenate([levels - levels.min(), np.zeros(NB - len(levels))])
            out[key].append([float(v) for v in np.sqrt(var)])
        if shown:
            out[edge_key] = [e / len(excess[0]) for e in edges]
    (row_edges, row_keep), (col_edges, col_keep) = found
    if "tile_excess" in first and row_edges and col_edges:
        cells = []
        for i, k in enumerate(ks):
            tiles = np.mean([r["tile_excess"][0] for r in by_k[k]], axis=0)
            noise = np.sqrt(np.mean([np.square(r["tile_noise"][0]) for r in by_k[k]], axis=0) / len(by_k[k]))
            cells.append(cell_levels(tiles, noise, row_edges, col_edges) if row_keep[i] and col_keep[i] else None)
        if any(c is not None for c in cells):  # the cells hold the map whole where they depart from the blocks' sum
            out["cell_dn"] = []
            for i, c in enumerate(cells):
                if c is not None:
                    out["row_block_dn"][i], out["col_block_dn"][i] = [0.0] * NB, [0.0] * NB
                out["cell_dn"].append(np.sqrt(c).tolist() if c is not None else np.zeros((NB, NB)).tolist())
    out["frame_h"], out["frame_w"] = first["frame_h"], first["frame_w"]
    return out


def empty(params) -> bool:
    """True when every amplitude is 0: it would add nothing."""
    return all_zero(params, tuple(g[0] for g in GROUPS) + ("cell_dn",))
