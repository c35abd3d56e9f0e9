"""Noisy columns (NoisyCol): a few sensor columns whose pixels all read with extra temporal
noise, Gaussian and new at every pixel and frame.

Physics: in a column-parallel readout every column has its own amplifier and ADC (comparator,
sample-and-hold); one with a noisy input transistor or a marginal comparator adds its own
white noise to each pixel it converts. The noise is the column's, so all its pixels show it,
but it is drawn anew at each conversion, so the column mean does not flicker and its offset
is fixed (``Col`` is an offset of the whole column in each frame, ``ColRTS`` a step of it,
``Noisy`` the same extra noise at single pixels, ``ReadMap`` by blocks of columns).

Stage (DN, with the read noise): ``s -> s + median_dn * exp(log_std * z) * n`` in the sensor
columns where a seeded U(0, 1) pattern falls below ``density`` (``z`` a seeded standard normal
of the column, both keyed by the sensor column), ``n`` a standard normal new at every pixel and
frame.

Profile entry (the noise in DN per gain: one record per calibrated K)::

    NoisyCol: {seed: 101, density: 0.01, log_std: 0.2, k: [K, ...], median_dn: [...]}

Detected by ``noisy_col_fraction`` (sensor columns whose pixels' median temporal variance,
with each frame's column mean taken out, stands 6 robust sigmas above the median column's)
and ``read_noise_spread`` (the column blocks' noise), and by the pixel statistics its pixels
raise (``noisy_fraction``, ``flicker_fraction``: the pixels of a noisy column are noisy
pixels, one column at a time). Estimated by ``estimate`` on bias stacks
of >= 4 frames: the noisy columns beyond the model's, each one's extra noise from its
excess variance (columns whose noise is lost in the spread are not seen: density and median
are those of the detectable population). Where every column has a noise of its own (the
columns' pixel noise spread ``SPREAD_FACTOR`` times the model's, by interquartile range, and
standing ``SPREAD_Z`` standard errors out: column amplifiers of unequal noise), the extra
noise is in every column (density 1), its median and log spread fitted to the quantiles of
the columns' noise (``spread_fit``); judged with the base read noise re-fitted, which
calibration gave the columns' mean extra variance.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import column_pixel_noise, median, noisy_of
from .base import DARK, NoiseEffect, pattern_key, register
from .k_records import _number, check_density, check_seed, validate_records, value_at_k
from .noisy_pixels import combine as combine_sparse  # one population over the bias stacks, the noise per gain: Noisy's

STATISTICS = ("noisy_col_fraction", "read_noise_spread", "noisy_fraction", "flicker_fraction")  # its pixels are noisy ones
SHARES_READ_NOISE = True  # with every column noisy, calibration's read noise holds their mean extra variance
SPREAD_FACTOR = 3.0  # columns' noise this many times the model's spread (interquartile range): every column its own
SPREAD_Z = 6.0  # ... standing this many standard errors of the measured range out


@register
class NoisyColumns(NoiseEffect):
    token = "NoisyCol"
    order = DARK
    flag = L.NOISY_COL
    columns = ("ncol_density", "ncol_median", "ncol_log_std")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        n = ctx.k.shape[0]
        return {"ncol_density": ctx.k.new_full((n,), float(p["density"])), "ncol_median": value_at_k(p, "median_dn", ctx.k),
                "ncol_log_std": ctx.k.new_full((n,), float(p["log_std"]))}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"ncol_where": pattern_key(seed, self.token, "where"), "ncol_size": pattern_key(seed, self.token, "size")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("median_dn",), nonnegative=("median_dn",))
        check_seed(cls.token, params)
        check_density(cls.token, params, most=1.0, of="sensor columns")
        if _number(params.get("log_std"), "NoisyCol.log_std") < 0:
            raise ValueError(f"effect 'NoisyCol': log_std must be >= 0, got {params.get('log_std')}")


def _iqr(v) -> float:
    q1, q3 = np.percentile(v, [25.0, 75.0])
    return float(q3 - q1)


def spread_fit(v) -> tuple[float, float, float]:
    """(base variance, median extra std, log spread) of columns' pixel variances ``v`` (DN^2)
    as ``base + m^2 exp(2 s z)``, ``z`` standard normal: least squares on the quantiles from
    2 % to 98 % (for each ``s`` on a grid, ``base`` and ``m^2`` are linear)."""
    p = np.linspace(0.02, 0.98, 49)
    q = np.quantile(np.asarray(v, dtype=np.float64), p)
    z = stats.norm.ppf(p)
    best = (np.inf, 0.0, 0.0, 0.0)
    for s in np.linspace(0.02, 1.5, 149):
        a = np.stack([np.ones_like(z), np.exp(2.0 * s * z)], axis=1)
        (base, m2), *_ = np.linalg.lstsq(a, q, rcond=None)
        if m2 <= 0:
            continue
        err = float(((a @ np.array([base, m2]) - q) ** 2).sum())
        if err < best[0]:
            best = (err, float(base), float(math.sqrt(m2)), float(s))
    return best[1], best[2], best[3]


def estimate(frames, synthesized, k: float, seed: int = 101, kind: str = "bias", **_) -> dict:
    """NoisyCol parameters at gain ``k`` from a bias stack (N >= 4, 4, h, w) in DN: the noisy
    sensor columns (``noisy_columns``) beyond the model's (its ``synthesized`` stacks of this
    stack), each one's extra noise the square root of its excess median variance over the
    median column's, scaled from the median of N - 1 degrees to the variance (a Gaussian
    column's median pixel variance is its variance x chi2.median(N - 1) / (N - 1)); where every
    column has a noise of its own, all of them (``spread_fit``)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "bias" or frames.shape[0] < 4:
        raise ValueError("NoisyCol is measured on bias stacks of >= 4 frames")
    none = {"seed": int(seed), "density": 0.0, "log_std": 0.0, "k": [float(k)], "median_dn": [0.0]}
    n = frames.shape[0]
    scale = (n - 1) / stats.chi2.median(n - 1)
    v = column_pixel_noise(frames)
    synth = [column_pixel_noise(s) for s in synthesized]  # one pass over each synthesized stack
    if synth:
        model = float(np.mean([_iqr(x) for x in synth]))
        se = _iqr(v) * 1.36 / math.sqrt(v.size)  # an interquartile range's standard error, relative (normal)
        if _iqr(v) > SPREAD_FACTOR * model and _iqr(v) - model > SPREAD_Z * se:
            _, m, s = spread_fit(v * scale)
            if m > 0:
                return {"seed": int(seed), "density": 1.0, "log_std": s, "k": [float(k)], "median_dn": [m]}
    noisy, med = noisy_of(v)
    base = float(np.mean([noisy_of(x)[0].mean() for x in synth])) if synth else 0.0
    density = float(noisy.mean()) - base
    if density <= 0.0 or noisy.sum() < 2:
        return none
    extra = np.sqrt(np.maximum(v[noisy] - med, 1e-12) * scale)
    logs = np.log(extra)
    return {"seed": int(seed), "density": min(density, 0.1), "log_std": float(logs.std(ddof=1)), "k": [float(k)],
            "median_dn": [float(math.exp(float(median(logs))))]}


def combine(records: list[dict]) -> dict:
    """Every column with a noise of its own where a stack showed it (density 1; a stack whose
    read noise hides the columns' spread sees only its tail, as sparse columns): the log spread
    the median over those stacks, the noise per gain their geometric mean at that K; else one
    sparse population (``noisy_pixels.combine``)."""
    spread = [r for r in records if float(r["density"]) == 1.0]
    if not spread:
        return combine_sparse(records)
    by_k: dict = {}
    for r in spread:
        by_k.setdefault(float(r["k"][0]), []).append(r["median_dn"][0])
    ks = sorted(by_k)
    return {"seed": spread[0]["seed"], "density": 1.0, "log_std": float(np.median([r["log_std"] for r in spread])), "k": ks,
            "median_dn": [float(np.exp(np.mean(np.log(by_k[k])))) for k in ks]}


def empty(params) -> bool:
    """True when no column is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
