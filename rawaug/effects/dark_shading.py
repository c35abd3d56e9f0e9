"""Dark shading and fixed-pattern noise (FPN): a per-pixel offset map, the same in every
frame, whose size depends on ISO.

Physics: pixel-to-pixel differences of dark current and source-follower offsets give
every pixel its own offset (a white fixed pattern); amplifier glow and readout-path
gradients add a smooth shading across the frame. Both grow with the analog gain.

Storage choice (compact YAML): a per-pixel map of a full sensor would take megabytes, so
the profile holds

* ``seed`` and ``sigma_dn``: the white part is a seeded standard-normal realization scaled
  by the measured per-pixel std. Its statistics (what a denoiser learns from) are the
  sensor's; its exact pixel values are not -- they cannot be from a profile of this size;
* ``shading_dn``: a low-resolution grid (at most 8x8) of the measured smooth shading over
  the measured frame of ``frame_h x frame_w`` packed pixels, shared by the four packed
  channels (their mean differences are the colour bias ``C``). A smaller input is a
  window of that frame at a random position (per sample), so the shading keeps its
  measured scale on training crops; an input as large or larger (or a profile without
  ``frame_h``/``frame_w``) gets the grid stretched over it: the input is the sensor.

Both are per-K records (nearest record in log K)::

    FPN: {seed: 11, k: [K, ...], sigma_dn: [..], shading_dn: [[[..gw..], ..gh..], ...],
          frame_h: H, frame_w: W}

Detected by ``fixed_std`` (stack-mean spread), ``fixed_pixel_var`` (its white part), ``psd2d_lowfreq``, ``row_lowfreq`` and
``col_lowfreq`` (smooth shading), see ``rawaug.statistics``. Estimated by
``estimate``: grid = least-squares fit of the upsampled grid to the stack-mean map, shrunk by
the temporal smooth power a mean of N frames keeps (``fixed_shading_grid``); sigma = the excess spread of the
map over the current model's (``fixed_pixel_var``: unbiased, hot pixels and impulses left out, shading and
row or column patterns cancelled). A single frame cannot separate a white
fixed pattern from temporal noise: then only the shading is estimated (``sigma_dn`` 0).
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from ..engine import layout as L
from ..statistics import fixed_pixel_var, repaired
from .base import DARK, NoiseEffect, pattern_key, register
from .k_records import check_seed, frame_size, grid_columns, validate_records, value_at_k

STATISTICS = ("fixed_std", "fixed_pixel_var", "psd2d_lowfreq", "row_lowfreq", "col_lowfreq")
MAX_GRID = 8
AMPLITUDES = ("sigma_dn", "shading_dn")  # corrected by simulation under a clip (rawaug.loop.clip_correction)
SHARES_READ_NOISE_UNDER_CLIP = True  # the censored read-noise fit took the pattern's spread (rawaug.loop.frames_loop)


def _grids(params) -> torch.Tensor:
    return torch.tensor(params["shading_dn"], dtype=torch.float32)  # (R, gh, gw)


def upsample_grid(grid, h: int, w: int):
    """Bilinear upsampling of (..., gh, gw) grids to (..., h, w) (numpy or torch)."""
    t = torch.as_tensor(np.asarray(grid) if not isinstance(grid, torch.Tensor) else grid, dtype=torch.float32)
    lead = t.shape[:-2]
    up = F.interpolate(t.reshape(-1, 1, *t.shape[-2:]), size=(h, w), mode="bilinear", align_corners=False)
    up = up.reshape(*lead, h, w)
    return up if isinstance(grid, torch.Tensor) else up.numpy().astype(np.float64)


@register
class DarkShading(NoiseEffect):
    token = "FPN"
    order = DARK
    flag = L.FPN
    columns = ("fpn_sigma", "fpn_record", "fpn_oy", "fpn_ox", "fpn_h", "fpn_w", "fpn_gh", "fpn_gw")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {"fpn_sigma": value_at_k(p, "sigma_dn", ctx.k), **grid_columns(ctx, self.token, p, "fpn")}

    def pattern_streams(self):
        return {"fpn_pattern": pattern_key(self.profile.effects[self.token]["seed"], self.token)}

    def tables(self):
        return {"grids": torch.tensor(self.profile.effects[self.token]["shading_dn"], dtype=torch.float64)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn", "shading_dn"), nonnegative=("sigma_dn",))
        check_seed(cls.token, params)
        frame_size(cls.token, params)
        shape = None
        for i, grid in enumerate(params["shading_dn"]):
            arr = np.asarray(grid, dtype=np.float64) if isinstance(grid, (list, tuple)) else None
            if arr is None or arr.ndim != 2 or min(arr.shape) < 1 or max(arr.shape) > 64 or not np.isfinite(arr).all():
                raise ValueError(f"effect 'FPN': shading_dn[{i}] must be a finite 2-D grid (at most 64x64), got {grid!r:.80}")
            if shape is not None and arr.shape != shape:
                raise ValueError(f"effect 'FPN': every shading_dn grid must have the same shape, got {shape} and {arr.shape}")
            shape = arr.shape


def _grid_shape(h, w):
    return max(1, min(MAX_GRID, h // 8)), max(1, min(MAX_GRID, w // 8))


def _upsampling_matrix(n_out, n_grid):
    """(n_out, n_grid) matrix of 1-D bilinear upsampling (``upsample_grid`` along one axis)."""
    eye = torch.eye(n_grid, dtype=torch.float32)[:, None, :]  # (n_grid, 1, n_grid)
    up = F.interpolate(eye, size=n_out, mode="linear", align_corners=False)[:, 0, :]
    return up.T.numpy().astype(np.float64)


def shading_map(frames) -> np.ndarray:
    """(h, w) channel-averaged, zero-mean stack-mean map of the repaired frames, DN: what a
    shading grid is fitted to."""
    m = repaired(frames).mean(axis=0)  # a stuck column is a defect, not shading
    return (m - m.mean(axis=(1, 2), keepdims=True)).mean(axis=0)


def fit_grid(m, shape: tuple) -> np.ndarray:
    """(gh, gw) grid whose bilinear upsampling best fits (least squares) the (h, w) map ``m``."""
    uy, ux = _upsampling_matrix(m.shape[0], shape[0]), _upsampling_matrix(m.shape[1], shape[1])
    return np.linalg.pinv(uy) @ m @ np.linalg.pinv(ux).T


def shading_grid(frames, shape: tuple | None = None) -> np.ndarray:
    """(gh, gw) grid (``shape``, default ``_grid_shape``) whose bilinear upsampling best fits
    (least squares) the channel-averaged, zero-mean stack-mean map, DN."""
    m = shading_map(frames)
    return fit_grid(m, shape or _grid_shape(*m.shape))


def fixed_shading_grids(frames, shapes) -> list[np.ndarray]:
    """``fixed_shading_grid`` at each of ``shapes`` (None: the default), the stack's maps
    repaired and averaged once for them all."""
    m = shading_map(frames)
    shapes = [shape or _grid_shape(*m.shape) for shape in shapes]
    n = frames.shape[0]
    if n < 2:
        return [fit_grid(m, shape) for shape in shapes]
    mean = frames.mean(axis=0)
    deviations = [shading_map((f - mean)[None]) for f in frames]
    return [shrunk_grid(m, deviations, shape) for shape in shapes]


def shrunk_grid(m, deviations, shape: tuple) -> np.ndarray:
    """``fit_grid`` of a stack's mean map ``m`` shrunk by the temporal power a mean of N frames
    keeps, N the frames' maps about the mean ``deviations`` (each frame's grid power, x N/(N-1))."""
    n = len(deviations)
    grid = fit_grid(m, shape)
    temporal = np.mean([np.sum(fit_grid(np.asarray(d, dtype=np.float64), shape) ** 2) for d in deviations]) * n / (n - 1)
    power = float(np.sum(grid**2))
    return grid * (max(0.0, 1.0 - temporal / n / power) if power > 0 else 0.0)


def fixed_shading_grid(frames, shape: tuple | None = None) -> np.ndarray:
    """``shading_grid`` of the stack mean less what temporal noise leaves in it, DN.

    A mean of N frames keeps 1/N of the power of any per-frame smooth field (interference,
    a drifting glow) and of the white noise under the grid's cells. That power is measured
    from each frame's grid about the mean and the grid is shrunk by it, so a smooth field
    new in every frame is not taken for fixed shading (as ``Col`` subtracts temporal / N).
    """
    return fixed_shading_grids(frames, [shape])[0]


def estimate(frames, synthesized, k: float, seed: int = 11, kind: str = "bias", **_) -> dict:
    """Dark-shading record at gain ``k`` from measured frames (N, 4, h, w) in DN and
    stacks of the same shape synthesized by the current model: bias and dark stacks only (a
    dark offset pattern; in a flat, the light's shot noise dwarfs it -- a pair's mean map
    made a white pattern of 4-6 DN out of it -- and the light's own shading is not dark)."""
    if kind == "flat":
        raise ValueError("FPN is measured on bias and dark stacks")
    frames = np.asarray(frames, dtype=np.float64)
    sigma = 0.0
    if frames.shape[0] >= 2:
        base = [np.asarray(s, dtype=np.float64) for s in synthesized]
        excess = fixed_pixel_var(frames) - float(np.mean([fixed_pixel_var(s) for s in base]))
        sigma = float(np.sqrt(max(excess, 0.0)))
    return {"seed": int(seed), "k": [float(k)], "sigma_dn": [sigma], "shading_dn": [fixed_shading_grid(frames).tolist()],
            "frame_h": int(frames.shape[2]), "frame_w": int(frames.shape[3])}
