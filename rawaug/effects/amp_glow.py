"""Amplifier glow (Glow): a smooth dark-current map that grows with exposure, brightest near
the readout amplifiers, as long dark frames of many CMOS sensors show.

Physics: the output amplifiers and other readout circuits emit infrared light and heat
while the sensor integrates, so the pixels near them collect extra dark electrons, at a
rate that falls off smoothly with distance. Those electrons are Poisson like any others
and their number grows linearly with the exposure; bias frames show none of it. It is the
low-frequency part of the dark signal non-uniformity (EMVA 1288 sees it in the spectrogram
of the dark image); ``Dark`` holds the uniform rate and the white pixel-to-pixel part.

Stage (DN, before shot noise): ``s -> s + K * exposure_s * g(y, x)``, ``g`` the bilinear
upsampling of a low-resolution grid (e- per second, the excess over the far field)
measured over a frame of ``frame_h x frame_w`` packed pixels and shared by the four packed
channels. A smaller input is a window of that frame at a random position per sample (as
``FPN``'s shading). The exposure is the synthesis setting ``fixed={"exposure_s": t}``.

Profile entry (per-K records, nearest record in log K)::

    Glow: {k: [K, ...], rate_e_per_s: [[[..gw..], ..gh..], ...], frame_h: H, frame_w: W}

Detected on dark stacks by the low-frequency statistics (``psd2d_lowfreq``,
``row_lowfreq``, ``col_lowfreq``) growing with exposure while the bias stacks of the same
ISO show none. Estimated by ``estimate``: the smooth fixed grid of the measured stack mean
less that of the model's syntheses (which hold ``FPN``'s shading and the temporal part),
plus the mean excess, less the far field (the grid's minimum) where that is positive: a
uniform dark signal the model lacks is ``Dark``'s; where the model's uniform dark signal
already holds the glow's mean, the grid keeps its zero mean. Over ``K * exposure_s``;
``combine`` fits one grid per gain through the origin over every exposure. The grid's cells
(4 to 32 pixels) are the ones that predict each stack's odd frames from its even ones and
back best, summed over the stacks (``split_half_errors``): a glow that falls off within a
tenth of the frame and a dark signal that varies over a few pixels need fine cells, a
faint one coarse cells that average the noise.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from .base import PHOTON, NoiseEffect, register
from .dark_shading import fit_grid, fixed_shading_grids, shading_map, upsample_grid
from .k_records import frame_size, grid_columns, validate_records

STATISTICS = ("psd2d_lowfreq", "row_lowfreq", "col_lowfreq")
MAX_GRID = 64  # cells per axis at most (the profile's limit)
CELLS = (4, 6, 8, 12, 16, 24, 32)  # packed pixels per cell the grid is tried at; the data choose (``split_half_errors``)


def glow_grid_shapes(h: int, w: int) -> list[tuple[int, int]]:
    """The (gh, gw) glow grids tried over a packed frame of h x w, finest first: cells of each
    size of CELLS, at most MAX_GRID per axis."""
    return sorted({(max(1, min(MAX_GRID, h // c)), max(1, min(MAX_GRID, w // c))) for c in CELLS}, reverse=True)


SINGLE_GRID = 16  # cells per axis at most where one frame cannot choose (cells of 4 pixels or more)


def glow_grid_shape(h: int, w: int) -> tuple[int, int]:
    """The glow grid over a packed frame of h x w where a single frame gives no split-half
    error: cells of 4 pixels or more, at most SINGLE_GRID per axis."""
    return max(1, min(SINGLE_GRID, h // CELLS[0])), max(1, min(SINGLE_GRID, w // CELLS[0]))


def _mean_map(frames) -> np.ndarray:
    """(h, w) channel-averaged stack mean, each channel's mean taken out, DN."""
    m = frames.mean(axis=0)
    return (m - m.mean(axis=(1, 2), keepdims=True)).mean(axis=0)


def split_half_errors(frames, shapes) -> list[float]:
    """Per grid of ``shapes``: the mean squared error (DN^2 per pixel) with which the grid
    fitted to the even frames' mean map predicts the odd frames', and back: the finer grid
    follows the glow closer and the noise more, and the grid that predicts frames it was not
    fitted to best is the one the data support. Each half's maps are made once."""
    h, w = frames.shape[2:]
    halves = (frames[0::2], frames[1::2])
    fits, tests = [shading_map(f) for f in halves], [_mean_map(f) for f in halves]
    return [sum(float(np.mean((upsample_grid(fit_grid(fit, shape), h, w) - test) ** 2))
                for fit, test in zip(fits, tests[::-1])) / 2.0 for shape in shapes]


