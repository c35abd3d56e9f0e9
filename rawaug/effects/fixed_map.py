"""Measured fixed map (FixedMap), a measured fallback: the fixed pattern itself, as measured.

Not a named physical effect: a fixed pattern of offsets that no physical effect of the set
explains (the mura of a clamp network, rings or streaks of a substrate, a pattern of the
readout's routing) is reproduced as it was measured: the bias or dark stacks' mean map less
the model's, on a bilinear grid fine enough to hold it. ``FixedField`` reproduces such a
pattern's statistics (a random field at its cell size); this reproduces the pattern.

Stage (DN, with ``FPN``): ``s -> s + map(y, x)``, the bilinear upsampling of the grid record
nearest the sample's K, shared by the four channels at their packed position, over the
measured frame of ``frame_h x frame_w`` packed pixels: a smaller input is a window of it at an
offset drawn per sample (as ``FPN``'s shading), an input as large or larger is the frame.

Profile entry (per-K records of one grid shape, DN)::

    FixedMap: {k: [K, ...], map_dn: [[[..gw..], ..gh..], ...], frame_h: H, frame_w: W}

Estimated from bias and dark stacks of >= 2 frames: the channel-averaged stack-mean map less
the model's syntheses' (``shading_map``), fitted on the grid of the cell size (packed pixels)
that predicts one half of each stack's frames best from the other (split-half cross
validation, relative errors summed over the stacks, each half less syntheses of its own: a cell fine enough
for the pattern, coarse enough not to fit the frames' temporal noise), at most ``MAX_NODES``
nodes; shrunk by the temporal power a mean of N frames keeps (as ``FPN``'s shading); the
stacks of one gain averaged. None where no cell predicts the other half ``MIN_GAIN`` better
than no map. A last resort (``LAST_RESORT``): the loop keeps it only where no other candidate
of its round is acceptable.
"""
from __future__ import annotations

from collections import Counter

import numpy as np
import torch

from ..engine import layout as L
from .base import DARK, NoiseEffect, register
from .dark_shading import fit_grid, shading_map, shrunk_grid, upsample_grid
from .k_records import frame_size, grid_columns, validate_records

STATISTICS = ("fixed_std", "fixed_pixel_var", "psd2d_lowfreq", "row_lowfreq", "col_lowfreq", "row_tone", "col_tone", "diag_tone")
MEASURED = True
LAST_RESORT = True  # chosen only where no other candidate is acceptable: FixedField's few numbers, if they do, before a map's thousands
MAX_NODES = 4096  # grid nodes per record (a 64 x 64 grid): the profile stays small
CELLS = (2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)  # cell sizes tried (packed pixels)
MIN_GAIN = 0.02  # a map predicts the other half's map this much better than none, relative (a coarse grid fits noise by ~nodes / pixels)


@register
class FixedMap(NoiseEffect):
    token = "FixedMap"
    order = DARK + 1  # an offset of the pixel, beside FPN's
    flag = L.FIXED_MAP
    columns = ("fmap_record", "fmap_oy", "fmap_ox", "fmap_h", "fmap_w", "fmap_gh", "fmap_gw")

    def draw(self, ctx):
        return grid_columns(ctx, self.token, self.profile.effects[self.token], "fmap")

    def tables(self):
        return {"grids": torch.tensor(self.profile.effects[self.token]["map_dn"], dtype=torch.float64)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("map_dn",))
        if frame_size(cls.token, params) is None:
            raise ValueError(f"effect {cls.token!r} needs frame_h and frame_w (packed pixels of the frame its map was measured on)")
        shape = None
        for i, grid in enumerate(params["map_dn"]):
            arr = np.asarray(grid, dtype=np.float64) if isinstance(grid, (list, tuple)) else None
            if arr is None or arr.ndim != 2 or min(arr.shape) < 1 or arr.size > MAX_NODES or not np.isfinite(arr).all():
                raise ValueError(f"effect {cls.token!r}: map_dn[{i}] must be a finite 2-D grid of at most {MAX_NODES} nodes, "
                                 f"got {grid!r:.80}")
            if shape is not None and arr.shape != shape:
                raise ValueError(f"effect {cls.token!r}: every map_dn grid must have the same shape, got {shape} and {arr.shape}")
            shape = arr.shape


