"""Row pairs (RowPair): the two sensor rows of a Bayer row pair share a row offset, new in every
frame.

Physics: many CMOS sensors convert two rows at once (a two-row readout: one column ADC bank
per row, or shared column lines); the reference both rows' conversions use moves them together.
The ELD row noise ``R`` is one offset per sensor row; calibration reads ``sigma_r`` from
sensor-row means, which hold the shared part as well, so the model gives it to every row on
its own and misses that the pair moves as one.

Stage (DN): in frame ``b``, packed row ``y`` (sensor rows 2y and 2y + 1) adds ``sigma_dn(K) *
z[b, y]``, ``z`` standard normal per frame and pair.

Profile entry (per-K records)::  ``RowPair: {k: [K, ...], sigma_dn: [...]}``

Detected on bias and dark stacks of >= 3 frames by ``row_pair_corr`` (the covariance of a pair's
two rows beyond that of rows of adjacent pairs). Estimated by ``estimate``: that difference of
covariances less the model's, kept where it stands ``Z`` standard errors above 0; judged with
``sigma_r`` re-fitted.
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import row_pair_covariances
from .base import BANDING, NoiseEffect, register
from .k_records import combine_sigma, validate_records, value_at_k

STATISTICS = ("row_pair_corr",)
SHARES_ROW_NOISE = True  # calibration gave the shared offsets to sigma_r
Z = 5.0  # standard errors of the covariance difference a shared offset must reach


@register
class RowPair(NoiseEffect):
    token = "RowPair"
    order = BANDING
    flag = L.ROW_PAIR
    columns = ("rpair_sigma",)

    def draw(self, ctx):
        return {"rpair_sigma": value_at_k(self.profile.effects[self.token], "sigma_dn", ctx.k)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",), nonnegative=("sigma_dn",))


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """RowPair record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w; DN) against the
    model's syntheses of it."""
    frames = np.asarray(frames, dtype=np.float64)
    n = frames.shape[0]
    if kind not in ("bias", "dark") or n < 3:
        raise ValueError("RowPair is measured on bias or dark stacks of >= 3 frames")
    within, across, var = row_pair_covariances(frames)
    model = [row_pair_covariances(np.asarray(s, dtype=np.float64)) for s in synthesized]
    base = float(np.mean([m[0] - m[1] for m in model])) if model else 0.0
    excess = within - across - base
    se = var * np.sqrt(2.0 / (n * frames.shape[2]))  # two means of products over n x h pairs
    sigma2 = excess * n / (n - 1) if excess > Z * se else 0.0  # the stack's mean took 1/N
    return {"k": [float(k)], "sigma_dn": [float(np.sqrt(sigma2))]}


def combine(records: list[dict]) -> dict:
    """One record per gain: the rms of its stacks' offsets."""
    return combine_sigma(records)


def empty(params) -> bool:
    """True when no pair shares an offset."""
    return not any(float(s) > 0 for s in params["sigma_dn"])
