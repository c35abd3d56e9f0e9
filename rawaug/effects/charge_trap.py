"""Charge trapping (Trap): a pixel loses the first electrons of its charge, so the response
has a toe at low light and a constant shortfall above it.

Physics: traps in the photodiode or at the transfer gate capture electrons of the collected
charge (and release them after the readout). A few traps fill first: a charge of ``n``
electrons loses ``q (1 - exp(-n / q))`` of them, ``q`` the traps' capacity. Dim flats fall
below the line of a linear response by a larger share than bright ones, which all lack about
``q`` electrons: EMVA 1288's linearity error at the low end, which a compression of the
bright end (``NonLin``) does not make.

Stage (DN, after shot noise, before the gain non-linearity): ``s -> s - K q (1 - exp(-s / (K q)))``
for ``s > 0`` (``q`` = ``trap_e`` electrons at the gain K). A clean level ``x`` DN with Poisson
shot noise has the mean ``mean_response``.

Profile entry (per-K records, nearest record in log K)::

    Trap: {k: [K, ...], trap_e: [...]}

Detected by ``flat_linearity`` on a flat series (flats at three or more doses: exposure time
x relative light). Estimated by ``estimate``: ``q`` and one rate per channel fitted jointly to
the series' means in relative terms (``fit_series``); the model then synthesizes each flat at
the rate its toe implies (``fit_rates``, through ``rawaug.loop.diagnose.FlatSeries``).
"""
from __future__ import annotations

import numpy as np
import torch
from scipy import optimize

from ..engine import layout as L
from .base import SHOT, NoiseEffect, register
from .gain_nonlinearity import _check_series, linear_rates
from .gain_nonlinearity import mean_response as compressed
from .k_records import all_zero, combine_first, validate_records, value_at_k

STATISTICS = ("flat_linearity",)


@register
class ChargeTrap(NoiseEffect):
    token = "Trap"
    order = SHOT + 4
    flag = L.TRAP
    columns = ("trap_dn",)

    def draw(self, ctx):
        return {"trap_dn": ctx.k * value_at_k(self.profile.effects[self.token], "trap_e", ctx.k)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("trap_e",), nonnegative=("trap_e",))


def mean_response(x, q, k):
    """Mean output (DN) of a clean level ``x`` DN (> 0) with Poisson shot noise of gain ``k``
    DN/e- after traps of ``q`` electrons: for a Poisson count n of mean x / k,
    E[exp(-n / q)] = exp((x / k) (exp(-1 / q) - 1)), so the mean is x - k q (1 - that)."""
    x = np.asarray(x, dtype=np.float64)
    if q <= 0:
        return x
    return x - k * q * (1.0 - np.exp(x / k * np.expm1(-1.0 / q)))


def fit_rates(doses, signal_dn, q, k, c: float = 0.0):
    """Rate per channel (DN per unit dose) whose clean levels, through traps of ``q`` electrons
    and then a compression ``c`` per DN (``NonLin``), fit the series' means best in relative
    terms (Gauss-Newton from the linear rates, numerical slopes)."""
    t, mu = _check_series(doses, signal_dn)
    rates = linear_rates(t, mu)

    def response(x):
        return compressed(mean_response(x, q, k), c, k)

    for _ in range(12):
        x = rates[None, :] * t[:, None]
        h = 1e-6 * np.maximum(x, 1.0)
        r = (response(x) - mu) / mu
        j = t[:, None] * (response(x + h) - response(x - h)) / (2.0 * h) / mu
        step = (j * r).sum(axis=0) / (j * j).sum(axis=0)
        rates = rates - step
        if np.all(np.abs(step) <= 1e-12 * np.abs(rates)):
            break
    return rates


def fit_series(doses, signal_dn, k):
    """(q electrons >= 0, rates (4,) DN per unit dose) fitted jointly to a flat series."""
    t, mu = _check_series(doses, signal_dn)
    rates = linear_rates(t, mu)
    q0 = max(float(mu.min()) / k * 0.05, 1.0)

    def residuals(p):
        return ((mean_response(p[1:][None, :] * t[:, None], p[0], k) - mu) / mu).ravel()

    fit = optimize.least_squares(residuals, np.concatenate([[q0], rates]), bounds=(np.r_[0.0, rates * 0.5], np.r_[np.inf, rates * 2.0]),
                                 x_scale=np.concatenate([[q0], rates]))
    return float(fit.x[0]), fit.x[1:]


def estimate(frames, synthesized, k: float, series=None, **_) -> dict:
    """Trap capacity at gain ``k`` from the flat series a flat stack belongs to (``series.doses``
    (n,), ``series.signal_dn`` (n, 4)). Every stack of one series gives the same record."""
    if series is None:
        raise ValueError("Trap needs flats at >= 3 doses (time x relative light): a flat series")
    q, _ = fit_series(series.doses, series.signal_dn, k)
    return {"k": [float(k)], "trap_e": [q]}


def combine(records: list[dict]) -> dict:
    """One record per gain (the stacks of one series give the same one)."""
    return combine_first(records, "trap_e")


def empty(params) -> bool:
    """True when no trap holds an electron: it would add nothing."""
    return all_zero(params, ("trap_e",))


def trap_at(profile, k: float) -> float:
    """The profile's trap capacity (electrons) at gain ``k``; 0 without ``Trap``."""
    params = profile.effects.get("Trap")
    if not params:
        return 0.0
    return float(value_at_k(params, "trap_e", torch.tensor([float(k)], dtype=torch.float64))[0])
