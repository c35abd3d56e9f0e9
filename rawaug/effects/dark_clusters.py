"""Clusters of hot pixels (DarkCluster): small square patches of neighbouring sensor pixels that
share one high dark-current rate, growing with exposure, with its shot noise.

Physics: displacement damage (a neutron or proton knocking a silicon atom out of the lattice
in flight or in storage) leaves a cascade of defects that raises the leakage of several
neighbouring photodiodes at once; a metal contamination spot does the same. Each patch is
one defect: its pixels collect ``rate * t`` electrons in the dark, Poisson. ``DarkHot`` is the
same physics at single pixels (one pixel of a packed channel, none of its neighbours hot); a
patch of 2 x 2 sensor pixels or more lights neighbours in every channel, which ``DarkHot``'s
isolated-pixel estimate leaves out.

Stage (DN, before shot noise): a sensor pixel ``(Y, X)`` collects ``K * t * median_e_per_s *
exp(log_std * z)`` for every seed ``(Y - dy, X - dx)``, ``0 <= dy, dx < size``, where a seeded
U(0, 1) of the sensor position falls below ``density`` (``z``: a seeded standard normal of the
seed's position, so a patch has one rate); ``t`` is the synthesis setting
``fixed={"exposure_s": t}`` (default 0: none).

Profile entry (electrons do not depend on the gain: one population)::

    DarkCluster: {seed: 61, density: 1.0e-4, size: 3, median_e_per_s: 40.0, log_std: 0.3}

(``density``: patches per sensor pixel; ``size``: the side of a patch, sensor pixels, 1 to
``rawaug.engine.layout.CLUSTER_MAX``.)

Detected on dark stacks by ``hot_fraction`` and ``tail_mass``. Estimated by ``estimate``: the
pixels of a dark stack's mean 8 robust sigma (``hot_pixels.THRESHOLD_SIGMA``) above the median of their 5 x 5
neighbourhood (same channel), put back at their sensor positions and joined into 8-connected
patches; the patches of two pixels or more in excess of the model's (Poisson, p ``P_VALUE``) are the clusters, the
side the square root of their median area, the rate each patch's mean excess over (K t).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage, stats

from ..engine import layout as L
from .base import PHOTON, NoiseEffect, pattern_key, register
from . import dark_hot_pixels
from .dark_hot_pixels import draw_population, validate_population

STATISTICS = ("hot_fraction", "tail_mass")
RAW_FRAMES = True  # as DarkHot: a column holding a bright patch can read as a defect line, whose repair would move it
EIGHT = np.ones((3, 3), dtype=bool)  # 8-connected neighbours on the sensor
P_VALUE = 1e-3  # patches count where as many or more have this chance under the model's count (Poisson)
MIN_BASE = 0.1  # the model's patches per stack taken as at least this (a few syntheses may see none)


@register
class DarkClusters(NoiseEffect):
    token = "DarkCluster"
    order = PHOTON + 6  # with the dark current, before shot noise
    flag = L.DARK_CLUSTER
    columns = ("dclus_density", "dclus_e", "dclus_log_std", "dclus_size")
    exposure = True

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return draw_population(ctx, p, "dclus") | {"dclus_size": ctx.k.new_full((ctx.k.shape[0],), float(p["size"]))}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"dclus_where": pattern_key(seed, self.token, "where"), "dclus_size": pattern_key(seed, self.token, "size")}

    @classmethod
    def validate_params(cls, params):
        validate_population(cls.token, params, "sensor pixels")
        size = params.get("size")
        if isinstance(size, bool) or not isinstance(size, int) or not 1 <= size <= L.CLUSTER_MAX:
            raise ValueError(f"effect {cls.token!r}: size (the side of a patch, sensor pixels) must be a whole number in "
                             f"[1, {L.CLUSTER_MAX}], got {size!r}")


def sensor_excess(frames) -> tuple[np.ndarray, np.ndarray]:
    """(excess map (2h, 2w) in DN, its mask of hot pixels) of a stack (N, 4, h, w; DN) at the
    sensor positions: ``dark_hot_pixels.local_excess`` of each channel put back in the mosaic."""
    r, high = dark_hot_pixels.local_excess(frames)
    _, h, w = r.shape
    excess, hot = np.zeros((2 * h, 2 * w)), np.zeros((2 * h, 2 * w), dtype=bool)
    for c, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 1), (1, 0))):  # R, G1, B, G2 at their sensor positions
        excess[dy::2, dx::2] = r[c]
        hot[dy::2, dx::2] = high[c]
    return excess, hot


def patches(frames) -> tuple[np.ndarray, np.ndarray]:
    """(areas, mean excess in DN) of the 8-connected patches of two hot sensor pixels or more
    (``sensor_excess``) of a stack."""
    excess, hot = sensor_excess(frames)
    labels, n = ndimage.label(hot, structure=EIGHT)
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    index = np.arange(1, n + 1)
    area = ndimage.sum_labels(np.ones_like(excess), labels, index).astype(np.int64)
    mean = ndimage.mean(excess, labels, index)
    keep = area >= 2
    return area[keep], np.asarray(mean)[keep]


def estimate(frames, synthesized, k: float, exposure_s=None, kind=None, seed: int = 61, **_) -> dict:
    """DarkCluster population from a dark stack (N, 4, h, w) in DN of ``exposure_s`` seconds at
    gain ``k`` (DN per electron), against stacks of the same shape synthesized by the model."""
    if kind != "dark" or not exposure_s:
        raise ValueError("DarkCluster is measured on dark stacks with their exposure_s")
    frames = np.asarray(frames, dtype=np.float64)
    area, excess = patches(frames)
    base = float(np.mean([patches(s)[0].size for s in synthesized])) if synthesized else 0.0
    sensor_pixels = 4 * frames.shape[2] * frames.shape[3]
    count = max(area.size - base, 0.0)
    rate = excess[excess > 0] / (float(k) * float(exposure_s))
    if count == 0.0 or rate.size == 0 or stats.poisson.sf(area.size - 1, max(base, MIN_BASE)) > P_VALUE:
        return {"seed": int(seed), "density": 0.0, "size": 1, "median_e_per_s": 0.0, "log_std": 0.0}
    logs = np.log(rate)
    size = int(np.clip(round(math.sqrt(float(np.median(area)))), 1, L.CLUSTER_MAX))
    return {"seed": int(seed), "density": min(count / sensor_pixels, 0.01), "size": size,
            "median_e_per_s": float(math.exp(logs.mean())), "log_std": float(logs.std(ddof=1)) if rate.size > 1 else 0.0}


def combine(records: list[dict]) -> dict:
    """One population from the dark stacks (every ISO and exposure: the same patches in
    electrons): density, median and log spread as ``DarkHot``'s (``dark_hot_pixels.combine``),
    the side the median of the stacks that found any."""
    found = [r for r in records if r["density"] > 0]
    if not found:
        return dict(records[0])
    return dark_hot_pixels.combine(records) | {"size": int(round(float(np.median([r["size"] for r in found]))))}


def empty(params) -> bool:
    """True when no patch is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
