"""Noisy pixels (Noisy): a sparse, fixed set of pixels with extra temporal noise, Gaussian and
new in every frame.

Physics: a pixel whose source follower has a large 1/f noise (many oxide traps, none of them
dominant), or a leaky one whose leakage fluctuates, reads with a temporal noise several times
the sensor's. Unlike a telegraph pixel (``RTS``) its values are unimodal; unlike a hot pixel
(``Hot``, ``DarkHot``) its stack mean is not offset. The ELD read noise is the same at every
pixel, and ``ReadMap`` varies it by blocks, not by pixel.

Stage (DN, with the read noise): ``s -> s + median_dn * exp(log_std * z) * n`` at the pixels
where a seeded U(0, 1) pattern falls below ``density``, ``z`` a seeded standard normal of the
pixel (both fixed: the sensor's), ``n`` a standard normal new in every frame. Density 1: every
pixel its own read noise (a source follower's trap population differs from pixel to pixel:
a log-normal spread of the read noise, not a sparse population).

Profile entry (the noise in DN per gain: one record per calibrated K)::

    Noisy: {seed: 83, density: 0.005, log_std: 0.3, k: [K, ...], median_dn: [...]}

Detected by ``noisy_fraction`` (pixels of bias and dark stacks of >= 4 frames whose temporal
variance a white pixel exceeds with probability 1e-6, with and without their most extreme
value, and that show no two states: a heavy read-noise tail's single extreme values and
telegraph pixels do not count) and ``flicker_fraction`` (noisy pixels whose values happen to
split in two groups). Estimated by ``estimate`` on bias stacks: the upper tail of the pixels'
temporal variances without their most extreme value as the model's syntheses plus a
population of noisy pixels made from the syntheses' own pixels (``combine``: one population
over the ISOs, the noise per gain). Where a pixel's variance in the first half of the
frames and in the second vary together over the pixels beyond the model's (``half_spread``:
the covariance of their logs, ``SPREAD_Z`` standard errors out, over all pixels and over
the bulk, where sparse noisy pixels add none; a heavy read-noise tail is new in every frame
and gives none), every pixel: the share of the variance and the log
spread whose variance of log and relative variance are those covariances (``spread_fit``);
judged with the base read noise re-fitted (calibration's holds their mean).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import median, pixel_variances, temporal_moments, trimmed_variances
from .base import DARK, NoiseEffect, pattern_key, register
from .k_records import _number, check_density, check_seed, validate_records, value_at_k

STATISTICS = ("noisy_fraction", "flicker_fraction")
SIMULATED = 20_000  # noisy pixels simulated (the same ones at every point of the grid)
SHARES_READ_NOISE = True  # with every pixel noisy, calibration's read noise holds their mean extra variance
SPREAD_Z = 6.0  # every pixel its own noise: the halves' log-variance covariance this many standard errors above the model's ...
SPREAD_MIN = 0.01  # ... and this much (a spread of the pixels' variance of ~0.1 in log)
SPREAD_TRIM = 25.0  # pixels whose variance in a half passes this many times the median (telegraph, hot) left out
BULK = 0.8  # the bulk of the pixels: below this quantile of one half's log variances
_NODES, _WEIGHTS = np.polynomial.hermite_e.hermegauss(61)  # standard normal quadrature
_WEIGHTS = _WEIGHTS / _WEIGHTS.sum()


@register
class NoisyPixels(NoiseEffect):
    token = "Noisy"
    order = DARK
    flag = L.NOISY
    columns = ("noisy_density", "noisy_median", "noisy_log_std")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        n = ctx.k.shape[0]
        return {"noisy_density": ctx.k.new_full((n,), float(p["density"])), "noisy_median": value_at_k(p, "median_dn", ctx.k),
                "noisy_log_std": ctx.k.new_full((n,), float(p["log_std"]))}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"noisy_where": pattern_key(seed, self.token, "where"), "noisy_size": pattern_key(seed, self.token, "size")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("median_dn",), nonnegative=("median_dn",))
        check_seed(cls.token, params)
        check_density(cls.token, params, most=1.0)
        if _number(params.get("log_std"), "Noisy.log_std") < 0:
            raise ValueError(f"effect 'Noisy': log_std must be >= 0, got {params.get('log_std')}")


EDGES = np.geomspace(3.0, 300.0, 21)  # bins of trimmed temporal variance over the stack's median: the upper tail
COARSE_LOG_SIGMA = np.arange(-0.5, 3.51, 0.25)  # log(extra noise / read noise) tried, then refined 4-fold:
# below 0.6 x the read noise a pixel's extra noise is not resolved in a stack
MIN_GAIN = 9.0  # the fit's chi-square gain over no noisy pixels: 3 sigma, or none is found
COARSE_LOG_STD = np.arange(0.0, 1.21, 0.3)  # ... and the log-normal spread, refined 3-fold


def _tail_counts(values, median_var):
    """Counts of the rows of ``values`` (M, N) whose ``trimmed_variances`` fall in each bin of
    ``EDGES`` (x ``median_var``) and above the last."""
    trimmed = trimmed_variances(values)
    return np.bincount(np.searchsorted(EDGES * median_var, trimmed, side="right"), minlength=EDGES.size + 1)[1:]


def _pixels(frames):
    """A stack (N, 4, h, w) as rows of pixels (4 h w, N)."""
    frames = np.asarray(frames, dtype=np.float64)
    return frames.reshape(frames.shape[0], -1).T


def half_spread(frames) -> tuple[float, float, float, float, float, float]:
    """(covariance of log variance, relative covariance of variance, mean variance (DN^2), the
    log covariance's standard error, the bulk's log covariance, its standard error) of each
    pixel's temporal variance in the first half of a stack's frames and in the second (N >= 4),
    over the pixels neither of whose halves passes ``SPREAD_TRIM`` x the median. A pixel's own
    noise level is in both halves; the sampling of a variance, whatever the noise's shape, is
    new in each: the covariances are the spread of the pixels' true variances alone (0 for a
    sensor of one noise). The bulk: the pixels below ``BULK`` of one half's log variances (each
    half in turn; the other half is not selected on), where a sparse population of noisy or
    telegraph pixels adds nothing and a spread of every pixel's noise still shows."""
    frames = np.asarray(frames, dtype=np.float64)
    half = frames.shape[0] // 2
    va = temporal_moments(frames[:half])[1].ravel()
    vb = temporal_moments(frames[half:2 * half])[1].ravel()
    med = max(float(median(0.5 * (va + vb))), 1e-12)
    keep = (va > 0.0) & (vb > 0.0) & (va < SPREAD_TRIM * med) & (vb < SPREAD_TRIM * med)
    va, vb = va[keep], vb[keep]
    la, lb = np.log(va), np.log(vb)
    c_log = float(np.mean((la - la.mean()) * (lb - lb.mean())))
    mean = float(0.5 * (va.mean() + vb.mean()))
    c_lin = float(np.mean((va - va.mean()) * (vb - vb.mean()))) / mean**2
    se = math.sqrt(float(la.var() * lb.var()) / max(la.size, 1))
    bulk, bulk_var = [], []
    for x, y in ((la, lb), (lb, la)):
        k = x < np.percentile(x, 100.0 * BULK)
        bulk.append(float(np.mean((x[k] - x[k].mean()) * (y[k] - y[k].mean()))))
        bulk_var.append(float(x[k].var() * y[k].var()) / max(int(k.sum()), 1))
    return c_log, c_lin, mean, se, float(np.mean(bulk)), math.sqrt(float(np.mean(bulk_var)))


