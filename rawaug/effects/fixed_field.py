"""Measured fixed field (FixedField), a measured fallback: a fixed pattern with spatial
correlation, reproduced as a smooth random field of the sensor at its measured scale.

Not a named physical effect: a blotchy fixed pattern (mura of the readout, a non-uniform
implant or oxide, a pattern of the substrate) is neither the white pixel-to-pixel spread nor
the frame-wide shading of ``FPN``, nor a line pattern: its power lies at the spatial
frequencies of its blotches. It shows in the fixed pattern's variance (``fixed_pixel_var``,
``fixed_std``, ``pixel_std``), in the low-frequency statistics and in the tone statistics
(the periodograms of its low-pass row and column means peak above their median bin). The loop tries this component only when
no physical effect explains such a residual, and the report lists it as reproduced by
measurement.

Stage (DN, with ``LowFreq``): ``s -> s + sigma_dn * Z(y, x)``, Z the bilinear upsampling of a
``gh x gw`` grid of standard normals of the sample's sensor (counter ``(sensor * gh + i) * gw + j``:
the same in every frame), shared by the four channels at their packed position.

Profile entry (per-K records)::  ``FixedField: {seed: 53, grid: [gh, gw], k: [K, ...], sigma_dn: [...], frame_h: H, frame_w: W}``
(an input of another size gets the grid that keeps the measured cell size, as ``LowFreq``).

Estimated by ``estimate`` from a bias or dark stack: the 2-D power spectrum of its mean map
(each channel's mean taken out, the channels averaged) in log-spaced rings from one cycle
per frame to Nyquist, less the model's syntheses', fitted by the spectrum of a unit field of
each cell size (1, 2, 4, ... packed pixels up to half the frame), each ring weighed by its
precision (bins over power squared); the cell that fits the excess best is kept, so the
pattern's correlation length is measured, not assumed.
"""
from __future__ import annotations

from collections import Counter

import numpy as np

from ..engine import layout as L
from .base import ADC, NoiseEffect, pattern_key, register
from .dark_shading import upsample_grid
from .k_records import check_seed, frame_size, validate_records
from .low_frequency import grid_field_columns

STATISTICS = ("fixed_pixel_var", "fixed_std", "pixel_std", "psd2d_lowfreq", "row_lowfreq", "col_lowfreq", "row_tone", "col_tone",
              "diag_tone")  # a blotchy pattern's row and column means are low-pass: their periodograms peak
MEASURED = True
MAX_GRID = 1 << 15  # grid nodes per axis
RINGS = 16  # log-spaced rings of the 2-D spectrum