@register
class AmpGlow(NoiseEffect):
    token = "Glow"
    order = PHOTON + 6  # dark electrons, after Dark, before the shot noise that counts them
    flag = L.GLOW
    columns = ("glow_s", "glow_record", "glow_oy", "glow_ox", "glow_h", "glow_w", "glow_gh", "glow_gw")
    exposure = True

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        exposure = torch.as_tensor(ctx.fixed.get("exposure_s", 0.0), dtype=torch.float64, device=ctx.device).expand(ctx.batch)
        return {"glow_s": exposure, **grid_columns(ctx, self.token, p, "glow")}

    def tables(self):
        return {"grids": torch.tensor(self.profile.effects[self.token]["rate_e_per_s"], dtype=torch.float64)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("rate_e_per_s",))
        frame_size(cls.token, params)
        shape = None
        for i, grid in enumerate(params["rate_e_per_s"]):
            arr = np.asarray(grid, dtype=np.float64) if isinstance(grid, (list, tuple)) else None
            if arr is None or arr.ndim != 2 or min(arr.shape) < 1 or max(arr.shape) > 64 or not np.isfinite(arr).all():
                raise ValueError(f"effect 'Glow': rate_e_per_s[{i}] must be a finite 2-D grid (e-/s, at most 64x64), "
                                 f"got {grid!r:.80}")
            if shape is not None and arr.shape != shape:
                raise ValueError(f"effect 'Glow': every rate_e_per_s grid must have the same shape, got {shape} and {arr.shape}")
            shape = arr.shape


def estimate(frames, synthesized, k: float, exposure_s=None, kind: str = "dark", **_) -> dict:
    """Glow record at gain ``k`` from a dark stack (N, 4, h, w) in DN of ``exposure_s``
    seconds and stacks of the same shape synthesized by the current model (a flat's shading
    is the light's)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "dark" or not exposure_s:
        raise ValueError("Glow needs a dark stack and its exposure_s")
    base = [np.asarray(s, dtype=np.float64) for s in synthesized]
    shapes = glow_grid_shapes(*frames.shape[2:]) if frames.shape[0] >= 2 else [glow_grid_shape(*frames.shape[2:])]
    measured = fixed_shading_grids(frames, shapes)  # each stack's maps made once for every grid
    model = [np.mean(g, axis=0) for g in zip(*(fixed_shading_grids(s, shapes) for s in base))]
    offset = float(frames.mean() - np.mean([s.mean() for s in base]))
    errors = dict(zip(shapes, split_half_errors(frames, shapes) if len(shapes) > 1 else [0.0]))
    grids = {}
    for shape, meas, mod in zip(shapes, measured, model):
        excess_dn = meas - mod + offset  # the smooth grids' difference has zero mean
        # the glow is what rises above the far field: a uniform dark signal the model lacks is
        # Dark's (left out), one the model has in excess is the glow's mean it already counts
        excess_dn = excess_dn - max(float(excess_dn.min()), 0.0)
        grids[shape] = (excess_dn / (k * float(exposure_s))).tolist()
    best = min(shapes, key=lambda sh: errors[sh])
    return {"k": [float(k)], "rate_e_per_s": [grids[best]], "grids": grids, "split_half_error": errors,
            "exposure_s": [float(exposure_s)], "frame_h": int(frames.shape[2]), "frame_w": int(frames.shape[3])}


def combine(records: list[dict]) -> dict:
    """One grid per gain from the dark stacks of every exposure: the least-squares rate
    through the origin (each exposure's grid weighted by its exposure squared), at the grid
    whose split-half error summed over the stacks is least (``split_half_errors``)."""
    shared = [r for r in records if "split_half_error" in r and (r["frame_h"], r["frame_w"]) == (records[0]["frame_h"], records[0]["frame_w"])]
    if len(shared) == len(records):
        shapes = list(shared[0]["split_half_error"])
        best = min(shapes, key=lambda sh: sum(r["split_half_error"][sh] for r in shared))
        records = [{**r, "rate_e_per_s": [r["grids"][best]]} for r in records]
    by_k: dict = {}
    for r in records:
        by_k.setdefault(r["k"][0], []).append(r)
    ks = sorted(by_k)
    grids = []
    for k in ks:
        t = np.array([r["exposure_s"][0] for r in by_k[k]])
        rates = np.array([r["rate_e_per_s"][0] for r in by_k[k]])  # (n, gh, gw)
        grids.append((np.tensordot(t**2, rates, axes=1) / np.sum(t**2)).tolist())
    return {"k": ks, "rate_e_per_s": grids, "frame_h": records[0]["frame_h"], "frame_w": records[0]["frame_w"]}