def spread_fit(c_log: float, c_lin: float) -> tuple[float, float]:
    """(share f of the mean variance that is the pixels' own, log spread s) whose pixel variances
    ``(1 - f) + f exp(2 s z - 2 s^2)`` (of mean 1, z standard normal) have variance of log
    ``c_log`` and variance ``c_lin``: least squares in relative error on a grid, refined."""
    def cost(f, s):
        g = np.log((1.0 - f) + f * np.exp(2.0 * s * _NODES - 2.0 * s * s))
        var_log = float(_WEIGHTS @ g**2 - (_WEIGHTS @ g) ** 2)
        var_lin = f * f * math.expm1(4.0 * s * s)
        return (var_log / c_log - 1.0) ** 2 + (var_lin / max(c_lin, 1e-12) - 1.0) ** 2, float(f), float(s)

    best = min(cost(f, s) for f in np.linspace(0.05, 1.0, 20) for s in np.linspace(0.05, 1.5, 30))
    _, f0, s0 = best
    fine = [cost(f, s) for f in f0 + np.linspace(-0.05, 0.05, 11) if 0.0 < f <= 1.0
            for s in s0 + np.linspace(-0.05, 0.05, 11) if s > 0.0]
    _, share, log_std = min([best] + fine)
    return share, log_std


