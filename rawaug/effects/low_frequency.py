"""Measured low-frequency noise (LowFreq), a measured fallback: what the frames' low
spatial frequencies hold beyond every physical effect, reproduced as a random smooth field.

Not a named physical effect: interference picked up by the readout, illumination flicker
of a supposedly dark setup and other unexplained smooth patterns that change from frame to
frame all show up as excess power at low spatial frequencies (``psd2d_lowfreq``,
``row_lowfreq``, ``col_lowfreq``) that ``FPN`` (a fixed shading) does not remove. The loop
tries this component only when no physical effect explains such a residual, and the report
lists it as reproduced by measurement.

Stage (DN, after quantization): ``s -> s + sigma_dn * Z(y, x)``, Z the bilinear upsampling
of a ``gh x gw`` grid of standard normals drawn anew for every frame (shared by the four
channels; counter ``(b * gh + i) * gw + j`` of its stream).

Profile entry (per-K records)::  ``LowFreq: {grid: [gh, gw], k: [K, ...], sigma_dn: [...], frame_h: H, frame_w: W}``
(the grid spans the measured frame of ``frame_h x frame_w`` packed pixels; an input of
another size gets the grid that keeps the measured cell size, ``round(gh * h / H)`` cells
down, so a training crop sees the field at its measured scale).

Estimated by ``estimate``: the excess low-frequency power over the current model, ring by
ring of the 2-D spectrum (channel-averaged frames, per-frame mean removed), fitted by the
spectrum of a unit field; the grid (cells of 16 pixels up to two cells across the frame)
is the one whose spectrum fits the excess best, so the field's correlation length is
measured, not assumed.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from ..statistics import repaired
from .base import ADC, NoiseEffect, register
from .k_records import combine_mean, frame_size, validate_records, value_at_k

STATISTICS = ("psd2d_lowfreq", "row_lowfreq", "col_lowfreq")
MEASURED = True
CELL = 16  # pixels per grid cell (per packed channel): the statistics' low band


@register
class LowFrequencyNoise(NoiseEffect):
    token = "LowFreq"
    order = ADC + 5
    flag = L.LOW_FREQ
    columns = ("lowfreq_sigma", "lowfreq_gh", "lowfreq_gw")

    def draw(self, ctx):
        return grid_field_columns(ctx, self.token, self.profile.effects[self.token], "lowfreq", 256)

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",), nonnegative=("sigma_dn",))
        grid = params.get("grid")
        if not (isinstance(grid, (list, tuple)) and len(grid) == 2 and all(isinstance(v, int) and 1 <= v <= 256 for v in grid)):
            raise ValueError(f"effect 'LowFreq' needs grid: [gh, gw], integers in [1, 256], got {grid!r}")
        frame_size(cls.token, params)


def grid_field_columns(ctx, token: str, p: dict, prefix: str, max_grid: int) -> dict:
    """Columns ``{prefix}_sigma``, ``{prefix}_gh``, ``{prefix}_gw`` of a bilinear normal grid
    field: its sigma at each sample's K and its grid, rescaled on an input of another size than
    the measured frame so that a cell keeps its measured size (at most ``max_grid`` nodes)."""
    grid = [float(v) for v in p["grid"]]
    frame = frame_size(token, p)
    if frame is not None and ctx.shape is not None:  # the measured cell size, on an input of any size
        grid = [float(min(max_grid, max(1, round(g * n / f)))) for g, n, f in zip(grid, ctx.shape, frame)]
    return {f"{prefix}_sigma": value_at_k(p, "sigma_dn", ctx.k), f"{prefix}_gh": torch.full_like(ctx.k, grid[0]),
            f"{prefix}_gw": torch.full_like(ctx.k, grid[1])}


def grid_shape(h: int, w: int, cell: int = CELL) -> tuple[int, int]:
    return max(2, min(256, h // cell)), max(2, min(256, w // cell))


def candidate_grids(h: int, w: int) -> list[tuple[int, int]]:
    """Grid shapes from cells of CELL pixels up to two cells across the frame: the field's
    correlation length is chosen among them by its spectrum (``estimate``)."""
    grids, cell = [], CELL
    while True:
        g = grid_shape(h, w, cell)
        if g not in grids:
            grids.append(g)
        if g == (2, 2) or cell > max(h, w):
            return grids
        cell *= 2


def _centered_fields(frames) -> np.ndarray:
    """(N, h, w) channel-averaged frames, each with its own mean removed and its defect
    lines repaired (as ``psd2d_lowfreq`` sees them), DN."""
    f = repaired(frames)
    return (f - f.mean(axis=(2, 3), keepdims=True)).mean(axis=1)


def _rings(h: int, w: int):
    """Ring index of every rfft2 bin in cycles per frame (1, 2, ... up to the statistics' low
    band, 1/16 of Nyquist along the shorter side); -1 outside."""
    fy = np.fft.fftfreq(h)[:, None] * h
    fx = np.fft.rfftfreq(w)[None, :] * w
    radius = np.sqrt(fy**2 + fx**2)
    top = max(2, min(h, w) // 32)
    ring = np.floor(radius).astype(int)
    return np.where((radius >= 1) & (ring <= top), ring, -1), top


def ring_power(frames) -> np.ndarray:
    """Mean 2-D power (DN^2 per bin) of the centered, channel-averaged fields in each
    low-frequency ring (``_rings``)."""
    f = _centered_fields(frames)
    p = np.abs(np.fft.rfft2(f, axes=(1, 2))) ** 2 / (f.shape[1] * f.shape[2])
    ring, top = _rings(*f.shape[1:])
    p = p.mean(axis=0)
    return np.array([p[ring == r].mean() if (ring == r).any() else 0.0 for r in range(1, top + 1)])


def _unit_field(h: int, w: int, gh: int, gw: int) -> np.ndarray:
    """Simulated frames of the unit field (sigma 1) itself: the stage's bilinear upsampling
    of standard-normal grids (the same in every channel, so one is enough); about 4096
    grid values in all, at most 256 frames and about 2^24 pixels (4 frames at least), so a
    12 MP frame needs about 100 MB, not gigabytes."""
    from .dark_shading import upsample_grid

    n = int(max(4, min(256, 4096 // (gh * gw), 2**24 // (h * w))))
    z = np.random.default_rng(0).standard_normal((n, gh, gw))
    return upsample_grid(z, h, w)[:, None]


def estimate(frames, synthesized, k: float, **_) -> dict:
    """LowFreq record at gain ``k`` from measured frames (N, 4, h, w) in DN.

    The excess low-frequency power over the current model, ring by ring, is fitted by a
    unit field of each candidate grid times sigma^2 (least squares, sigma^2 >= 0); the grid
    that leaves the smallest misfit is kept. So a field that varies over the whole frame
    gets a coarse grid and a finer pattern a fine one."""
    frames = np.asarray(frames, dtype=np.float64)
    h, w = frames.shape[2:]
    excess = ring_power(frames) - np.mean([ring_power(s) for s in synthesized], axis=0)
    best = None
    for gh, gw in candidate_grids(h, w):
        unit = ring_power(_unit_field(h, w, gh, gw))
        var = max(float(excess @ unit / max(unit @ unit, 1e-30)), 0.0)
        misfit = float(np.sum((excess - var * unit) ** 2))
        if best is None or misfit < best[0]:
            best = (misfit, gh, gw, var)
    _, gh, gw, var = best
    return {"grid": [gh, gw], "k": [float(k)], "sigma_dn": [float(np.sqrt(var))], "frame_h": int(h), "frame_w": int(w)}


def combine(records: list[dict]) -> dict:
    """One record per gain (several stacks at one K: their sigmas averaged); the grid of the
    first stack (a camera's frames share one size)."""
    out = {"grid": list(records[0]["grid"]), **combine_mean(records, "sigma_dn")}
    out.update({key: records[0][key] for key in ("frame_h", "frame_w") if key in records[0]})
    return out
