"""Pixel gain noise (GainNoise): each pixel's gain on its signal moves by a small relative
amount, new at every pixel and frame, so a flat's temporal variance grows with the square of
its level.

Physics: photon transfer gives a flat's temporal variance as ``read + K mean`` (shot noise).
Noise on the conversion itself (the source follower's gain, the sense node's capacitance, the
column amplifier's reference sampled at every pixel) multiplies the signal by ``1 + g z``
and adds ``g^2 mean^2``: the photon transfer curve bends upward, and the bright flats' noise
exceeds what K and the read noise give. Bias frames carry no signal and show none. ``PRNU``
is fixed (it cancels in a pair's difference), ``FrameGain`` and ``RowGain`` move whole frames
and rows; calibration's photon-transfer parabola takes K as its slope at zero, so the
curvature is left to this stage.

Stage (DN, after shot noise and the other gains): ``s -> s (1 + g(K) z)``, ``z`` a standard
normal new at every pixel and frame.

Profile entry (per-K records, relative std)::

    GainNoise: {k: [K, ...], sigma_rel: [...]}

Detected on flat stacks by ``temporal_std`` and ``pixel_std``. Estimated by ``estimate``: the
relative std that, planted on the model's syntheses of a flat stack, gives them the stack's
white temporal variance (``dark_noise.white_variance``); ``combine`` pools a gain's flat
stacks by the precision of each (a dim flat says little about a variance that grows with
the square of the level).
"""
from __future__ import annotations

import numpy as np
from scipy import optimize

from ..engine import layout as L
from .base import SHOT, NoiseEffect, register
from .dark_noise import white_variance
from .k_records import all_zero, validate_records, value_at_k

STATISTICS = ("temporal_std", "pixel_std")
SOLVE_STACKS = 2  # syntheses the noise is planted on to solve for it
MAX_SIGMA = 0.2  # a relative gain noise beyond this is not a gain's noise


@register
class GainNoise(NoiseEffect):
    token = "GainNoise"
    order = SHOT + 6
    flag = L.GAIN_NOISE
    columns = ("gain_noise",)

    def draw(self, ctx):
        return {"gain_noise": value_at_k(self.profile.effects[self.token], "sigma_rel", ctx.k)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_rel",), nonnegative=("sigma_rel",))
        for v in params["sigma_rel"]:
            if float(v) > MAX_SIGMA:
                raise ValueError(f"effect {cls.token!r}: sigma_rel must be <= {MAX_SIGMA} (a relative std), got {v}")


def estimate(frames, synthesized, k: float, kind=None, black_dn=None, seed: int = 0, **_) -> dict:
    """GainNoise record at gain ``k`` from a flat stack (N >= 2, 4, h, w; DN) against stacks of
    the same shape synthesized by the model: the relative std ``g`` whose noise ``g x z`` (``x``
    each channel's level above ``black_dn``) added to the syntheses gives them the stack's
    ``white_variance``, with the record's ``weight``: the squared level over that variance,
    squared (the precision of ``g^2`` from one stack, up to a constant)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "flat" or frames.shape[0] < 2 or not synthesized:
        raise ValueError("GainNoise is measured on flat stacks of >= 2 frames, against their syntheses")
    black = np.zeros(4) if black_dn is None else np.broadcast_to(np.asarray(black_dn, dtype=np.float64), (4,))
    black = black[:, None, None]
    target = white_variance(frames)
    level = float(np.maximum(frames.mean(axis=(0, 2, 3)) - black[:, 0, 0], 0.0).mean())
    weight = (level**2 / max(target, 1e-12)) ** 2
    base = [np.asarray(s, dtype=np.float64) for s in synthesized[:SOLVE_STACKS]]
    z = [np.random.default_rng(seed + i).standard_normal(b.shape) for i, b in enumerate(base)]

    def short(g):  # the stage's noise on each synthesized pixel's signal
        return float(np.mean([white_variance(b + g * np.maximum(b - black, 0.0) * n) for b, n in zip(base, z)])) - target

    g = 0.0
    if level > 0.0 and short(0.0) < 0.0:
        hi = min(np.sqrt(max(target, 1e-12)) / level, MAX_SIGMA)
        while short(hi) < 0.0 and hi < MAX_SIGMA:
            hi = min(2.0 * hi, MAX_SIGMA)
        g = optimize.brentq(short, 0.0, hi, xtol=1e-4 * hi) if short(hi) >= 0.0 else MAX_SIGMA
    return {"k": [float(k)], "sigma_rel": [float(g)], "weight": [float(weight)]}


def combine(records: list[dict]) -> dict:
    """One relative std per gain: its stacks' ``g^2`` averaged with their weights."""
    by_k: dict[float, list] = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append((float(r["sigma_rel"][0]) ** 2, float(r["weight"][0])))
    ks = sorted(by_k)
    sigmas = []
    for kk in ks:
        g2, w = np.array(by_k[kk]).T
        sigmas.append(float(np.sqrt(np.sum(w * g2) / np.sum(w))) if np.sum(w) > 0 else float(np.sqrt(g2.mean())))
    return {"k": ks, "sigma_rel": sigmas}


def empty(params) -> bool:
    """True when every relative std is 0: it would add nothing."""
    return all_zero(params, ("sigma_rel",))