def estimate(frames, synthesized, k: float, seed: int = 83, kind: str = "bias", **_) -> dict:
    """Noisy-pixel parameters at gain ``k`` from a bias stack (N >= 4, 4, h, w) in DN.

    The upper tail of the pixels' temporal variances without their most extreme value (3 to
    300 x the stack's median variance, in log bins: ``noisy_fraction``'s measure) is the
    model's (its syntheses of this stack: read noise, every added effect) plus a population of
    noisy pixels: pixels of the syntheses with the extra noise ``sigma_r * exp(m + s z)``
    added, so that the read noise keeps its shape. (m, s) on a grid, refined once about the
    best; the density by least squares at each, weighted by the counts' Poisson variance;
    none unless the fit beats no noisy pixels by ``MIN_GAIN`` in chi-square."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "bias" or frames.shape[0] < 4:
        raise ValueError("Noisy is measured on bias stacks of >= 4 frames")
    none = {"seed": int(seed), "density": 0.0, "log_std": 0.0, "k": [float(k)], "median_dn": [0.0]}
    if len(synthesized) == 0:
        return none
    n = frames.shape[0]
    var, median_var = pixel_variances(frames)
    c_log, c_lin, mean_var, se, c_bulk, se_bulk = half_spread(frames)
    model = np.array([[h[0], h[1], h[4]] for h in map(half_spread, synthesized)])
    excess_log, excess_lin = c_log - float(model[:, 0].mean()), c_lin - float(model[:, 1].mean())
    # the excess's standard error: the stack's own and that of the syntheses' mean
    spread_se = math.hypot(se, (float(model[:, 0].std(ddof=1)) if len(model) > 1 else se) / math.sqrt(len(model)))
    bulk_se = math.hypot(se_bulk, (float(model[:, 2].std(ddof=1)) if len(model) > 1 else se_bulk) / math.sqrt(len(model)))
    if (excess_log > max(SPREAD_Z * spread_se, SPREAD_MIN) and excess_lin > 0.0
            and c_bulk - float(model[:, 2].mean()) > SPREAD_Z * bulk_se):
        share, log_std = spread_fit(excess_log, excess_lin)
        return {"seed": int(seed), "density": 1.0, "log_std": log_std, "k": [float(k)],
                "median_dn": [math.sqrt(mean_var * share) * math.exp(-log_std**2)]}  # E exp(2 s z) = exp(2 s^2)
    measured = _tail_counts(_pixels(frames), median_var).astype(np.float64)
    base = np.mean([_tail_counts(_pixels(s), median_var) for s in synthesized], axis=0)
    if measured.sum() <= base.sum():
        return none
    # read-noise series of the model's pixels, the normals of the extra noise and its log-normal
    # scores: the same at every point of the grid
    rng = np.random.default_rng(seed)
    which = rng.integers(0, len(synthesized), SIMULATED)
    where = rng.integers(0, var.size, SIMULATED)
    series = np.empty((SIMULATED, n))
    for i, s in enumerate(synthesized):
        series[which == i] = np.asarray(s).reshape(n, -1)[:, where[which == i]].T
    normals = rng.standard_normal((SIMULATED, n))
    z = rng.standard_normal(SIMULATED)
    sigma_r = math.sqrt(median_var * (n - 1) / stats.chi2.median(n - 1))
    weight = 1.0 / np.maximum(measured + base, 2.0)  # Poisson variance of the difference
    y = measured - base

    def fit(m, log_std):
        sigma = sigma_r * np.exp(m + log_std * z)
        share = _tail_counts(series + sigma[:, None] * normals, median_var) / SIMULATED  # of a noisy pixel, per bin
        x = var.size * share - base  # a noisy pixel moves the base's tail to its own
        d = float(np.clip(np.sum(weight * x * y) / max(float(np.sum(weight * x * x)), 1e-12), 0.0, 0.1))
        return float(np.sum(weight * (y - d * x) ** 2)), d, m, log_std

    best = min(fit(m, s) for s in COARSE_LOG_STD for m in COARSE_LOG_SIGMA)
    _, _, m0, s0 = best
    fine = [fit(m0 + dm, s0 + ds) for ds in (-0.2, -0.1, 0.0, 0.1, 0.2) if s0 + ds >= 0.0
            for dm in np.arange(-0.25, 0.26, 0.0625)]
    cost, d, m, log_std = min([best] + fine)
    if d == 0.0 or float(np.sum(weight * y * y)) - cost < MIN_GAIN:
        return none
    return {"seed": int(seed), "density": d, "log_std": float(log_std), "k": [float(k)],
            "median_dn": [float(sigma_r * math.exp(m))]}


def combine(records: list[dict]) -> dict:
    """One population from the bias stacks: density and log spread the medians over the stacks
    that found any (a stack whose read noise hides the pixels finds few, and guesses), the noise
    per gain the geometric mean of those stacks at that K; every pixel (density 1) where a stack
    showed the pixels' spread (one whose read noise hides it sees only the tail, as sparse
    pixels)."""
    spread = [r for r in records if float(r["density"]) == 1.0]
    seen = spread or [r for r in records if r["density"] > 0]
    if not seen:
        return {**records[0], "k": [float(records[0]["k"][0])], "median_dn": [0.0]}
    by_k: dict = {}
    for r in seen:
        by_k.setdefault(float(r["k"][0]), []).append(r["median_dn"][0])
    ks = sorted(by_k)
    return {"seed": seen[0]["seed"], "density": float(np.median([r["density"] for r in seen])),
            "log_std": float(np.median([r["log_std"] for r in seen])), "k": ks,
            "median_dn": [float(np.exp(np.mean(np.log(by_k[k])))) for k in ks]}


def empty(params) -> bool:
    """True when no pixel is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
