"""Gain non-linearity (NonLin): the output compresses (or expands) as the signal grows.

Physics: the pixel's source follower, the column amplifier and the ADC are not exactly
linear, so the mean output is not proportional to the light (EMVA 1288's linearity error);
the slope of the output against the signal falls as the signal grows, and with it the shot
noise seen in DN.

Stage (DN, after shot noise, before read noise): ``s -> s * (1 - c * s)`` for ``s > 0``
(``c`` = ``compression_per_dn``; negative ``c`` expands). A clean level of ``x`` DN then
has the mean ``x - c * (x^2 + K x)`` (``mean_response``) and a shot-noise variance
``(1 - 2 c x)^2 K x``; ``c = 4e-6`` /DN loses 6 % of the signal at 15000 DN.

Profile entry (per-K records, nearest record in log K)::

    NonLin: {k: [K, ...], compression_per_dn: [...]}

Detected by ``flat_linearity`` on flats taken at three or more exposure times under one
light, or at three or more known relative lights (the manifest's ``light`` column): a flat
series, whose dose is exposure time x light. The statistic is the stack's mean against the
line through zero that the series fits (``linear_rates``). Estimated by ``estimate``: ``c``
and one rate per channel (DN per unit dose) fitted jointly to the series' means, in relative terms (``fit_series``);
the model then synthesizes each flat at the rate its compression implies (``fit_rates``).
"""
from __future__ import annotations

import numpy as np
from scipy import optimize

from ..engine import layout as L
from .base import SHOT, NoiseEffect, register
from .k_records import combine_first, validate_records, value_at_k

STATISTICS = ("flat_linearity",)
MIN_EXPOSURES = 3  # distinct exposure times a flat series needs: a line through zero and its curvature


@register
class GainNonLinearity(NoiseEffect):
    token = "NonLin"
    order = SHOT + 5
    flag = L.NONLIN
    columns = ("nl_c",)

    def draw(self, ctx):
        return {"nl_c": value_at_k(self.profile.effects[self.token], "compression_per_dn", ctx.k)}

    @classmethod
    def check(cls, profile, fixed):
        span = float(profile.span_dn)
        for c in profile.effects[cls.token]["compression_per_dn"]:
            if not abs(c) * 2.0 * span < 1.0:
                raise ValueError(f"effect 'NonLin': compression_per_dn {c:g} /DN makes the output fall before the "
                                 f"white level ({span:g} DN): |c| must be < {0.5 / span:.3g}")

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("compression_per_dn",))


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
    if c == 0:
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
    c, _ = fit_series(series.doses, series.signal_dn, k)
    return {"k": [float(k)], "compression_per_dn": [c]}


def combine(records: list[dict]) -> dict:
    """One record per gain (the stacks of one series give the same one)."""
    return combine_first(records, "compression_per_dn")
