"""Heavy-tailed row noise (RowTail): the row noise of each frame has heavier tails than a
Gaussian's, at the same variance.

Physics: the ELD model draws row noise (one offset per sensor row and frame, ``R``) from a
Gaussian. A row's offset is the noise of the reference and the column-parallel circuits
sampled while the row is read; where that noise comes in bursts (a switching supply, a
telegraph-like source in the reference, interference that is on for some rows only), most
rows read a small offset and a few a large one. The row means then have a kurtosis above 3,
which a Gaussian of any width does not give.

Stage (DN, in ``R``): the row's standard normal draw ``z`` becomes
``z exp(h z^2 / 2) (1 - 2h)^(3/4)`` (Tukey's h transform, scaled back to unit variance), so
``sigma_r`` stays the rows' standard deviation; ``h = 0`` is the Gaussian.

Profile entry (per-K records)::

    RowTail: {k: [K, ...], h: [...]}

Detected on bias and dark stacks by ``row_tail_mass`` (the share of temporal row means beyond
4 robust sigmas; rows of their own, telegraph or noisy, left out). Estimated by ``estimate``:
h whose simulated row means (``tail_model``: the stack's row variance and pixel noise, the
transform, the statistic's own steps) exceed the Gaussian's tail share by as much as the
stack's (on the frames with their defect lines in place: a row burst is not a defect line)
exceeds the model's syntheses'; ``combine`` averages a gain's stacks.
"""
from __future__ import annotations

import numpy as np
from scipy import optimize

from ..engine import layout as L
from ..statistics import steady_rows, tail_share, temporal_row_means, without_outliers
from .base import READ, NoiseEffect, register
from .k_records import all_zero, combine_mean, validate_records, value_at_k

STATISTICS = ("row_tail_mass",)
RAW_FRAMES = True  # the frames with their defect lines in place (``without_outliers`` only), as ``row_tail_mass`` reads them
MAX_H = 0.2  # the transform's fourth moment is finite for h < 1/4


@register
class RowTail(NoiseEffect):
    token = "RowTail"
    order = READ + 3
    flag = L.ROW_TAIL
    columns = ("row_h",)

    def draw(self, ctx):
        return {"row_h": value_at_k(self.profile.effects[self.token], "h", ctx.k)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("h",), nonnegative=("h",))
        for v in params["h"]:
            if float(v) > MAX_H:
                raise ValueError(f"effect {cls.token!r}: h must be <= {MAX_H} (a finite kurtosis), got {v}")


def excess_kurtosis(h):
    """Excess kurtosis of ``z exp(h z^2 / 2)``, z standard normal (0 <= h < 1/4)."""
    h = np.asarray(h, dtype=np.float64)
    return 3.0 * (1.0 - 2.0 * h) ** 3 / (1.0 - 4.0 * h) ** 2.5 - 3.0


SIM_ROWS = 50_000  # simulated rows per frame in the estimator's tail-share model


def tail_model(h: float, n: int, row_var: float, pixel_var: float, seed: int = 0) -> float:
    """``row_tail_mass`` of simulated temporal row means: ``SIM_ROWS`` rows of ``n`` frames, each
    row's offset ``sqrt(row_var)`` times the transform of a standard normal, the rows' pixel
    noise Gaussian of ``pixel_var`` (DN^2, in the temporal residual), taken through the
    statistic's own steps (``steady_rows``, ``tail_share``)."""
    z = np.random.default_rng(seed).standard_normal((2, n, SIM_ROWS))
    x = np.sqrt(row_var) * z[0] * np.exp(0.5 * h * z[0] ** 2) * (1.0 - 2.0 * h) ** 0.75
    rm = x - x.mean(axis=0) + np.sqrt(pixel_var) * z[1]
    return tail_share(steady_rows(rm))


def estimate(frames, synthesized, k: float, kind=None, seed: int = 0, **_) -> dict:
    """RowTail record at gain ``k`` from a bias or dark stack (N >= 2, 4, h, w; DN; its defect
    lines in place) against the model's ``synthesized`` stacks of it: h whose ``tail_model``
    rises above the Gaussian's by as much as the stack's ``row_tail_mass`` exceeds the
    syntheses' (the rows' variance and the pixel noise's share from the stack itself)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 2:
        raise ValueError("RowTail is measured on bias or dark stacks of >= 2 frames")
    f = without_outliers(frames)
    n, _, _, w = f.shape
    rm = temporal_row_means(f)
    resid = f - f.mean(axis=0)
    pixel_var = float(np.mean((resid - resid.mean(axis=3, keepdims=True)) ** 2)) / (2 * w)  # a row mean's share
    row_var = max((float(np.mean(rm**2)) - pixel_var) * n / (n - 1), 1e-30)
    base = float(np.mean([tail_share(temporal_row_means(without_outliers(np.asarray(s, dtype=np.float64))))
                          for s in synthesized])) if synthesized else tail_model(0.0, n, row_var, pixel_var, seed)
    target = tail_share(rm) - base + tail_model(0.0, n, row_var, pixel_var, seed)

    def short(h):
        return tail_model(h, n, row_var, pixel_var, seed) - target

    if short(0.0) >= 0.0:
        return {"k": [float(k)], "h": [0.0]}
    if short(MAX_H) <= 0.0:
        return {"k": [float(k)], "h": [MAX_H]}
    return {"k": [float(k)], "h": [float(optimize.brentq(short, 0.0, MAX_H, xtol=1e-4))]}


def combine(records: list[dict]) -> dict:
    """One h per gain: its stacks' averaged."""
    return combine_mean(records, "h")


def empty(params) -> bool:
    """True when every h is 0: Gaussian rows, nothing added."""
    return all_zero(params, ("h",))
