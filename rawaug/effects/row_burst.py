"""Burst rows (RowBurst): a few sensor rows of every frame, new ones each frame, read with extra
white noise.

Physics: interference that comes in bursts (a motor's brushes, a radio transmitter's packets, a
switching converter that skips cycles under light load) couples into the readout chain only
while it lasts; a rolling readout turns a burst into the sensor rows read meanwhile, whose
pixels all carry the extra noise. Unlike ``RowRTS`` (a row's offset that jumps), ``Noisy``
(pixels noisy in every frame), ``NoisyCol`` (columns noisy in every frame) or ``FrameNoise``
(a whole frame's read noise), the rows change from frame to frame and their mean does not
move.

Stage (DN, with the read noise): in frame ``b``, sensor row ``Y`` is a burst row where a U(0, 1)
of ``(b, Y)`` falls below ``density``; each of its pixels gets ``sigma_dn(K) * z``, ``z`` a
standard normal new at every pixel and frame.

Profile entry (per-K records)::

    RowBurst: {density: 0.01, k: [K, ...], sigma_dn: [...]}

Detected on bias and dark stacks of >= 3 frames by ``burst_rows`` (frames' sensor rows whose
variance, clipped at 8 robust sigma, stands ``BURST_Z`` sds above the same row's median over
the frames) and
``read_noise_spread``. Estimated by ``estimate``: the measured share of burst rows less the
model's, kept where the count has a chance under ``P_VALUE`` under the model's (Poisson); the
extra variance the median over the burst rows of their variance less their row's median, over
(1 - 1/N)^2 (the stack mean holds 1/N of a burst).
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import burst_cols, burst_row_ratios, burst_rows
from .base import READ, NoiseEffect, register
from .k_records import _number, validate_records, value_at_k

STATISTICS = ("burst_rows", "read_noise_spread")
SHARES_READ_NOISE = True  # calibration's read noise holds the bursts' share of the variance
P_VALUE = 1e-3  # burst rows count where as many or more have this chance under the model's count
MIN_BASE = 0.5  # the model's burst rows per stack taken as at least this
MAX_DENSITY = 0.5


@register
class RowBurst(NoiseEffect):
    token = "RowBurst"
    order = READ + 1
    flag = L.ROW_BURST
    columns = ("burst_density", "burst_sigma")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {"burst_density": ctx.k.new_full(ctx.k.shape, float(p["density"])), "burst_sigma": value_at_k(p, "sigma_dn", ctx.k)}

    @classmethod
    def validate_params(cls, params):
        validate_bursts(cls.token, params, "rows")


def validate_bursts(token: str, params, lines: str):
    """Per-K ``sigma_dn`` records and a ``density`` (share of a frame's sensor ``lines``) in [0,
    ``MAX_DENSITY``]; ValueError naming the value otherwise."""
    validate_records(token, params, ("sigma_dn",), nonnegative=("sigma_dn",))
    density = _number(params.get("density"), f"{token}.density")
    if not 0.0 <= density <= MAX_DENSITY:
        raise ValueError(f"effect {token!r}: density (share of a frame's sensor {lines}) must be in [0, {MAX_DENSITY}], got {density}")


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """RowBurst record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w) in DN, against
    stacks of the same shape synthesized by the model."""
    return burst_record("RowBurst", frames, synthesized, k, kind, columns=False)


def burst_record(token: str, frames, synthesized, k: float, kind, columns: bool) -> dict:
    """A burst-line record (RowBurst, or with ``columns`` ColBurst) at gain ``k`` from a bias or
    dark stack against the model's syntheses: the share of lines beyond the model's count and
    their extra noise (DN)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3:
        raise ValueError(f"{token} is measured on bias or dark stacks of >= 3 frames")
    ratio, threshold, line_var = burst_row_ratios(frames, columns=columns)
    hit = ratio > threshold
    share = burst_cols if columns else burst_rows
    base = float(np.mean([share(s) for s in synthesized])) * hit.size if synthesized else 0.0
    record = {"density": 0.0, "k": [float(k)], "sigma_dn": [0.0], "rows": [int(hit.size)]}
    count = int(hit.sum())
    if not beyond_model(count, base):
        return record
    excess = (ratio - 1.0) * line_var[None, :]  # DN^2 above the line's own
    sigma2 = float(np.median(excess[hit])) / (1.0 - 1.0 / frames.shape[0]) ** 2
    return record | {"density": min((count - base) / hit.size, MAX_DENSITY), "sigma_dn": [float(np.sqrt(max(sigma2, 0.0)))]}


def beyond_model(count: int, base: float) -> bool:
    """Do ``count`` events of a stack exceed the model's mean count ``base`` by more than chance
    (as many or more with a chance under ``P_VALUE`` for a Poisson count of mean ``base``, at
    least ``MIN_BASE``)?"""
    return count > base and stats.poisson.sf(count - 1, max(base, MIN_BASE)) <= P_VALUE


def combine(records: list[dict]) -> dict:
    """The camera's share of burst rows: the stacks' that found any, weighed by their rows (a
    burst is an event in time, the same share at every gain; where the read noise is larger it
    hides the bursts, and a stack that sees none does not vote); the extra noise per gain, the
    rms over its stacks that found any."""
    found = [r for r in records if r["density"] > 0]
    if not found:
        return {"density": 0.0, "k": [float(records[0]["k"][0])], "sigma_dn": [0.0]}
    density = float(np.average([r["density"] for r in found], weights=[r["rows"][0] for r in found]))
    by_k: dict = {}
    for r in found:
        by_k.setdefault(float(r["k"][0]), []).append(r["sigma_dn"][0] ** 2)
    ks = sorted(by_k)
    return {"density": density, "k": ks, "sigma_dn": [float(np.sqrt(np.mean(by_k[k]))) for k in ks]}


def empty(params) -> bool:
    """True when no row bursts (density 0 or no extra noise)."""
    return float(params["density"]) == 0.0 or not any(float(s) > 0 for s in params["sigma_dn"])
