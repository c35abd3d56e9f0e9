"""Shared-pixel readout (Shared): the four pixels of a Bayer tile share part of their read noise.

Physics: small-pixel sensors share one floating diffusion, source follower and row select
among a 2x2 cell of photodiodes (4-shared pixels); the noise of the shared transistors is
in all four readings. Aligned with the colour filter tile, the four packed channels at one
packed position share it, while pixels of neighbouring tiles do not: the covariance of
raw neighbours depends on whether they lie in one tile. ``Xtalk`` (coupling between
neighbours) is the same everywhere; the ELD read noise is white.

Synthesis: ``sigma_dn * z[b, y, x]`` on all four packed channels at (y, x), ``z`` standard
normal per frame and packed position.

Profile entry (per-K records)::  ``Shared: {k: [K, ...], sigma_dn: [...]}``

Detected by ``tile_corr`` (the correlation of raw neighbours in one tile over that of
neighbours in adjacent tiles). Estimated by ``estimate``: that covariance difference over
the model's, from bias and dark stacks; within 3 sd of the model's spread it is 0. Judged with
the read noise re-fitted (calibration counted the shared noise as white read noise).
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import tile_covariance_excess
from .base import READ, NoiseEffect, register
from .k_records import all_zero, combine_sigma, validate_records, value_at_k

STATISTICS = ("tile_corr",)
SHARES_READ_NOISE = True  # calibration counted its variance as white read noise
SIGNIFICANT = 3.0  # the excess counts beyond this many sd of the model's


@register
class SharedPixel(NoiseEffect):
    token = "Shared"
    order = READ
    flag = L.SHARED
    columns = ("shared_sigma",)

    def draw(self, ctx):
        return {"shared_sigma": value_at_k(self.profile.effects[self.token], "sigma_dn", ctx.k)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",), nonnegative=("sigma_dn",))


def estimate(frames, synthesized, k: float, level_dn=None, **_) -> dict:
    """Shared record at gain ``k`` from a bias or dark stack (N >= 2, 4, h, w) in DN."""
    frames = np.asarray(frames, dtype=np.float64)
    if level_dn is not None or frames.shape[0] < 2:
        raise ValueError("Shared is measured on bias and dark stacks of >= 2 frames")
    measured = tile_covariance_excess(frames)[0]
    model = np.array([tile_covariance_excess(np.asarray(s, dtype=np.float64))[0] for s in synthesized])
    excess = measured - model.mean()
    spread = model.std(ddof=1) * np.sqrt(1.0 + 1.0 / len(model)) if len(model) > 1 else 0.0
    var = excess if excess > SIGNIFICANT * spread else 0.0
    return {"k": [float(k)], "sigma_dn": [float(np.sqrt(var))]}


def combine(records: list[dict]) -> dict:
    """One record per gain: the stacks at one K averaged in variance."""
    return combine_sigma(records)


def empty(params) -> bool:
    """True when every amplitude is 0: it would add nothing."""
    return all_zero(params, ("sigma_dn",))
