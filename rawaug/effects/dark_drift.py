"""Dark-signal drift (DarkDrift): the whole dark signal of a frame is scaled by a factor of its
own, which wanders over a sequence of frames.

Physics: dark current doubles every 6 to 8 degrees C, and a sensor warms while it reads a
series of long dark frames (or cools between bursts), so each frame collects its dark
electrons at a rate of its own: the frame means of a dark stack move in proportion to the
dark signal, with its shot noise, while the bias frames (no dark signal) stay put. Consecutive
frames are close in temperature: the log factor is an AR(1) over the frames, like
``BlackDrift``'s offsets. ``BlackDrift`` moves bias frames as much as darks; ``FrameGain``
scales the photo signal of flats.

Stage (DN, before shot noise, after every dark stage): ``s -> s_pixel + f (s - s_pixel)``,
``s - s_pixel`` the dark signal the stages above added (``Dark``, ``Glow``, hot, leaky and
telegraph pixels), ``f = exp(x - sigma^2 / 2)`` (mean 1), ``x`` the AR(1) log factor. With
``fixed={"sequence": 1}`` the batch's samples are consecutive frames and ``x`` walks across
them (the loop synthesizes a measured stack so); otherwise every sample is an independent
shot, ``x`` from the stationary law N(0, sigma^2).

Profile entry (one for the camera: a temperature does not depend on the gain)::

    DarkDrift: {sigma: 0.1, rho: 0.5}

Detected on dark stacks by ``frame_mean_std``, ``frame_mean_common_cov``, ``frame_mean_lag1``
(the frame means) and ``frame_noise_spread`` (their dark shot noise). Estimated by
``estimate``: each dark stack's frame means less the black level of its ISO's bias frames,
over their mean (the relative dark signal of each frame), their common-mode sums in excess of
the model's syntheses; ``combine`` pools them as ``BlackDrift`` does (one ``rho`` and one
``sigma``), without its drift test.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..engine import layout as L
from . import black_drift
from .base import PHOTON, NoiseEffect, register
from .k_records import _number

STATISTICS = ("frame_mean_std", "frame_mean_common_cov", "frame_mean_lag1", "frame_noise_spread")
MAX_SIGMA = 2.0  # log factor per frame: 2 is a 7-fold rate, 15 degrees C


@register
class DarkDrift(NoiseEffect):
    token = "DarkDrift"
    order = PHOTON + 9  # after every dark stage, before shot noise
    flag = L.DARK_DRIFT
    columns = ("dark_factor",)

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        sigma, rho = float(p["sigma"]), float(p["rho"])
        z = ctx.normal("dark_drift")
        x = black_drift.ar1(z, sigma, rho) if float(ctx.fixed.get("sequence", 0)) else sigma * z
        return {"dark_factor": torch.exp(x - 0.5 * sigma * sigma)}

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r}")
        sigma = _number(params.get("sigma"), f"{cls.token}.sigma")
        rho = _number(params.get("rho"), f"{cls.token}.rho")
        if not 0.0 <= sigma <= MAX_SIGMA:
            raise ValueError(f"effect {cls.token!r}: sigma (std of the log dark factor per frame) must be in [0, {MAX_SIGMA:g}], "
                             f"got {sigma}")
        if not 0.0 <= rho < 1.0:
            raise ValueError(f"effect {cls.token!r}: rho (correlation of consecutive frames) must be in [0, 1), got {rho}")


def relative_means(frames, black_dn, signal_dn: float):
    """(N, 4) frame-channel means of a dark stack (N, 4, h, w; DN) less the black level
    ``black_dn`` (4,), over ``signal_dn``: each frame's dark signal relative to the stack's."""
    return (np.asarray(frames, dtype=np.float64).mean(axis=(2, 3)) - np.asarray(black_dn, dtype=np.float64)) / signal_dn


def estimate(frames, synthesized, k: float, kind=None, black_dn=None, **_) -> dict:
    """Excess common-mode sums of one dark stack (N >= 2, 4, h, w; DN) over the model's
    syntheses, in units of its dark signal above ``black_dn`` (the channel means of its ISO's
    bias frames), and its relative frame means in order: ``{k, ss, ssd, n, series}`` for
    ``combine``."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "dark" or frames.shape[0] < 2 or not synthesized or black_dn is None:
        raise ValueError("DarkDrift is measured on dark stacks of >= 2 frames, against their syntheses and the black level")
    signal = float(np.mean(frames.mean(axis=(0, 2, 3)) - np.asarray(black_dn, dtype=np.float64)))
    if not signal > 0.0:
        raise ValueError("DarkDrift needs a dark signal above the black level")
    rel = relative_means(frames, black_dn, signal)
    ss, ssd = black_drift.common_sums(rel)
    base = np.array([black_drift.common_sums(relative_means(s, black_dn, signal)) for s in synthesized])
    return {"k": [1.0], "ss": [ss - float(base[:, 0].mean())], "ssd": [ssd - float(base[:, 1].mean())],
            "n": [int(frames.shape[0])], "series": [float(v) for v in rel.mean(axis=1)]}


def combine(records: list[dict]) -> dict:
    """``{sigma, rho}`` for the camera: ``BlackDrift.combine`` of the relative sums, every stack
    at one gain, rho from the ratio of the sums about the mean to the successive ones (an
    AR(1)'s) without the drift test, the spread of the factor turned into the log-normal's
    ``sigma``."""
    # no drift test: new factors in every frame (rho 0) are no other effect's, as they are BLE's
    # for BlackDrift, so rho is the sums' own (a walk of 16 frames rarely passes the test, and
    # a spread taken with rho 0 was a third of a walk's)
    out = black_drift.combine([{k: v for k, v in r.items() if k != "series"} | {"k": [1.0]} for r in records])
    spread = float(out["sigma_dn"][0])  # of the factor itself: a log-normal's log sigma from it
    return {"sigma": min(math.sqrt(math.log1p(spread * spread)), MAX_SIGMA), "rho": float(out["rho"][0])}


def empty(params) -> bool:
    """True when sigma is 0: it would add nothing."""
    return float(params["sigma"]) == 0.0 or not math.isfinite(float(params["sigma"]))