def grid_shape(h: int, w: int, cell: int) -> tuple[int, int]:
    return max(1, -(-h // cell)), max(1, -(-w // cell))


def cells(h: int, w: int) -> list[int]:
    """The cell sizes of ``CELLS`` whose grid on an h x w frame has at most ``MAX_NODES`` nodes
    and at least 2 along each axis."""
    return [c for c in CELLS if np.prod(grid_shape(h, w, c)) <= MAX_NODES and min(grid_shape(h, w, c)) >= 2]


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """One stack's record for ``combine`` (``_seen``: its residual map, its halves' and its
    frames' temporal maps); the cell is chosen over every stack there, once."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.ndim != 4 or frames.shape[0] < 2:
        raise ValueError("FixedMap is measured on bias or dark stacks of >= 2 frames (N, 4, h, w)")
    maps = [shading_map(np.asarray(s, dtype=np.float64)) for s in synthesized]
    model = np.mean(maps, axis=0) if maps else 0.0
    # each half less a model map of syntheses of its own: under no pattern the halves' residuals
    # are independent (one model map less from both would carry its noise into each)
    split = len(maps) // 2
    model_a, model_b = (np.mean(maps[:split], axis=0), np.mean(maps[split:], axis=0)) if split else (model, model)
    half = frames.shape[0] // 2
    seen = {"k": float(k), "frame": frames.shape[2:], "map": shading_map(frames) - model,
            "a": shading_map(frames[:half]) - model_a, "b": shading_map(frames[half:2 * half]) - model_b,
            "temporal": _temporal_maps(frames)}
    return {"_seen": seen}


def _temporal_maps(frames) -> np.ndarray:
    """(N, h, w) each frame's map less the stack mean's: the temporal part a grid fit shrinks by."""
    mean = frames.mean(axis=0)
    return np.stack([shading_map((f - mean)[None]) for f in frames]).astype(np.float32)


def _cv_error(seen: dict, cell: int) -> float:
    """Split-half error of a grid of ``cell``: each half's fit predicting the other half."""
    shape = grid_shape(*seen["map"].shape, cell)
    h, w = seen["map"].shape
    err = 0.0
    for x, y in ((seen["a"], seen["b"]), (seen["b"], seen["a"])):
        err += float(np.mean((upsample_grid(fit_grid(x, shape), h, w) - y) ** 2))
    return err / 2.0


def combine(records: list[dict]) -> dict:
    """One grid shape for the sensor: the cell of least split-half error, relative to each
    stack's without a map, summed over the stacks of the frame size most stacks have (none
    where no cell beats no map by ``MIN_GAIN``); per gain, the stacks' shrunk grids averaged."""
    seen = [r["_seen"] for r in records]
    frame = Counter(tuple(s["frame"]) for s in seen).most_common(1)[0][0]
    same = [s for s in seen if tuple(s["frame"]) == frame]
    h, w = frame
    # each stack's error relative to its own without a map: a noisy high-gain stack does not outvote the others
    nothing = [max(float((np.mean(s["a"] ** 2) + np.mean(s["b"] ** 2)) / 2.0), 1e-30) for s in same]
    none = float(len(same))
    errors = {c: sum(_cv_error(s, c) / z for s, z in zip(same, nothing)) for c in cells(h, w)}
    ks = sorted({s["k"] for s in same})
    if not errors or min(errors.values()) > (1.0 - MIN_GAIN) * none:
        shape = (1, 1)
        grids = [np.zeros(shape) for _ in ks]
    else:
        shape = grid_shape(h, w, min(errors, key=errors.get))
        grids = [np.mean([shrunk_grid(s["map"], s["temporal"], shape) for s in same if s["k"] == k], axis=0) for k in ks]
    return {"k": ks, "map_dn": [np.round(g, 4).tolist() for g in grids], "frame_h": int(h), "frame_w": int(w)}


def empty(params) -> bool:
    """True when every map is 0: it would add nothing."""
    return all(not np.any(np.asarray(g)) for g in params["map_dn"])
