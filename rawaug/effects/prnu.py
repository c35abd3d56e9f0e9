"""Photo-response non-uniformity (PRNU): every pixel has its own gain.

Physics: pixel-to-pixel differences of photodiode area and microlens give each pixel a
slightly different response; it multiplies the photo signal, so its fixed-pattern spread
grows in proportion to the signal (the quadratic term of a photon transfer curve).

Synthesis: ``signal * (1 + sigma * g)`` before shot noise, with a seeded standard-normal
map ``g`` (the same in every frame). ``sigma`` does not depend on ISO.

Profile entry::  ``PRNU: {seed: 17, sigma: 0.01}``  (fraction of the signal)

Detected by ``flat_fixed_rel`` on flat stacks (fixed-pattern std over the mean level).
Estimated by ``estimate``: the excess fixed-pattern variance of the flat stack over the
current model, divided by the squared mean level. Bias frames cannot show PRNU.
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import pixel_fixed_std
from .base import PHOTON, NoiseEffect, pattern_key, register
from .k_records import _number, check_gain_pattern

STATISTICS = ("flat_fixed_rel",)


@register
class PhotoResponseNonUniformity(NoiseEffect):
    token = "PRNU"
    order = PHOTON
    flag = L.PRNU
    columns = ("prnu_sigma",)

    def draw(self, ctx):
        return {"prnu_sigma": ctx.k.new_full((ctx.k.shape[0],), float(self.profile.effects[self.token]["sigma"]))}

    def pattern_streams(self):
        return {"prnu_pattern": pattern_key(self.profile.effects[self.token]["seed"], self.token)}

    @classmethod
    def validate_params(cls, params):
        if isinstance(params, dict):
            _number(params.get("sigma"), f"{cls.token}.sigma")  # required
        check_gain_pattern(cls.token, params, ("sigma",))


def _fixed_var(frames):
    """Pixel-to-pixel fixed-pattern variance of a stack (``pixel_fixed_std`` squared), DN^2:
    an uneven illumination of the flat does not count."""
    return pixel_fixed_std(frames) ** 2


def estimate(frames, synthesized, k: float, level_dn=None, seed: int = 17, **_) -> dict:
    """PRNU from a flat stack (N >= 2, 4, h, w) in DN at clean level ``level_dn`` (DN)."""
    frames = np.asarray(frames, dtype=np.float64)
    if level_dn is None or frames.shape[0] < 2:
        raise ValueError("PRNU needs a flat stack of >= 2 frames and its clean level level_dn (DN)")
    level = float(np.mean(level_dn))
    base = float(np.mean([_fixed_var(np.asarray(s, dtype=np.float64)) for s in synthesized]))
    return {"seed": int(seed), "sigma": float(np.sqrt(max(_fixed_var(frames) - base, 0.0)) / max(level, 1e-12))}


def empty(params) -> bool:
    """True when the gains do not vary (sigma 0): it would add nothing."""
    return float(params["sigma"]) == 0.0
