"""Frame-to-frame black-level error (BLE): one offset for the whole frame, new in every frame.

Physics: the black-level clamp (optical-black rows, ADC reference) settles to a slightly
different value in every frame, so each frame's mean moves as a whole, in all four
channels together. The row noise ``R`` cannot produce this: it averages out over the rows
of a frame, and it only couples the two channels of a sensor row.

Synthesis: ``signal + sigma_dn * z + channel_sigma_dn * z_c`` with one standard-normal
``z`` per frame shared by all channels, and ``z_c`` per frame and channel (the measured
IMX686 tables show both parts); drawn from the effect's own generator, so
``aug._params`` replays them.

Profile entry (per-K records)::  ``BLE: {k: [K, ...], sigma_dn: [...], channel_sigma_dn: [...]}``
(``channel_sigma_dn`` optional, default 0).

Detected by ``frame_mean_std`` and, specifically, ``frame_mean_common_cov``: the
covariance across frames of the means of channels that share neither a row nor a column.
Estimated by ``estimate``: that covariance minus the current model's (needs >= 3 frames).
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from .base import OFFSET, NoiseEffect, register
from .k_records import validate_records, value_at_k

STATISTICS = ("frame_mean_common_cov", "frame_mean_std")


@register
class FrameBlackLevel(NoiseEffect):
    token = "BLE"
    order = OFFSET
    flag = L.BLE
    columns = ("ble_sigma", "ble_channel_sigma")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        channel = value_at_k(p, "channel_sigma_dn", ctx.k) if "channel_sigma_dn" in p else torch.zeros_like(ctx.k)
        return {"ble_sigma": value_at_k(p, "sigma_dn", ctx.k), "ble_channel_sigma": channel}

    @classmethod
    def validate_params(cls, params):
        keys = ("sigma_dn", "channel_sigma_dn") if isinstance(params, dict) and "channel_sigma_dn" in params else ("sigma_dn",)
        validate_records(cls.token, params, keys, nonnegative=keys)


def common_covariance(frame_means) -> float:
    """Covariance across frames of the (R, B) and (G1, G2) means, DN^2, from (N, 4) means."""
    c = np.cov(np.asarray(frame_means, dtype=np.float64).T)
    return float((c[0, 2] + c[1, 3]) / 2.0)


def channel_variance(frame_means) -> float:
    """Mean over channels of the variance across frames of the channel means, DN^2."""
    return float(np.asarray(frame_means, dtype=np.float64).var(axis=0, ddof=1).mean())


def split_excess(common_excess: float, variance_excess: float) -> tuple[float, float]:
    """(sigma_dn, channel_sigma_dn) from the excess common covariance and the excess
    per-channel variance over the model (DN^2): variance = common + channel part."""
    common = max(common_excess, 0.0)
    return float(np.sqrt(common)), float(np.sqrt(max(variance_excess - common, 0.0)))


def estimate(frames, synthesized, k: float, **_) -> dict:
    """BLE record at gain ``k`` from a measured stack (N >= 3, 4, h, w) in DN."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.shape[0] < 3:
        raise ValueError(f"BLE needs a stack of at least 3 frames, got {frames.shape[0]}")
    fm = frames.mean(axis=(2, 3))
    base = [np.asarray(s, dtype=np.float64).mean(axis=(2, 3)) for s in synthesized]
    cov_base = float(np.mean([common_covariance(b) for b in base])) if base else 0.0
    var_base = float(np.mean([channel_variance(b) for b in base])) if base else 0.0
    sigma, channel = split_excess(common_covariance(fm) - cov_base, channel_variance(fm) - var_base)
    return {"k": [float(k)], "sigma_dn": [sigma], "channel_sigma_dn": [channel]}
