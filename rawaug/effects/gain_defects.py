"""Gain defect pixels (PixelGain): sparse pixels whose response to light is far off.

Physics: a pixel with a damaged or partly masked photodiode, a misaligned microlens or a
particle on its colour filter collects a share of the light its neighbours do; a few collect
more. EMVA 1288 counts them among the defects of its PRNU image: dim or bright outliers of a
flat in proportion to its signal, and nothing in bias frames (``Hot`` is an offset, the same
in the dark; ``PRNU`` the Gaussian spread of every pixel's gain; ``LineGain`` whole lines;
``GainGrid`` a periodic grid such as phase-detection pixels).

Stage (DN, after shot noise, with the photo signal's other gains): ``s -> s max(1 + d, 0)``;
a pixel is a gain defect where a seeded U(0, 1) falls below ``density``, with
``d = +-median exp(log_std z)`` (a seeded standard normal ``z``), negative with probability
``negative``; 0 elsewhere. The same in every frame and at every gain; a sensor instance's own.

Profile entry (``density`` a fraction of pixels, ``median`` a fraction of the signal)::

    PixelGain: {seed: 41, density: 0.003, median: 0.5, log_std: 0.0, negative: 1.0}

Detected in flat stacks by ``tail_mass`` (dim and bright outliers of a frame) and
``hot_fraction`` (bright ones of the stack mean). Estimated by ``estimate`` from a flat stack:
the pixels of its relative fixed pattern (``flat_relative_map``: the stack mean over the
light's local shape) beyond ``DEFECT_Z`` robust sigmas, in excess of the model's syntheses',
and their deviations; ``combine`` keeps the flat stack that resolved the most (a dim defect
is lost in a dim flat's noise).
"""
from __future__ import annotations

import math

import numpy as np

from ..engine import layout as L
from ..statistics import flat_relative_map, robust_scale
from .base import SHOT, NoiseEffect, pattern_key, register
from .defect_lines import validate_spread
from .k_records import _number, check_density, check_seed

STATISTICS = ("tail_mass", "hot_fraction")
DEFECT_Z = 8.0  # robust sigmas of the relative fixed pattern: a gain defect, not the noise or the PRNU
MAX_DENSITY = 0.05
MAX_MEDIAN = 0.95  # a gain at most 95 % off (a pixel that reads no light at all is ``Dead``'s)


@register
class PixelGain(NoiseEffect):
    token = "PixelGain"
    order = SHOT + 2  # with the photo signal's other gains, before the frame's and the columns' and rows'
    flag = L.PIXEL_GAIN
    columns = ("pgain_density", "pgain_median", "pgain_log_std", "pgain_negative")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        full = lambda key: ctx.k.new_full((ctx.k.shape[0],), float(p[key]))  # noqa: E731
        return {"pgain_density": full("density"), "pgain_median": full("median"), "pgain_log_std": full("log_std"),
                "pgain_negative": full("negative")}

    def pattern_streams(self):
        return {"pgain": pattern_key(self.profile.effects[self.token]["seed"], self.token, "pixel")}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r:.80}")
        check_seed(cls.token, params)
        check_density(cls.token, params, most=MAX_DENSITY)
        median = _number(params.get("median"), f"{cls.token}.median")
        if not 0.0 <= median <= MAX_MEDIAN:
            raise ValueError(f"effect {cls.token!r}: median (fraction of the signal) must be in [0, {MAX_MEDIAN}], got {median}")
        validate_spread(cls.token, params, "pixels")


def defect_pixels(frames) -> np.ndarray:
    """Relative deviations (fractions of the signal) of the gain defect pixels of a flat stack
    (N, 4, h, w; DN): the pixels of ``flat_relative_map`` beyond ``DEFECT_Z`` robust sigmas of
    their channel's."""
    rel = flat_relative_map(frames).reshape(4, -1)
    med, scale = robust_scale(rel, axis=1)
    return rel[np.abs(rel - med) > DEFECT_Z * scale]


def estimate(frames, synthesized, k: float, kind=None, seed: int = 41, **_) -> dict:
    """PixelGain from a flat stack (N, 4, h, w; DN) against the model's ``synthesized`` stacks
    of it: its gain defect pixels (``defect_pixels``) beyond the model's, and their deviations."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "flat":
        raise ValueError(f"PixelGain is measured on flat stacks, got a {kind!r} stack")
    if not float(frames.mean()) > 0:
        raise ValueError(f"PixelGain needs a flat stack above black, got a mean of {float(frames.mean()):.4g} DN")
    found = defect_pixels(frames)
    base = np.mean([defect_pixels(s).size for s in synthesized]) if synthesized else 0.0
    density = min(max((found.size - base) / (frames[0].size), 0.0), MAX_DENSITY)
    amp = np.abs(found[found != 0])
    if density == 0.0 or amp.size == 0:
        return {"seed": int(seed), "density": 0.0, "median": 0.0, "log_std": 0.0, "negative": 0.0}
    logs = np.log(np.minimum(amp, MAX_MEDIAN))
    return {"seed": int(seed), "density": float(density), "median": min(float(math.exp(logs.mean())), MAX_MEDIAN),
            "log_std": float(logs.std(ddof=1)) if amp.size > 1 else 0.0, "negative": float(np.mean(found < 0))}


def combine(records: list[dict]) -> dict:
    """One set of defects (the sensor's, the same at every gain and level): the flat stack's
    record that resolved the most."""
    return max(records, key=lambda r: r["density"])


def empty(params) -> bool:
    """True when no pixel is drawn or none is off: it would change nothing."""
    return params["density"] == 0.0 or params["median"] == 0.0
