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
over the ISOs, the noise per gain). Where the pixels' log temporal variances spread wider
than the model's (interquartile range, ``SPREAD_REL`` and ``SPREAD_Z`` standard errors
beyond), every pixel: the share of the variance and the log spread whose variances, through
the syntheses' own sampling of a pixel's variance, give the measured quantiles
(``spread_fit``); judged with the base read noise re-fitted (calibration's holds their mean).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import pixel_variances, trimmed_variances
from .base import DARK, NoiseEffect, pattern_key, register
from .k_records import _number, check_density, check_seed, validate_records, value_at_k

STATISTICS = ("noisy_fraction", "flicker_fraction")
SIMULATED = 20_000  # noisy pixels simulated (the same ones at every point of the grid)
SHARES_READ_NOISE = True  # with every pixel noisy, calibration's read noise holds their mean extra variance
SPREAD_REL = 0.05  # every pixel its own noise: the log variances' interquartile range this much above the model's ...
SPREAD_Z = 6.0  # ... and this many standard errors (the model's, over its syntheses) out
SPREAD_SAMPLE = 100_000  # pixels of the quantile fit (measured and simulated)


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


def _log_iqr(var) -> float:
    q1, q3 = np.percentile(np.log(np.maximum(var, 1e-12)), [25.0, 75.0])
    return float(q3 - q1)


def spread_fit(var, model_vars, seed: int = 0) -> tuple[float, float, float]:
    """(mean variance V, share f of it that is the pixels' own, log spread s) of pixel variances
    ``var`` (DN^2; N frames each) as ``V g r``: ``g = (1 - f) + f exp(2 s z - 2 s^2)`` a pixel's
    variance over the mean (z standard normal), ``r`` a pixel's sampling ratio, from the
    model's syntheses ``model_vars`` (their pixels' variances over their mean: the read noise's
    own shape). Least squares on the log quantiles from 2 % to 98 % over a grid of (f, s),
    log V the mean difference."""
    rng = np.random.default_rng(seed)
    p = np.linspace(0.02, 0.98, 49)
    q = np.quantile(np.log(np.maximum(var, 1e-12)), p)
    pool = np.concatenate([np.asarray(v, dtype=np.float64) / max(float(np.mean(v)), 1e-12) for v in model_vars])
    log_r = np.log(np.maximum(rng.choice(pool, SPREAD_SAMPLE), 1e-12))
    z = rng.standard_normal(SPREAD_SAMPLE)
    def cost(f, s):
        sim = np.quantile(np.log((1.0 - f) + f * np.exp(2.0 * s * z - 2.0 * s * s)) + log_r, p)
        c = float(np.mean(q - sim))
        return float(np.sum((q - sim - c) ** 2)), math.exp(c), float(f), float(s)

    best = min(cost(f, s) for s in np.linspace(0.05, 1.5, 30) for f in np.linspace(0.05, 1.0, 20))
    _, _, f0, s0 = best  # refined 5-fold about the best
    fine = [cost(f, s) for s in s0 + np.linspace(-0.05, 0.05, 11) if s > 0.0
            for f in f0 + np.linspace(-0.05, 0.05, 11) if 0.0 < f <= 1.0]
    _, mean_var, share, log_std = min([best] + fine)
    return mean_var, share, log_std


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
    model_vars = [pixel_variances(s)[0] for s in synthesized]
    model_iqr = [_log_iqr(v) for v in model_vars]
    spread_se = float(np.std(model_iqr, ddof=1)) if len(model_iqr) > 1 else 0.0
    if (_log_iqr(var) > (1.0 + SPREAD_REL) * float(np.mean(model_iqr))
            and _log_iqr(var) - float(np.mean(model_iqr)) > SPREAD_Z * max(spread_se, 1e-12)):
        mean_var, share, log_std = spread_fit(var, model_vars, seed)
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
