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
are those of the detectable population).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import column_pixel_noise, median, noisy_columns
from .base import DARK, NoiseEffect, pattern_key, register
from .k_records import _number, check_density, check_seed, validate_records, value_at_k
from .noisy_pixels import combine  # noqa: F401  (one population over the bias stacks, the noise per gain: Noisy's)

STATISTICS = ("noisy_col_fraction", "read_noise_spread", "noisy_fraction", "flicker_fraction")  # its pixels are noisy ones


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
        check_density(cls.token, params, of="sensor columns")
        if _number(params.get("log_std"), "NoisyCol.log_std") < 0:
            raise ValueError(f"effect 'NoisyCol': log_std must be >= 0, got {params.get('log_std')}")


def estimate(frames, synthesized, k: float, seed: int = 101, kind: str = "bias", **_) -> dict:
    """NoisyCol parameters at gain ``k`` from a bias stack (N >= 4, 4, h, w) in DN: the noisy
    sensor columns (``noisy_columns``) beyond the model's (its ``synthesized`` stacks of this
    stack), each one's extra noise the square root of its excess median variance over the
    median column's, scaled from the median of N - 1 degrees to the variance (a Gaussian
    column's median pixel variance is its variance x chi2.median(N - 1) / (N - 1))."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "bias" or frames.shape[0] < 4:
        raise ValueError("NoisyCol is measured on bias stacks of >= 4 frames")
    none = {"seed": int(seed), "density": 0.0, "log_std": 0.0, "k": [float(k)], "median_dn": [0.0]}
    noisy, med = noisy_columns(frames)
    base = float(np.mean([noisy_columns(s)[0].mean() for s in synthesized])) if len(synthesized) else 0.0
    density = float(noisy.mean()) - base
    if density <= 0.0 or noisy.sum() < 2:
        return none
    n = frames.shape[0]
    scale = (n - 1) / stats.chi2.median(n - 1)
    extra = np.sqrt(np.maximum(column_pixel_noise(frames)[noisy] - med, 1e-12) * scale)
    logs = np.log(extra)
    return {"seed": int(seed), "density": min(density, 0.1), "log_std": float(logs.std(ddof=1)), "k": [float(k)],
            "median_dn": [float(math.exp(float(median(logs))))]}


def empty(params) -> bool:
    """True when no column is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
