"""Black-level drift (BlackDrift): the black level wanders over a sequence of frames, so that
consecutive frames are offset alike, in all four channels together.

Physics: the black-level clamp or the ADC reference follows the sensor's temperature and
supply, which change slowly against the frame rate. Each frame's offset is then close to the
last one's: an AR(1) (discrete Ornstein-Uhlenbeck) process over the frames,
``b_n = rho b_{n-1} + sqrt(1 - rho^2) sigma e_n``. ``BLE`` is the case ``rho = 0``; a drift
makes the frame means of a long stack wander further about their mean than a short stack's,
and makes neighbouring frames alike (a lag-1 autocorrelation of the frame means). The
IMX686's per-frame bias fits in the README show 0.66 at ISO 100.

Synthesis: one offset per frame, ``b_n`` in DN, added to every channel. With
``fixed={"sequence": 1}`` the batch's samples are consecutive frames and the offsets walk
across them (the loop synthesizes a measured stack so); otherwise every sample is an
independent shot, with an offset drawn from the process's stationary law N(0, sigma^2).

Profile entry (per-K records; ``rho`` in [0, 1))::

    BlackDrift: {k: [K, ...], sigma_dn: [...], rho: [...]}

Detected by ``frame_mean_common_cov``, ``frame_mean_std`` and ``frame_mean_lag1``.
Estimated by ``estimate`` (bias and dark stacks) and ``combine``: the common-mode sum of
squares of the frame means about their stack mean and of their successive differences, in
excess of the model's; their ratio gives ``rho`` (one for the camera, pooled over every
stack: a clamp's time constant does not depend on the gain), their level ``sigma`` per K.
Only where the frames show a drift (``drift_lr``); else ``rho`` is 0, which is ``BLE``'s, and
the loop does not try it (``empty``).
"""
from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import brentq, minimize_scalar

from ..engine import layout as L
from .base import OFFSET, NoiseEffect, register
from .k_records import all_zero, validate_records, value_at_k

STATISTICS = ("frame_mean_common_cov", "frame_mean_std", "frame_mean_lag1")


