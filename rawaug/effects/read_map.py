"""Read-noise non-uniformity (ReadMap): read noise that differs by channel and by region.

Physics: a channel read through an amplifier of its own (one colour of a 2x2 tile), or a
readout split into halves or column groups, each with its own amplifier and ADC, has read
noise of its own level there. The ELD read noise has one level for the whole frame;
calibration measures the frame's average.

Synthesis: extra white read noise ``sqrt(c[ch]^2 + r[by]^2 + q[bx]^2) * z``, ``z`` standard
normal per pixel and frame, where ``by`` / ``bx`` are the row / column block
(``READ_MAP_BLOCKS`` equal runs of the measured frame) of the pixel; an input smaller than
the measured frame is a window of it at an offset drawn per sample (as ``FPN`` shading).

Profile entry (per-K records; extra sigma in DN, frame size in packed pixels)::

    ReadMap: {k: [K, ...], channel_dn: [[4 values], ...], row_block_dn: [[8 values], ...],
              col_block_dn: [[8 values], ...], frame_h: H, frame_w: W}

Detected by ``read_noise_spread`` (the channel, row-block and column-block main effects of the
log white temporal variance per cell: per-frame smooth fields and flickering pixels left
out). Estimated by ``estimate`` from bias stacks: per cell, the measured over the model's
white temporal variance, times the model's, less it; the channel, row-block and column-block main effects of that excess, each
group shifted to start at 0 and kept only where an F-test puts its pattern beyond the
model's at p < 1e-3. Judged with the read noise re-fitted (calibration counted the extra
noise in the frame's average).
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import highpass_gain, map_effects, temporal_variance_cells
from .base import READ, NoiseEffect, register
from .k_records import all_zero, frame_size, record_index, validate_records, window_columns

STATISTICS = ("read_noise_spread",)
SHARES_READ_NOISE = True  # calibration counted its variance in the frame's read noise
P_VALUE = 1e-3  # a group's pattern counts where the model makes one as large less often
NB = L.READ_MAP_BLOCKS
GROUPS = (("channel_dn", "rmap_c", 4), ("row_block_dn", "rmap_y", NB), ("col_block_dn", "rmap_x", NB))


@register
class ReadMap(NoiseEffect):
    token = "ReadMap"
    order = READ
    flag = L.READ_MAP
    columns = tuple(f"{prefix}{i}" for _, prefix, n in GROUPS for i in range(n)) + ("rmap_oy", "rmap_ox", "rmap_h", "rmap_w")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        idx = record_index(p, ctx.k)
        out = {}
        for key, prefix, n in GROUPS:
            table = ctx.k.new_tensor(np.asarray(p[key], dtype=np.float64).reshape(len(p["k"]), n))
            for i in range(n):
                out[f"{prefix}{i}"] = table[idx, i]
        out.update(window_columns(ctx, self.token, p, ("rmap_oy", "rmap_ox", "rmap_h", "rmap_w")))
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


def estimate(frames, synthesized, k: float, level_dn=None, kind: str = "bias", **_) -> dict:
    """ReadMap record at gain ``k`` from a bias stack (N >= 2, 4, h, w) in DN, against
    syntheses of it (at least 3). Dark stacks are left out: a dark current of uneven rate
    (glow) makes temporal noise uneven too."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "bias" or level_dn is not None or frames.shape[0] < 2 or len(synthesized) < 3:
        raise ValueError("ReadMap is measured on bias stacks of >= 2 frames, against >= 3 syntheses")
    measured = temporal_variance_cells(frames)
    synth = np.array([temporal_variance_cells(s) for s in synthesized])
    model = synth.mean(axis=0)
    # per cell, the white variance the model lacks (the high pass kept highpass_gain of it), DN^2
    excess = model.mean() * (measured / np.maximum(model, 1e-12) - 1.0) / highpass_gain(*frames.shape[2:])
    out = {"k": [float(k)], "frame_h": int(frames.shape[2]), "frame_w": int(frames.shape[3])}
    for part, keep, (key, _, _) in zip(map_effects(excess), _significant(measured, synth), GROUPS):
        var = part - part.min() if keep else np.zeros_like(part)
        out[key] = [[float(v) for v in np.sqrt(var)]]
    return out


def combine(records: list[dict]) -> dict:
    """One record per gain: the stacks at one K averaged in variance."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    ks = sorted(by_k)
    out: dict = {"k": ks}
    for key, _, _ in GROUPS:
        out[key] = [[float(v) for v in np.sqrt(np.mean([np.square(r[key][0]) for r in by_k[k]], axis=0))] for k in ks]
    first = records[0]
    out["frame_h"], out["frame_w"] = first["frame_h"], first["frame_w"]
    return out


def empty(params) -> bool:
    """True when every amplitude is 0: it would add nothing."""
    return all_zero(params, tuple(g[0] for g in GROUPS))
