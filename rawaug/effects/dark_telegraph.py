"""Dark-current telegraph pixels (DarkRTS): a few pixels whose dark-current rate switches
between two levels, from frame to frame.

Physics: a generation centre in a photodiode's depletion region (a metastable defect) turns
on and off at random; while it is on, the pixel's dark current is a fixed step higher
(dark-current random telegraph signal, DC-RTS). The step is electrons per second: it grows
with the exposure and carries its shot noise, so bias frames do not show it and long darks
show two states. ``RTS`` is the same two states in the read chain (a fixed step in DN at
every exposure); ``DarkHot`` a dark-current rate that stays high.

Stage (DN, before shot noise): ``s -> s + K * t * median_e_per_s * exp(log_std * z)`` at the
pixels where a seeded U(0, 1) pattern falls below ``density`` (``z`` a seeded standard normal
of the pixel), in a frame where that frame's U(0, 1) for the pixel falls below ``high`` (the
share of frames in the high state); ``t`` is the synthesis setting ``fixed={"exposure_s": t}``
(default 0: none). A state lasts a frame: a centre switching within the exposure gives
levels between the two, which this stage does not draw.

Profile entry (electrons do not depend on the gain: one population)::

    DarkRTS: {seed: 97, density: 0.005, high: 0.5, median_e_per_s: 25.0, log_std: 0.3}

Detected on dark stacks by ``flicker_fraction`` (pixels with two states), ``spike_fraction``
(a pixel high in one frame of the stack) and ``hot_fraction`` (high in most frames: its mean
sits high). Estimated by ``estimate`` on each dark stack: ``RTS``'s telegraph population
beyond the model's, its steps with their shot noise, in electrons per second
(``combine``: one population over the dark stacks).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..engine import layout as L
from .base import PHOTON, NoiseEffect, pattern_key, register
from .dark_hot_pixels import validate_population
from .k_records import _number
from .telegraph import population

STATISTICS = ("flicker_fraction", "spike_fraction", "hot_fraction")


@register
class DarkTelegraph(NoiseEffect):
    token = "DarkRTS"
    order = PHOTON + 6  # with the dark current, before shot noise
    flag = L.DARK_RTS
    columns = ("drts_density", "drts_e", "drts_log_std", "drts_high")
    exposure = True

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        exposure = torch.as_tensor(ctx.fixed.get("exposure_s", 0.0), dtype=torch.float64, device=ctx.device).expand(ctx.batch)
        n = ctx.k.shape[0]
        return {"drts_density": ctx.k.new_full((n,), float(p["density"])), "drts_e": float(p["median_e_per_s"]) * exposure,
                "drts_log_std": ctx.k.new_full((n,), float(p["log_std"])), "drts_high": ctx.k.new_full((n,), float(p["high"]))}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"drts_where": pattern_key(seed, self.token, "where"), "drts_size": pattern_key(seed, self.token, "size")}

    @classmethod
    def validate_params(cls, params):
        validate_population(cls.token, params, "pixels")
        high = _number(params.get("high"), "DarkRTS.high")
        if not 0.0 < high < 1.0:
            raise ValueError(f"effect 'DarkRTS': high (share of frames in the high state) must be in (0, 1), got {high}")


def estimate(frames, synthesized, k: float, exposure_s=None, kind=None, seed: int = 97, **_) -> dict:
    """DarkRTS population from a dark stack (N >= 3, 4, h, w) in DN of ``exposure_s`` seconds
    at gain ``k`` (DN per electron): the telegraph pixels beyond the model's (its
    ``synthesized`` stacks of this stack), steps with their shot noise (``population``), over
    ``k x exposure_s``."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "dark" or not exposure_s or frames.shape[0] < 3:
        raise ValueError("DarkRTS is measured on dark stacks of >= 3 frames with their exposure_s")
    found = population(frames, synthesized, seed, shot_k=float(k))
    if found is None:
        return {"seed": int(seed), "density": 0.0, "high": 0.5, "median_e_per_s": 0.0, "log_std": 0.0}
    density, high, mu, sd, _ = found
    return {"seed": int(seed), "density": density, "high": high,
            "median_e_per_s": float(math.exp(mu) / (float(k) * float(exposure_s))), "log_std": sd}


def combine(records: list[dict]) -> dict:
    """One population from the dark stacks (every ISO and exposure: the same pixels in
    electrons): the medians over the stacks that found any (a stack whose noise hides most of
    the steps finds few, and guesses), the rate's in log."""
    found = [r for r in records if r["density"] > 0]
    if not found:
        return dict(records[0])
    return {"seed": found[0]["seed"], "density": float(np.median([r["density"] for r in found])),
            "high": float(np.median([r["high"] for r in found])),
            "median_e_per_s": float(math.exp(np.median([math.log(r["median_e_per_s"]) for r in found]))),
            "log_std": float(np.median([r["log_std"] for r in found]))}


def empty(params) -> bool:
    """True when no pixel is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
