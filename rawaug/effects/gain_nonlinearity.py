"""Gain non-linearity (NonLin): the output compresses (or expands) as the signal grows.

Physics: the pixel's source follower, the column amplifier and the ADC are not exactly
linear, so the mean output is not proportional to the light (EMVA 1288's linearity error);
the slope of the output against the signal falls as the signal grows, and with it the shot
noise seen in DN.

Stage (DN, after shot noise, before read noise): ``s -> s * (1 - c * s)`` for ``s > 0``
(``c`` = ``compression_per_dn``; negative ``c`` expands). A clean level of ``x`` DN then
has the mean ``x - c * (x^2 + K x)`` (``mean_response``) and a shot-noise variance
``(1 - 2 c x)^2 K x``; ``c = 4e-6`` /DN loses 6 % of the signal at 15000 DN.

Profile entry (per-K records, nearest record in log K; a record is one ``c`` for every
channel, or ``[c_R, c_G1, c_B, c_G2]`` where a channel's amplifier bends on its own)::

    NonLin: {k: [K, ...], compression_per_dn: [...]}

Detected by ``flat_linearity`` (and ``channel_linearity``, one channel against the others) on flats taken at three or more exposure times under one
light, or at three or more known relative lights (the manifest's ``light`` column): a flat
series, whose dose is exposure time x light. The statistic is the stack's mean against the
line through zero that the series fits (``linear_rates``). Estimated by ``estimate``: ``c``
and one rate per channel (DN per unit dose) fitted jointly to the series' means, in relative terms (``fit_series``);
one ``c`` per channel where the common one leaves the channels' linearity errors apart by more
than ``channel_linearity`` resolves (``fit_channels``). The model then synthesizes each flat at
the rate its compression implies (``fit_rates``).
"""
from __future__ import annotations

import numpy as np
import torch
from scipy import optimize

from ..engine import layout as L
from .base import SHOT, NoiseEffect, register
from ..statistics import CHANNEL_LINEARITY_FLOOR
from .k_records import record_index, validate_records

STATISTICS = ("flat_linearity", "channel_linearity")
CHANNEL_EXCESS = 3.0  # a channel's own compression: the common one's channel spread over the channels' own fits' at least this
MIN_EXPOSURES = 3  # distinct exposure times a flat series needs: a line through zero and its curvature


@register
class GainNonLinearity(NoiseEffect):
    token = "NonLin"
    order = SHOT + 5
    flag = L.NONLIN
    columns = tuple(f"nl_c{i}" for i in range(4))

    def draw(self, ctx):
        params = self.profile.effects[self.token]
        table = ctx.k.new_tensor(channel_records(params))[record_index(params, ctx.k)]  # (B, 4)
        return {f"nl_c{i}": table[:, i] for i in range(4)}

    @classmethod
    def check(cls, profile, fixed):
        span = float(profile.span_dn)
        for c in np.ravel(channel_records(profile.effects[cls.token])):
            if not abs(c) * 2.0 * span < 1.0:
                raise ValueError(f"effect 'NonLin': compression_per_dn {c:g} /DN makes the output fall before the "
                                 f"white level ({span:g} DN): |c| must be < {0.5 / span:.3g}")

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("compression_per_dn",))
        for c in params["compression_per_dn"]:
            if isinstance(c, (list, tuple)) and (len(c) != 4 or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                                          and np.isfinite(v) for v in c)):
                raise ValueError(f"effect 'NonLin': a compression_per_dn record is one number or 4 finite numbers "
                                 f"(R, G1, B, G2; /DN), got {c!r}")


def channel_records(params: dict) -> list[list[float]]:
    """Each record's compression per channel (R, G1, B, G2; /DN): a common one repeated."""
    return [[float(v) for v in c] if isinstance(c, (list, tuple)) else [float(c)] * 4 for c in params["compression_per_dn"]]


def at_k(params: dict | None, k: float) -> np.ndarray:
    """(4,) compression per channel (/DN) of the record nearest ``k`` (zeros without NonLin)."""
    if not params:
        return np.zeros(4)
    return np.asarray(channel_records(params)[int(record_index(params, torch.tensor([float(k)], dtype=torch.float64))[0])])


def mean_response(x, c, k):
    """Mean output (DN) of a clean level ``x`` DN (> 0) under Poisson shot noise of gain ``k``
    DN/e-, compressed by ``c`` per DN: E[s - c s^2] = x - c (x^2 + k x)."""
    x = np.asarray(x, dtype=np.float64)
    return x - c * (x * x + k * x)


