"""Exposure noise (DarkNoise): temporal noise that grows with the exposure time beyond the
dark current's shot noise, white and Gaussian, with no change of level.

Physics: EMVA 1288 measures the temporal dark noise against the exposure time. With a Poisson
dark current its variance rises by ``K * mean`` DN^2 (the shot noise of the dark signal,
``Dark``). It rises faster, or without any dark signal, when the exposure itself makes noise:
a readout chain whose low-frequency noise is sampled over a longer correlated double sampling
interval, an amplifier or supply that warms during a long exposure, a dark current whose rate
fluctuates within the frame. Neither the read noise of the bias frames nor ``Dark`` (whose
noise comes with a mean) reproduces it.

Stage (DN, with the read noise): ``s -> s + sqrt(rate(K) * exposure_s) * n``, ``n`` a
standard normal new at every pixel and frame. The variance grows linearly with the exposure,
as a dark signal's shot noise does (a rate per second). The exposure is a synthesis setting
(``RawNoiseAugment(fixed={"exposure_s": t})``, default 0: none).

Profile entry (per-K records, DN^2 per second at each gain)::

    DarkNoise: {k: [K, ...], rate_dn2_per_s: [...]}

Detected on dark stacks by ``temporal_std`` and ``pixel_std``. Estimated by ``estimate``: the
median over pixels of the temporal variance, each frame's channel means taken out (a black
level that moves from frame to frame is not this), in excess of the model's syntheses',
over the exposure: the white Gaussian variance that, planted on the syntheses, gives them the
stack's (the read noise's shape moves a median of variances). ``combine`` averages the stacks
at one gain.
"""
from __future__ import annotations

import numpy as np
import torch
from scipy import optimize, stats

from ..engine import layout as L
from .base import READ, NoiseEffect, register
from .k_records import all_zero, combine_mean, validate_records, value_at_k

STATISTICS = ("temporal_std", "pixel_std")
AMPLITUDES = ("rate_dn2_per_s",)  # corrected by simulation under a clip (rawaug.loop.clip_correction)
SOLVE_STACKS = 2  # syntheses the noise is planted on to solve for it


@register
class DarkNoise(NoiseEffect):
    token = "DarkNoise"
    order = READ + 2
    flag = L.DARK_NOISE
    columns = ("dark_noise",)
    exposure = True

    def draw(self, ctx):
        rate = value_at_k(self.profile.effects[self.token], "rate_dn2_per_s", ctx.k)
        exposure = torch.as_tensor(ctx.fixed.get("exposure_s", 0.0), dtype=torch.float64, device=ctx.device).expand(ctx.batch)
        return {"dark_noise": torch.sqrt(rate * exposure)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("rate_dn2_per_s",), nonnegative=("rate_dn2_per_s",))


def white_variance(frames) -> float:
    """Median over pixels of the temporal variance (DN^2) of a stack (N >= 2, 4, h, w), each
    frame's channel means taken out, over the median of chi-square(N - 1) / (N - 1): the
    variance of white Gaussian temporal noise; a few telegraph or noisy pixels do not move it."""
    frames = np.asarray(frames, dtype=np.float64)
    n = frames.shape[0]
    centred = frames - frames.mean(axis=(2, 3), keepdims=True)
    var = centred.var(axis=0, ddof=1)
    return float(np.median(var)) / (stats.chi2.median(n - 1) / (n - 1))


def estimate(frames, synthesized, k: float, kind=None, exposure_s=None, seed: int = 0, **_) -> dict:
    """DarkNoise record at gain ``k`` from a dark stack (N >= 2, 4, h, w) in DN of
    ``exposure_s`` seconds against stacks of the same shape synthesized by the model: the
    variance of white Gaussian noise that, added to the syntheses, gives them the stack's
    ``white_variance`` (solved for: the read noise's shape moves a median of variances)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "dark" or not exposure_s or frames.shape[0] < 2 or not synthesized:
        raise ValueError("DarkNoise is measured on dark stacks of >= 2 frames with their exposure_s, against their syntheses")
    target = white_variance(frames)
    base = [np.asarray(s, dtype=np.float64) for s in synthesized[:SOLVE_STACKS]]
    z = [np.random.default_rng(seed + i).standard_normal(b.shape) for i, b in enumerate(base)]

    def short(var):
        return float(np.mean([white_variance(b + np.sqrt(var) * n) for b, n in zip(base, z)])) - target

    if short(0.0) >= 0.0:
        return {"k": [float(k)], "rate_dn2_per_s": [0.0]}
    hi = max(target, 1e-12)
    while short(hi) < 0.0:
        hi *= 2.0
    var = optimize.brentq(short, 0.0, hi, xtol=1e-4 * hi)
    return {"k": [float(k)], "rate_dn2_per_s": [float(var) / float(exposure_s)]}


def combine(records: list[dict]) -> dict:
    """One rate per gain: its stacks' rates averaged."""
    return combine_mean(records, "rate_dn2_per_s")


def empty(params) -> bool:
    """True when every rate is 0: it would add nothing."""
    return all_zero(params, ("rate_dn2_per_s",))
