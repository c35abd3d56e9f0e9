"""Dead pixels (Dead): a few pixels read a fixed level whatever the light and the noise.

Physics: a broken photodiode, transfer gate or source follower leaves a pixel's output
stuck: at the black clip (code 0), at white (stuck high), or at some level of its own. The
level is a code, the same at every gain, and it does not move from frame to frame. ``Hot``
pixels add an offset to a pixel that still has noise and responds to light; a dead pixel has
neither.

Synthesis: positions are the pixels where a seeded U(0, 1) pattern falls below ``density``;
each reads one of ``levels_dn`` (DN, black-subtracted; equally likely, chosen by a second
seeded U(0, 1)) in place of everything before it (after the code map, before the clips).

Profile entry::

    Dead: {seed: 47, density: 0.002, levels_dn: [-40.0, ...]}   # 1 to 8 levels

Detected by ``stuck_fraction`` (pixels with the same value in every frame of a stack, more
than 5 robust sigma from their channel's median, but for those at a clip that moving pixels
reach too; a pixel stuck within the noise is chance where codes are coarse) and ``hot_fraction`` (a pixel stuck high
sits high in the stack mean). Estimated by ``estimate``: the stuck pixels of a stack over
the model's; their levels as 8 octile medians. Every kind of stack shows them (a flat best:
a pixel stuck at the black clip, or at black itself, is left out of a bias stack).
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import stuck_pixels
from .base import OFFSET, NoiseEffect, pattern_key, register
from .k_records import _number, check_density, check_seed

STATISTICS = ("stuck_fraction", "hot_fraction")
RAW_FRAMES = True  # estimated from the frames as measured (every other estimator reads them without dead pixels)


def _levels(params) -> list[float]:
    levels = params.get("levels_dn")
    if not isinstance(levels, (list, tuple)) or not 1 <= len(levels) <= L.DEAD_LEVELS:
        raise ValueError(f"effect 'Dead': levels_dn must be a list of 1 to {L.DEAD_LEVELS} levels (DN), got {levels!r}")
    return [_number(x, "Dead.levels_dn") for x in levels]


@register
class DeadPixels(NoiseEffect):
    token = "Dead"
    order = OFFSET + 5  # after the offsets and the code map, before the clips
    flag = L.DEAD
    columns = ("dead_density", *(f"dead_l{i}" for i in range(L.DEAD_LEVELS)))

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        n = ctx.k.shape[0]
        levels = _levels(p)
        out = {"dead_density": ctx.k.new_full((n,), float(p["density"]))}
        for i in range(L.DEAD_LEVELS):  # 1 to 8 levels spread over the 8 equally likely slots
            out[f"dead_l{i}"] = ctx.k.new_full((n,), levels[i * len(levels) // L.DEAD_LEVELS])
        return out

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"dead_where": pattern_key(seed, self.token, "where"), "dead_level": pattern_key(seed, self.token, "level")}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect 'Dead' parameters must be a mapping {{seed, density, levels_dn}}, got {params!r}")
        check_seed(cls.token, params)
        check_density(cls.token, params)
        _levels(params)


def octiles(values) -> list[float]:
    """Median of each eighth of the sorted ``values``: 8 equally likely levels."""
    v = np.sort(np.asarray(values, dtype=np.float64))
    return [float(np.median(part)) for part in np.array_split(v, L.DEAD_LEVELS)] if v.size >= L.DEAD_LEVELS \
        else [float(v[i * v.size // L.DEAD_LEVELS]) for i in range(L.DEAD_LEVELS)]


def estimate(frames, synthesized, k: float, seed: int = 47, **_) -> dict:
    """Dead-pixel parameters from a stack (N >= 3, 4, h, w) in DN: the stuck fraction over the
    model's (its syntheses ``synthesized``), the stuck pixels' levels. Where the model's own
    pixels stick by chance (read noise well under a DN), some of the measured levels are theirs.
    ValueError where the stack shows none (no more stuck pixels than the model's)."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.shape[0] < 3:
        raise ValueError("dead pixels are measured on stacks of >= 3 frames")
    stuck, levels = stuck_pixels(frames)
    base = float(np.mean([stuck_pixels(s)[0].mean() for s in synthesized])) if len(synthesized) else 0.0
    density = max(float(stuck.mean()) - base, 0.0)
    if density == 0.0 or levels.size == 0:
        raise ValueError("no more stuck pixels than the model's: this stack shows no dead pixels")
    return {"seed": int(seed), "density": min(density, 0.1), "levels_dn": octiles(levels)}


def combine(records) -> dict:
    """One entry from the records of the stacks that saw dead pixels (a bias stack that clips
    where they are stuck sees none): the median density, the levels pooled."""
    levels = np.concatenate([r["levels_dn"] for r in records])
    return {"seed": int(records[0]["seed"]), "density": float(np.median([r["density"] for r in records])),
            "levels_dn": octiles(levels)}


def empty(params) -> bool:
    """True when no pixel is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
