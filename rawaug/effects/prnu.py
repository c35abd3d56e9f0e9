"""Photo-response non-uniformity (PRNU): every pixel has its own gain.

Physics: pixel-to-pixel differences of photodiode area and microlens give each pixel a
slightly different response; it multiplies the photo signal, so its fixed-pattern spread
grows in proportion to the signal (the quadratic term of a photon transfer curve).

Synthesis: ``signal * (1 + sigma * g)`` before shot noise, with a seeded standard-normal
map ``g`` (the same in every frame). ``sigma`` does not depend on ISO.

Profile entry::  ``PRNU: {seed: 17, sigma: 0.01}``  (fraction of the signal)

Detected by ``flat_fixed_rel`` on flat stacks (fixed-pattern std over the mean level).
Estimated by ``estimate``: the excess fixed-pattern variance of each flat stack over the
current model, against its squared mean level; ``combine`` fits one spread to every flat stack
(before the thirty-third session the loop took the first flat stack's alone: the dimmest, where
the gains show least). Bias frames cannot show PRNU.
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
    """PRNU from a flat stack (N >= 2, 4, h, w) in DN at clean level ``level_dn`` (DN): its
    fixed-pattern variance over the model's, over the squared level (``combine`` of this stack
    alone; what it saw is kept under ``"_seen"`` for ``combine`` over stacks)."""
    frames = np.asarray(frames, dtype=np.float64)
    if level_dn is None or frames.shape[0] < 2:
        raise ValueError("PRNU needs a flat stack of >= 2 frames and its clean level level_dn (DN)")
    level = max(float(np.mean(level_dn)), 1e-12)
    measured = _fixed_var(frames)
    base = float(np.mean([_fixed_var(np.asarray(s, dtype=np.float64)) for s in synthesized]))
    seen = {"level": level, "excess": measured - base, "var": max(measured, 1e-30), "seed": int(seed)}
    return {**combine([{"_seen": seen}]), "_seen": seen}


def combine(records: list[dict]) -> dict:
    """One gain spread for every flat stack (PRNU does not depend on the level or the ISO): the
    least-squares fit of the stacks' excess fixed-pattern variances by ``sigma^2 x level^2``,
    each weighted by its precision (a variance's standard error is proportional to it), so the
    brightest flats, where the gains show most, count most."""
    seen = [r["_seen"] for r in records]
    w = np.array([1.0 / s["var"] ** 2 for s in seen])
    x = np.array([s["level"] ** 2 for s in seen])
    y = np.array([s["excess"] for s in seen])
    var = float((w * x * y).sum() / max(float((w * x * x).sum()), 1e-300))
    return {"seed": seen[0]["seed"], "sigma": float(np.sqrt(max(var, 0.0)))}


def empty(params) -> bool:
    """True when the gains do not vary (sigma 0): it would add nothing."""
    return float(params["sigma"]) == 0.0