@register
class BlackDrift(NoiseEffect):
    token = "BlackDrift"
    order = OFFSET + 2
    flag = L.BLACK_DRIFT
    columns = ("black_drift",)

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        sigma, rho = value_at_k(p, "sigma_dn", ctx.k), value_at_k(p, "rho", ctx.k)
        z = ctx.normal("black_drift")
        if not float(ctx.fixed.get("sequence", 0)):
            return {"black_drift": sigma * z}
        return {"black_drift": ar1(z, sigma, rho)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn", "rho"), nonnegative=("sigma_dn", "rho"))
        bad = [r for r in params["rho"] if not float(r) < 1.0]
        if bad:
            raise ValueError(f"effect 'BlackDrift': every rho must be in [0, 1) (a correlation between consecutive "
                             f"frames), got {bad}")


def common_sums(frame_means) -> tuple[float, float]:
    """(sum of squares about the mean, sum of squared successive differences) of the common
    part of (N, 4) frame means, DN^2: cross-products of channels that share neither a row
    nor a column, (R, B) and (G1, G2), so that each channel's own noise and the row noise
    drop out."""
    m = np.asarray(frame_means, dtype=np.float64)
    c = m - m.mean(axis=0)
    d = np.diff(m, axis=0)
    cross = lambda a: float(np.sum(a[:, 0] * a[:, 2] + a[:, 1] * a[:, 3]) / 2.0)  # noqa: E731
    return cross(c), cross(d)


def ar1(z, sigma, rho):
    """Offsets (DN) of consecutive frames from their standard normals ``z`` (numpy or torch,
    (N,)): ``b_0 = sigma_0 z_0`` (the stationary law), ``b_n = rho_n b_{n-1} + sqrt(1 - rho_n^2)
    sigma_n z_n``; ``sigma`` and ``rho`` scalars or per frame."""
    n = z.shape[0]
    sigma = sigma * (z * 0 + 1)  # per frame, in z's kind of array
    rho = rho * (z * 0 + 1)
    out = z * 0
    out[0] = sigma[0] * z[0]
    for i in range(1, n):
        out[i] = rho[i] * out[i - 1] + (1.0 - rho[i] ** 2) ** 0.5 * sigma[i] * z[i]
    return out


def spread_factor(n: int, rho: float) -> float:
    """E[sum of squares about the mean] / sigma^2 for n frames of a stationary AR(1) of
    lag-1 correlation ``rho``: n - (1/n) sum_{i,j} rho^|i - j|."""
    lags = np.arange(1, n)
    return float(n - (n + 2.0 * np.sum((n - lags) * rho**lags)) / n)


DRIFT_LR = 9.0  # likelihood ratio (2 log) a drift must reach over new offsets in every frame (one-sided z 3: 0.13 % by chance)


def _reml_terms(x, rho: float) -> tuple[float, float, int]:
    """(quadratic form, log-determinant terms, degrees of freedom) of the restricted (REML)
    likelihood of one stack's frame means ``x`` under an AR(1) of lag-1 correlation ``rho``,
    its unknown mean taken out."""
    n = len(x)
    i = np.arange(n)
    inv = np.linalg.inv(rho ** np.abs(i[:, None] - i[None, :]))
    w = inv.sum(axis=1)
    a = float(w.sum())
    quad = float(x @ inv @ x - (w @ x) ** 2 / a)
    return quad, float(np.linalg.slogdet(inv)[1] * -1.0 + np.log(a)), n - 1


def drift_loglik(groups: dict, rho: float) -> float:
    """Restricted log-likelihood of the stacks' frame-mean series (``{K: [series, ...]}``) as
    AR(1)s of one ``rho`` and a spread per K (profiled out)."""
    total = 0.0
    for series in groups.values():
        terms = [_reml_terms(np.asarray(x, dtype=np.float64), rho) for x in series]
        quad, logdet, dof = (sum(t[j] for t in terms) for j in range(3))
        total -= 0.5 * (dof * np.log(max(quad / dof, 1e-300)) + logdet + dof)
    return total


def drift_lr(records: list[dict]) -> float:
    """Likelihood ratio (2 log) of a drift (an AR(1), rho in [0, 0.95]) over new offsets in
    every frame (rho 0), of the stacks' frame means (all channels) in the order taken. Under
    new offsets it is 0 half the time and chi-square(1) else (measured: above ``DRIFT_LR`` in
    0.2 % of 1000 sessions of 4 gains x (8 + 4) frames; a random walk there in 86 %)."""
    groups: dict = {}
    for r in records:
        x = np.asarray(r.get("series", []), dtype=np.float64)
        if x.size >= 3 and np.ptp(x) > 0:
            groups.setdefault(float(r["k"][0]), []).append(x)
    if not groups:
        return 0.0
    best = minimize_scalar(lambda rho: -drift_loglik(groups, rho), bounds=(0.0, 0.95), method="bounded")
    return max(0.0, 2.0 * (-best.fun - drift_loglik(groups, 0.0)))


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """Sums of one bias or dark stack (N >= 2, 4, h, w; DN) in excess of the model's syntheses
    (the mean over them) and its frame means (all channels) in order: ``{k, ss, ssd, n,
    series}``, for ``combine``."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 2 or not synthesized:
        raise ValueError("BlackDrift is measured on bias and dark stacks of >= 2 frames, against their syntheses")
    means = frames.mean(axis=(2, 3))
    ss, ssd = common_sums(means)
    base = np.array([common_sums(np.asarray(s, dtype=np.float64).mean(axis=(2, 3))) for s in synthesized])
    return {"k": [float(k)], "ss": [ss - float(base[:, 0].mean())], "ssd": [ssd - float(base[:, 1].mean())],
            "n": [int(frames.shape[0])], "series": [float(v) for v in means.mean(axis=1)]}


def combine(records: list[dict]) -> dict:
    """``{k, sigma_dn, rho}`` from the stacks' excess sums. ``rho`` is 0 unless the stacks'
    frame means are alike from frame to frame beyond chance (``drift_lr`` > ``DRIFT_LR``;
    records without ``series`` come from a caller that tested it); else where the pooled ratio of the sums
    about the mean to the successive ones equals an AR(1)'s, limited to ``1 - 1 / N`` (N the
    longest stack: a longer correlation is not resolved, and a walk has no stationary
    spread). ``sigma^2`` per K: its stacks' excess sum about the mean over what an AR(1) of
    that ``rho`` gives."""
    ns = [int(r["n"][0]) for r in records]
    drifting = drift_lr(records) > DRIFT_LR or not any("series" in r for r in records)
    ss = np.array([max(float(r["ss"][0]), 0.0) for r in records])
    ssd = np.array([max(float(r["ssd"][0]), 0.0) for r in records])
    rho_max = 1.0 - 1.0 / max(ns)
    expected_ratio = lambda rho: (sum(spread_factor(n, rho) for n in ns)  # noqa: E731
                                  / sum(2.0 * (1.0 - rho) * (n - 1) for n in ns))
    pooled = ss.sum() / ssd.sum() if ssd.sum() > 0 else np.inf
    if not drifting or pooled <= expected_ratio(0.0):
        rho = 0.0  # no drift shown: new offsets in every frame are BLE's
    elif pooled >= expected_ratio(rho_max):
        rho = rho_max
    else:
        rho = float(brentq(lambda r: expected_ratio(r) - pooled, 0.0, rho_max, xtol=1e-6))
    by_k: dict = {}
    for r, n, s in zip(records, ns, ss):
        acc = by_k.setdefault(float(r["k"][0]), [0.0, 0.0])
        acc[0] += s
        acc[1] += spread_factor(n, rho)
    ks = sorted(by_k)
    return {"k": ks, "sigma_dn": [float(np.sqrt(by_k[k][0] / by_k[k][1])) for k in ks], "rho": [rho] * len(ks)}


def empty(params) -> bool:
    """True when every spread is 0, or rho is (the frames show no drift: offsets new in every
    frame are ``BLE``'s, which the loop tries instead)."""
    return all_zero(params, ("sigma_dn",)) or all_zero(params, ("rho",))
