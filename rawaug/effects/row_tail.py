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
the fourth cumulant of the stack's temporal row means (on the frames with their defect lines
in place: a row burst is not a defect line) beyond the model's syntheses', over the square of
their variance (the pixel noise's share taken out), is the rows' excess kurtosis, and h is
the transform's that gives it (``excess_kurtosis``); ``combine`` averages a gain's stacks.
"""
from __future__ import annotations

import numpy as np
from scipy import optimize

from ..engine import layout as L
from ..statistics import temporal_row_means, without_outliers
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


def _cumulants(frames):
    """(variance less the pixel noise's share, fourth cumulant) of the rows' own offsets, DN^2
    and DN^4, from a stack's temporal row means (``temporal_row_means``). A frame less the mean
    of N holds (N - 1) / N of a row's variance and (1 - 1/N)^4 + (N - 1) / N^4 of its fourth
    cumulant (the other frames' shares): both are scaled back."""
    f = without_outliers(np.asarray(frames, dtype=np.float64))
    rm = temporal_row_means(f)
    n, _, _, w = f.shape
    v = float(np.mean(rm**2))
    k4 = (float(np.mean(rm**4)) - 3.0 * v * v) / ((1.0 - 1.0 / n) ** 4 + (n - 1) / n**4)
    resid = f - f.mean(axis=0)
    pix = float(np.mean((resid - resid.mean(axis=3, keepdims=True)) ** 2))  # per pixel, in the residual
    return max((v - pix / (2 * w)) * n / (n - 1), 1e-30), k4


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """RowTail record at gain ``k`` from a bias or dark stack (N >= 2, 4, h, w; DN) against the
    model's ``synthesized`` stacks of it: h whose excess kurtosis is the rows' fourth cumulant
    beyond the syntheses', over their variance squared."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 2:
        raise ValueError("RowTail is measured on bias or dark stacks of >= 2 frames")
    var, k4 = _cumulants(frames)
    base = np.mean([_cumulants(s)[1] for s in synthesized]) if synthesized else 0.0
    target = (k4 - base) / var**2
    if not target > 0.0:
        return {"k": [float(k)], "h": [0.0]}
    if target >= excess_kurtosis(MAX_H):
        return {"k": [float(k)], "h": [MAX_H]}
    return {"k": [float(k)], "h": [float(optimize.brentq(lambda h: excess_kurtosis(h) - target, 0.0, MAX_H))]}


def combine(records: list[dict]) -> dict:
    """One h per gain: its stacks' averaged."""
    return combine_mean(records, "h")


def empty(params) -> bool:
    """True when every h is 0: Gaussian rows, nothing added."""
    return all_zero(params, ("h",))
