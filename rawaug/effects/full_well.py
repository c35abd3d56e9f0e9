"""Full well (FullWell): a pixel holds at most its own full-well capacity of electrons.

Physics: a photodiode's charge capacity (EMVA 1288's saturation capacity) is set by its well
depth and varies a little from pixel to pixel. Where the ADC's range reaches beyond it (a low
gain), a bright pixel stops at its well: its value stays put from frame to frame, the
photon transfer curve's variance collapses and the response bends before the white level.

Stage (DN, after the shot noise, before the read noise): ``min(s, K * well_e * (1 + spread *
g))``, ``g`` a seeded standard-normal map (the same in every frame). In DN the well moves with
the gain: only the ISOs whose K * well_e falls below the white level show it.

Profile entry::  ``FullWell: {seed: 71, well_e: 17000.0, spread: 0.03}``

Detected on flat stacks by ``quiet_fraction`` (pixels that hold their value while the others
carry the shot noise) and ``flat_linearity``. Estimated by ``estimate``: where a flat stack holds
more quiet pixels than the model's by more than chance, the mean well and its spread whose clip
of the model's own frames matches the measured frames' quantiles, kept where that clip halves
their squared error (quiet pixels of another cause, stuck ones, are not clipped ones).
"""
from __future__ import annotations

import numpy as np
from scipy import optimize, stats

from ..engine import layout as L
from ..statistics import quiet_pixels
from .base import SHOT, NoiseEffect, pattern_key, register
from .k_records import _number

STATISTICS = ("quiet_fraction", "flat_linearity")
RAW_FRAMES = True  # a saturated pixel holds still: no repair may take it for a stuck one
P_VALUE = 1e-3  # more quiet pixels than the model's where as many or more have this chance (binomial)
MAX_SPREAD = 0.5
LEVELS = np.linspace(0.01, 0.999, 80)  # the quantiles matched
SAMPLE = 16384  # pixel positions the fit clips (a fixed random subset)
FIT_GAIN = 0.5  # the clip must halve the quantiles' squared error of the model without it


@register
class FullWell(NoiseEffect):
    token = "FullWell"
    order = SHOT + 1
    flag = L.FULL_WELL
    columns = ("well_e", "well_spread")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        n = ctx.k.shape[0]
        return {"well_e": ctx.k.new_full((n,), float(p["well_e"])), "well_spread": ctx.k.new_full((n,), float(p["spread"]))}

    def pattern_streams(self):
        return {"well_pattern": pattern_key(self.profile.effects[self.token]["seed"], self.token)}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict) or not {"seed", "well_e", "spread"} <= set(params):
            raise ValueError(f"effect 'FullWell' needs {{seed, well_e: electrons, spread: fraction}}, got {params!r}")
        if _number(params["well_e"], "FullWell.well_e") < 0:
            raise ValueError(f"FullWell.well_e (mean full well, electrons) must be >= 0, got {params['well_e']}")
        spread = _number(params["spread"], "FullWell.spread")
        if not 0.0 <= spread <= MAX_SPREAD:
            raise ValueError(f"FullWell.spread (relative spread of the wells) must be in [0, {MAX_SPREAD}], got {spread}")


def estimate(frames, synthesized, k: float, kind=None, seed: int = 71, **_) -> dict:
    """FullWell from a flat stack (N >= 2, 4, h, w; DN) at gain ``k`` against the model's
    syntheses of it (without a full well): a record with ``well_e`` 0 where the stack shows none."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "flat" or frames.shape[0] < 2 or not synthesized:
        raise ValueError("FullWell is measured on flat stacks of >= 2 frames")
    none = {"seed": int(seed), "well_e": 0.0, "spread": 0.0, "quiet": [0.0]}
    n = frames[0].size
    quiet = quiet_pixels(frames)
    base = float(np.mean([quiet_pixels(np.asarray(s, dtype=np.float64)).mean() for s in synthesized]))
    count = int(quiet.sum())
    if count <= base * n or stats.binom.sf(count - 1, n, max(base, 1.0 / n)) > P_VALUE:
        return none
    model = np.concatenate([np.asarray(s, dtype=np.float64) for s in synthesized])
    held = frames.mean(axis=0)[quiet]
    rng = np.random.default_rng(seed)
    pick = rng.choice(n, size=min(SAMPLE, n), replace=False)
    model = model.reshape(model.shape[0], -1)[:, pick]
    g = rng.standard_normal(pick.size)
    target = np.quantile(frames, LEVELS)
    scale = max(float(np.std(frames)), 1e-9)

    def error(x):
        well = k * np.exp(x[0]) * (1.0 + np.exp(x[1]) * g)
        return float(np.sum(((np.quantile(np.minimum(model, well), LEVELS) - target) / scale) ** 2))

    spread0 = max(float(stats.median_abs_deviation(held, scale="normal")) / float(np.median(held)), 0.002)
    fit = optimize.minimize(error, [np.log(max(float(np.median(held)), 1e-9) / k), np.log(spread0)], method="Nelder-Mead",
                            options={"xatol": 1e-4, "fatol": 1e-9, "maxiter": 400})
    if not fit.fun < FIT_GAIN * error([np.inf, -np.inf]):  # the clip does not explain the quantiles: quiet for another reason
        return none
    return {"seed": int(seed), "well_e": float(np.exp(fit.x[0])), "spread": float(min(np.exp(fit.x[1]), MAX_SPREAD)),
            "quiet": [float(count - base * n)]}


def combine(records: list[dict]) -> dict:
    """The camera's full well (electrons, the same at every gain): the mean over the flat stacks
    that show one, weighed by their excess of quiet pixels; none where no stack shows one."""
    found = [r for r in records if r["well_e"] > 0]
    if not found:
        return {key: records[0][key] for key in ("seed", "well_e", "spread")}
    w = [r["quiet"][0] for r in found]
    return {"seed": found[0]["seed"], "well_e": float(np.average([r["well_e"] for r in found], weights=w)),
            "spread": float(np.average([r["spread"] for r in found], weights=w))}


def empty(params) -> bool:
    """True when no full well (well_e 0)."""
    return float(params["well_e"]) <= 0.0