@register
class FixedField(NoiseEffect):
    token = "FixedField"
    order = ADC + 6
    flag = L.FIXED_FIELD
    columns = ("ffield_sigma", "ffield_gh", "ffield_gw")

    def draw(self, ctx):
        return grid_field_columns(ctx, self.token, self.profile.effects[self.token], "ffield", MAX_GRID)

    def pattern_streams(self):
        return {"ffield": pattern_key(self.profile.effects[self.token]["seed"], self.token, "field")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",), nonnegative=("sigma_dn",))
        check_seed(cls.token, params)
        grid = params.get("grid")
        if not (isinstance(grid, (list, tuple)) and len(grid) == 2 and all(isinstance(v, int) and 1 <= v <= MAX_GRID for v in grid)):
            raise ValueError(f"effect {cls.token!r} needs grid: [gh, gw], integers in [1, {MAX_GRID}], got {grid!r}")
        frame_size(cls.token, params)


def _field(frames) -> np.ndarray:
    """(h, w) fixed pattern of a stack (N, 4, h, w; DN): its mean map, each channel's mean
    taken out, the channels averaged."""
    m = np.asarray(frames, dtype=np.float64).mean(axis=0)
    return (m - m.mean(axis=(1, 2), keepdims=True)).mean(axis=0)


def _ring_index(h: int, w: int) -> np.ndarray:
    """Ring of every rfft2 bin: RINGS log-spaced rings of radius (cycles per frame along the
    shorter side) from 1 to Nyquist; -1 for the DC bin."""
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    radius = np.sqrt(fy**2 + fx**2) * min(h, w)  # cycles per frame
    edges = np.geomspace(1.0, 0.5 * np.sqrt(2.0) * min(h, w) + 1e-9, RINGS + 1)
    ring = np.searchsorted(edges, radius, side="right") - 1
    return np.where(radius >= 1.0, np.minimum(ring, RINGS - 1), -1)


def ring_power(fields, counts: bool = False):
    """(RINGS,) mean 2-D power (DN^2 per bin) of (..., h, w) fields, each row's and column's
    mean taken out (the frames' row and column noise, whose few bins would swamp a ring), in
    each ring, averaged over the leading axes; with ``counts``, also the bins each ring
    averages (per field)."""
    f = np.asarray(fields, dtype=np.float64).reshape(-1, *np.shape(fields)[-2:])
    h, w = f.shape[-2:]
    f = f - f.mean(axis=2, keepdims=True)  # row and column means out: row and column noise are not this
    f = f - f.mean(axis=1, keepdims=True)
    p = (np.abs(np.fft.rfft2(f, axes=(1, 2))) ** 2 / (h * w)).mean(axis=0)
    ring = _ring_index(h, w)
    n = np.bincount(ring[ring >= 0], minlength=RINGS)
    power = np.bincount(ring[ring >= 0], weights=p[ring >= 0], minlength=RINGS) / np.maximum(n, 1)
    return (power, n) if counts else power


def candidate_cells(h: int, w: int) -> list[int]:
    """Cell sizes (packed pixels): 1, 2, 4, ... up to half the shorter side."""
    cells, c = [], 1
    while c <= max(1, min(h, w) // 2):
        cells.append(c)
        c *= 2
    return cells


def _unit_power(h: int, w: int, cell: int) -> np.ndarray:
    """Ring power of the unit field (sigma 1) of ``cell`` packed pixels on an h x w frame."""
    gh, gw = max(1, round(h / cell)), max(1, round(w / cell))
    n = int(max(2, min(16, 2**22 // (h * w))))
    z = np.random.default_rng(0).standard_normal((n, gh, gw))
    return ring_power(upsample_grid(z, h, w))


def estimate(frames, synthesized, k: float, kind=None, seed: int = 53, **_) -> dict:
    """FixedField record at gain ``k`` from a bias or dark stack (N >= 2, 4, h, w; DN) against
    the model's ``synthesized`` stacks of it: sigma and grid of the unit field whose ring
    power, scaled, fits the stack's fixed pattern's excess over the syntheses' best."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 2:
        raise ValueError("FixedField is measured on bias or dark stacks of >= 2 frames")
    h, w = frames.shape[2:]
    measured, bins = ring_power(_field(frames), counts=True)
    excess = measured - (np.mean([ring_power(_field(s)) for s in synthesized], axis=0) if synthesized else 0.0)
    # each ring's mean power holds ``bins`` exponential powers: its sd is the power over sqrt(bins)
    weight = bins / np.maximum(measured, 1e-30) ** 2
    best = None
    for cell in candidate_cells(h, w):
        unit = _unit_power(h, w, cell)
        var = max(float(np.sum(weight * excess * unit) / max(np.sum(weight * unit * unit), 1e-30)), 0.0)
        misfit = float(np.sum(weight * (excess - var * unit) ** 2))
        if best is None or misfit < best[0]:
            best = (misfit, cell, var)
    _, cell, var = best
    grid = [max(1, round(h / cell)), max(1, round(w / cell))]
    return {"seed": int(seed), "grid": grid, "k": [float(k)], "sigma_dn": [float(np.sqrt(var))], "frame_h": int(h), "frame_w": int(w)}


def combine(records: list[dict]) -> dict:
    """One record per gain on the grid most stacks chose (their sigmas averaged; a gain none of
    whose stacks chose it keeps its own stacks' mean)."""
    grid = Counter(tuple(r["grid"]) for r in records).most_common(1)[0][0]
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append((tuple(r["grid"]) == grid, float(r["sigma_dn"][0])))
    ks = sorted(by_k)
    sigmas = []
    for kk in ks:
        on = [s for same, s in by_k[kk] if same] or [s for _, s in by_k[kk]]
        sigmas.append(float(np.mean(on)))
    out = {"seed": int(records[0].get("seed", 53)), "grid": list(grid), "k": ks, "sigma_dn": sigmas}
    out.update({key: records[0][key] for key in ("frame_h", "frame_w") if key in records[0]})
    return out


def empty(params) -> bool:
    """True when every sigma is 0: it would add nothing."""
    return all(float(v) == 0.0 for v in params["sigma_dn"])