def _check_series(exposures_s, signal_dn):
    t = np.asarray(exposures_s, dtype=np.float64)
    mu = np.asarray(signal_dn, dtype=np.float64)
    if t.ndim != 1 or mu.shape != (t.size, 4):
        raise ValueError(f"a flat series needs exposures (n,) and channel means (n, 4), got {t.shape} and {mu.shape}")
    if np.unique(t).size < MIN_EXPOSURES or not np.all(t > 0) or not np.all(mu > 0):
        raise ValueError(f"a flat series needs >= {MIN_EXPOSURES} distinct exposures > 0 (s, or s x relative light) and means > 0 DN, "
                         f"got exposures {t.tolist()}")
    return t, mu


def linear_rates(exposures_s, signal_dn):
    """Rate per channel (DN/s) of the line through zero that fits the series' means best in
    relative terms: R = sum(t / mu) / sum(t^2 / mu^2)."""
    t, mu = _check_series(exposures_s, signal_dn)
    return (t[:, None] / mu).sum(axis=0) / ((t[:, None] / mu) ** 2).sum(axis=0)


def fit_rates(exposures_s, signal_dn, c, k):
    """Rate per channel (DN/s) whose clean levels ``R t``, compressed by ``c``, fit the
    series' means best in relative terms (Gauss-Newton from the linear rates)."""
    t, mu = _check_series(exposures_s, signal_dn)
    rates = linear_rates(t, mu)
    if np.all(np.asarray(c) == 0):
        return rates
    for _ in range(8):
        x = rates[None, :] * t[:, None]
        r = (mean_response(x, c, k) - mu) / mu
        j = t[:, None] * (1.0 - c * (2.0 * x + k)) / mu
        rates = rates - (j * r).sum(axis=0) / (j * j).sum(axis=0)
    return rates


def fit_series(exposures_s, signal_dn, k):
    """(c per DN, rates (4,) DN/s) fitted jointly to a flat series: one compression, one
    rate per channel, relative residuals."""
    t, mu = _check_series(exposures_s, signal_dn)
    rates = linear_rates(t, mu)
    top = float(mu.max())

    def residuals(p):
        c = p[0] / top  # p[0]: the compression at the series' brightest mean (dimensionless)
        return ((mean_response(p[1:][None, :] * t[:, None], c, k) - mu) / mu).ravel()

    fit = optimize.least_squares(residuals, np.concatenate([[0.0], rates]), x_scale=np.concatenate([[0.01], rates]))
    return float(fit.x[0] / top), fit.x[1:]


def estimate(frames, synthesized, k: float, series=None, **_) -> dict:
    """Gain non-linearity at gain ``k`` from the flat series a flat stack belongs to
    (``series.doses`` (n,), ``series.signal_dn`` (n, 4): measured channel means less
    the bias offsets). Every stack of one series gives the same record."""
    if series is None:
        raise ValueError(f"NonLin needs flats at >= {MIN_EXPOSURES} exposures (time x relative light): a flat series")
    t, mu = series.doses, series.signal_dn
    c, rates = fit_series(t, mu, k)
    common = channel_spread(t, mu, c, rates, k)
    own, own_rates = fit_channels(t, mu, k)
    # each channel its own c where the common one leaves a spread the statistic resolves and
    # well beyond the one the channels' own fits leave (the means' noise, the light's colour)
    if common > max(CHANNEL_LINEARITY_FLOOR, CHANNEL_EXCESS * channel_spread(t, mu, own, own_rates, k)):
        return {"k": [float(k)], "compression_per_dn": [[float(v) for v in own]]}
    return {"k": [float(k)], "compression_per_dn": [c]}


def channel_spread(doses, signal_dn, c, rates, k) -> float:
    """The largest spread over the channels (rms about their mean, as ``channel_linearity``)
    of the relative residuals a compression ``c`` (one, or (4,)) and its ``rates`` leave."""
    t, mu = _check_series(doses, signal_dn)
    r = mean_response(rates[None, :] * t[:, None], np.asarray(c), k) / mu - 1.0
    return float(np.sqrt(((r - r.mean(axis=1, keepdims=True)) ** 2).mean(axis=1)).max())


def fit_channels(doses, signal_dn, k) -> tuple[np.ndarray, np.ndarray]:
    """((4,) compression per channel /DN, (4,) rates), each channel's series fitted on its own."""
    t, mu = _check_series(doses, signal_dn)
    fits = [fit_series(t, np.repeat(mu[:, i:i + 1], 4, axis=1), k) for i in range(4)]
    return np.array([c for c, _ in fits]), np.array([r[0] for _, r in fits])


def combine(records: list[dict]) -> dict:
    """One record per gain (the stacks of one series give the same one)."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), r["compression_per_dn"][0])
    ks = sorted(by_k)
    return {"k": ks, "compression_per_dn": [by_k[k] for k in ks]}
