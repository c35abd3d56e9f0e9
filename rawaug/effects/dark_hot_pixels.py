"""Hot pixels of dark current (DarkHot): a sparse set of pixels with a dark-current rate far
above the rest, growing with exposure, with its shot noise.

Physics: a crystal defect or a metal impurity in a photodiode raises its leakage current by
orders of magnitude (EMVA 1288 shows them as the long tail of the DSNU histogram). Such a
pixel collects ``rate * t`` electrons in the dark: invisible in bias frames, bright in long
exposures, and Poisson like every other electron. ``Hot`` is a fixed offset in DN, the same at
every exposure; ``Dark`` is the log-normal spread of the other pixels' rates.

Stage (DN, before shot noise): ``s -> s + K * t * median_e_per_s * exp(log_std * z)`` at the
pixels where a seeded U(0, 1) pattern falls below ``density``, ``z`` a seeded standard normal
(both keyed by the pixel position); ``t`` is the synthesis setting ``fixed={"exposure_s": t}``
(default 0: none).

Profile entry (electrons do not depend on the gain: one population)::

    DarkHot: {seed: 59, density: 0.003, median_e_per_s: 40.0, log_std: 0.5}

Detected on dark stacks by ``hot_fraction`` and ``tail_mass`` (with ``Hot``, which the loop
tries beside it: the bias frames tell them apart). Estimated by ``estimate``: the isolated
pixels of a dark stack's mean 8 robust sigma above the median of their 5 x 5 neighbourhood
(``isolated_hot``: a glow's smooth corner is no hot pixel) in excess of the model's, their
excess in electrons per second, on the frames as measured (the repair of defect lines would
move a column that one bright hot pixel lifts). Hot pixels dimmer than that threshold are not
seen: density and median are those of the detectable population.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from scipy import ndimage

from ..engine import layout as L
from .base import PHOTON, NoiseEffect, pattern_key, register
from .hot_pixels import THRESHOLD_SIGMA
from .k_records import _number, check_density, check_seed

STATISTICS = ("hot_fraction", "tail_mass")
RAW_FRAMES = True  # estimated from the frames as measured: a column holding a bright hot pixel can read as a defect line, whose repair moves hot pixels


@register
class DarkHotPixels(NoiseEffect):
    token = "DarkHot"
    order = PHOTON + 6  # with the dark current, before shot noise
    flag = L.DARK_HOT
    columns = ("dhot_density", "dhot_e", "dhot_log_std")
    exposure = True

    def draw(self, ctx):
        return draw_population(ctx, self.profile.effects[self.token], "dhot")

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"dhot_where": pattern_key(seed, self.token, "where"), "dhot_size": pattern_key(seed, self.token, "size")}

    @classmethod
    def validate_params(cls, params):
        validate_population(cls.token, params, "pixels")


def draw_population(ctx, p: dict, prefix: str) -> dict:
    """Per-sample columns of a dark-current population ``p``: ``{prefix}_density``, ``{prefix}_e``
    (the median electrons at this call's ``exposure_s``) and ``{prefix}_log_std``."""
    exposure = torch.as_tensor(ctx.fixed.get("exposure_s", 0.0), dtype=torch.float64, device=ctx.device).expand(ctx.batch)
    n = ctx.k.shape[0]
    return {f"{prefix}_density": ctx.k.new_full((n,), float(p["density"])), f"{prefix}_e": float(p["median_e_per_s"]) * exposure,
            f"{prefix}_log_std": ctx.k.new_full((n,), float(p["log_std"]))}


def validate_population(token: str, params, of: str) -> None:
    """Check a dark-current population entry (seed, density of ``of``, median e-/s, log
    spread): ValueError naming the bad value."""
    if not isinstance(params, dict):
        raise ValueError(f"effect {token!r} parameters must be a mapping, got {params!r}")
    check_seed(token, params)
    check_density(token, params, of=of)
    for key in ("median_e_per_s", "log_std"):
        if _number(params.get(key), f"{token}.{key}") < 0:
            raise ValueError(f"effect {token!r}: {key} must be >= 0, got {params.get(key)}")


def isolated_hot(frames):
    """(4, h, w) mask of a stack's (N, 4, h, w; DN) isolated hot pixels and their excess (DN):
    pixels of the stack mean more than THRESHOLD_SIGMA robust sigma above the median of their
    5 x 5 neighbourhood (same channel), none of whose 8 neighbours is so. Hot pixels are point
    defects: a smooth field (a glow's corner, its shot noise) is neither above its local median
    nor made of isolated pixels."""
    excess, high = local_excess(frames)
    ring = np.ones((1, 3, 3))
    ring[0, 1, 1] = 0.0
    hot = high & (ndimage.convolve(high.astype(np.float64), ring, mode="constant") == 0)
    return hot, excess[hot]


def local_excess(frames) -> tuple[np.ndarray, np.ndarray]:
    """((4, h, w) excess in DN, its mask of hot pixels) of a stack (N, 4, h, w; DN): each pixel
    of the stack mean less the median of its 5 x 5 neighbourhood (same channel) and less its
    channel's median of that; hot where that stands THRESHOLD_SIGMA robust sigma (the
    channel's) above."""
    m = np.asarray(frames, dtype=np.float64).mean(axis=0)
    r = m - ndimage.median_filter(m, size=(1, 5, 5), mode="mirror")
    flat = r.reshape(4, -1)
    med = np.median(flat, axis=1)[:, None, None]
    mad = 1.482602218505602 * np.median(np.abs(flat - med[:, :, 0]), axis=1)[:, None, None]
    high = (r - med) > THRESHOLD_SIGMA * np.where(mad > 0, mad, r.std(axis=(1, 2), keepdims=True) + 1e-12)
    return r - med, high


def estimate(frames, synthesized, k: float, exposure_s=None, kind=None, seed: int = 59, **_) -> dict:
    """DarkHot population from a dark stack (N, 4, h, w) in DN of ``exposure_s`` seconds at
    gain ``k`` (DN per electron), against stacks of the same shape synthesized by the model."""
    if kind != "dark" or not exposure_s:
        raise ValueError("DarkHot is measured on dark stacks with their exposure_s")
    frames = np.asarray(frames, dtype=np.float64)
    hot, amp = isolated_hot(frames)
    base = float(np.mean([isolated_hot(s)[0].mean() for s in synthesized])) if synthesized else 0.0
    density = max(float(hot.mean()) - base, 0.0)
    rate = amp[amp > 0] / (float(k) * float(exposure_s))  # electrons per second above the neighbourhood
    if density == 0.0 or rate.size == 0:
        return {"seed": int(seed), "density": 0.0, "median_e_per_s": 0.0, "log_std": 0.0}
    logs = np.log(rate)
    return {"seed": int(seed), "density": min(density, 0.1), "median_e_per_s": float(math.exp(logs.mean())),
            "log_std": float(logs.std(ddof=1)) if rate.size > 1 else 0.0}


def combine(records: list[dict]) -> dict:
    """One population from the dark stacks (every ISO and exposure: the same pixels in
    electrons): density averaged, the median's log averaged, the log spreads averaged in
    variance; stacks that found none count for the density only."""
    found = [r for r in records if r["density"] > 0]
    if not found:
        return dict(records[0])
    return {"seed": records[0]["seed"], "density": float(np.mean([r["density"] for r in records])),
            "median_e_per_s": float(math.exp(np.mean([math.log(r["median_e_per_s"]) for r in found]))),
            "log_std": float(math.sqrt(np.mean([r["log_std"] ** 2 for r in found])))}


def empty(params) -> bool:
    """True when no pixel is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
