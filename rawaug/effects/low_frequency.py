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

Profile entry (per-K records)::  ``LowFreq: {grid: [gh, gw], k: [K, ...], sigma_dn: [...]}``

Estimated by ``estimate``: the excess variance over the current model of the frames'
block means on the grid's cells (channel-averaged, per-frame mean removed), divided by what
a unit field gives on the same blocks.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from .base import ADC, NoiseEffect, register
from .k_records import validate_records, value_at_k

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
        p = self.profile.effects[self.token]
        gh, gw = (float(v) for v in p["grid"])
        return {"lowfreq_sigma": value_at_k(p, "sigma_dn", ctx.k), "lowfreq_gh": torch.full_like(ctx.k, gh),
                "lowfreq_gw": torch.full_like(ctx.k, gw)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",), nonnegative=("sigma_dn",))
        grid = params.get("grid")
        if not (isinstance(grid, (list, tuple)) and len(grid) == 2 and all(isinstance(v, int) and 1 <= v <= 256 for v in grid)):
            raise ValueError(f"effect 'LowFreq' needs grid: [gh, gw], integers in [1, 256], got {grid!r}")


def grid_shape(h: int, w: int) -> tuple[int, int]:
    return max(2, min(256, h // CELL)), max(2, min(256, w // CELL))


def block_variance(frames, gh: int, gw: int) -> float:
    """Variance of the channel-averaged, per-frame-centered block means on a gh x gw grid, DN^2."""
    f = np.asarray(frames, dtype=np.float64)
    f = (f - f.mean(axis=(2, 3), keepdims=True)).mean(axis=1)  # (N, h, w)
    n, h, w = f.shape
    bh, bw = h // gh, w // gw
    blocks = f[:, : bh * gh, : bw * gw].reshape(n, gh, bh, gw, bw).mean(axis=(2, 4))
    return float(blocks.var(axis=(1, 2), ddof=1).mean())


def _unit_block_variance(h: int, w: int, gh: int, gw: int) -> float:
    """``block_variance`` of the unit field (sigma 1) itself, by simulation: the stage's
    bilinear upsampling of standard-normal grids (the same in every channel, so one is
    enough); about 4096 blocks in all, at most 256 frames, so large frames cost little."""
    from .dark_shading import upsample_grid

    n = int(min(256, max(4, 4096 // (gh * gw))))
    z = np.random.default_rng(0).standard_normal((n, gh, gw))
    return block_variance(upsample_grid(z, h, w)[:, None], gh, gw)


def estimate(frames, synthesized, k: float, **_) -> dict:
    """LowFreq record at gain ``k`` from measured frames (N, 4, h, w) in DN."""
    frames = np.asarray(frames, dtype=np.float64)
    h, w = frames.shape[2:]
    gh, gw = grid_shape(h, w)
    excess = block_variance(frames, gh, gw) - float(np.mean([block_variance(s, gh, gw) for s in synthesized]))
    sigma = float(np.sqrt(max(excess, 0.0) / _unit_block_variance(h, w, gh, gw)))
    return {"grid": [gh, gw], "k": [float(k)], "sigma_dn": [sigma]}


def combine(records: list[dict]) -> dict:
    """One record per gain (several stacks at one K: their sigmas averaged); the grid of the
    first stack (a camera's frames share one size)."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(r["k"][0], []).append(r["sigma_dn"][0])
    ks = sorted(by_k)
    return {"grid": list(records[0]["grid"]), "k": ks, "sigma_dn": [float(np.mean(by_k[k])) for k in ks]}
