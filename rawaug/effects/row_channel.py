"""Row noise per channel (RowCh): each colour of a sensor row gets a row offset of its own.

Physics: a sensor whose odd and even columns are read by different ADC banks (top and
bottom readout) adds a row offset per bank on top of the one the whole row shares, new in
every frame. The ELD row noise ``R`` is one offset per sensor row, shared by the row's two
packed channels (R with G1, B with G2); calibration reads sigma_r from sensor-row means, in
which a per-bank part counts at half its variance.

Synthesis: ``sigma_dn * z[b, c, y]`` on every pixel of packed row ``y`` of channel ``c``,
``z`` standard normal per frame.

Profile entry (per-K records)::  ``RowCh: {k: [K, ...], sigma_dn: [...]}``

Detected by ``row_excess`` (per channel, its row means vary more than the model's).
Estimated by ``estimate`` from bias and dark stacks: per frame, the variance of each
channel's row means less their covariance with the other channel of the same sensor rows
(the shared part), over the model's. Judged with sigma_r re-fitted.
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from .base import BANDING, NoiseEffect, register
from .k_records import all_zero, combine_sigma, validate_records, value_at_k

STATISTICS = ("row_excess",)
SHARES_ROW_NOISE = True  # calibration gave half of its variance to sigma_r


@register
class RowChannel(NoiseEffect):
    token = "RowCh"
    order = BANDING
    flag = L.ROW_CHANNEL
    columns = ("rowch_sigma",)

    def draw(self, ctx):
        return {"rowch_sigma": value_at_k(self.profile.effects[self.token], "sigma_dn", ctx.k)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",), nonnegative=("sigma_dn",))


PAIRS = tuple((a, b) for a in range(4) for b in range(a + 1, 4) if L.ROW_SET[a] == L.ROW_SET[b])  # channels of one sensor row


def _unshared_variance(frames) -> float:
    """Mean over frames and sensor-row pairs of (variance of each channel's row means -
    their covariance with the pair's other channel), DN^2: the row variance a channel does
    not share (plus read noise / row length)."""
    rows = frames.mean(axis=3)
    rows = rows - rows.mean(axis=2, keepdims=True)
    out = []
    for a, b in PAIRS:
        cov = np.mean(rows[:, a] * rows[:, b], axis=1)
        out.append((np.mean(rows[:, a] ** 2, axis=1) + np.mean(rows[:, b] ** 2, axis=1)) / 2 - cov)
    return float(np.mean(out))


def estimate(frames, synthesized, k: float, level_dn=None, **_) -> dict:
    """RowCh record at gain ``k`` from a bias or dark stack (N, 4, h, w) in DN (temporal:
    about the stack mean when N >= 2). Flats are left out: a pair's shot noise leaves the
    row variance far less certain than a bias stack's."""
    frames = np.asarray(frames, dtype=np.float64)
    if level_dn is not None or not synthesized:
        raise ValueError("RowCh is measured on bias and dark stacks, against syntheses")

    def temporal(f):
        n = f.shape[0]
        return (f - f.mean(axis=0, keepdims=True)) * np.sqrt(n / (n - 1)) if n >= 2 else f

    excess = _unshared_variance(temporal(frames)) - np.mean([_unshared_variance(temporal(np.asarray(s, dtype=np.float64)))
                                                            for s in synthesized])
    return {"k": [float(k)], "sigma_dn": [float(np.sqrt(max(excess, 0.0)))]}


def combine(records: list[dict]) -> dict:
    """One record per gain: the stacks at one K averaged in variance."""
    return combine_sigma(records)


def empty(params) -> bool:
    """True when every amplitude is 0: it would add nothing."""
    return all_zero(params, ("sigma_dn",))
