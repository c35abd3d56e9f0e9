"""ADC differential non-linearity (DNL): the analog-to-digital converter's codes are not equally
wide, in a pattern that repeats every few codes.

Physics: an ADC decides a code by comparing its input with decision levels; in a real
converter (a ramp's counter, a successive-approximation's capacitor array, a pipeline's
stages) those levels are off their ideal places by a fraction of a code, the same way at the
same carries, so some codes take more of the input than their neighbours and a histogram of
a smooth input shows a periodic pattern of wide and narrow codes. (A code of width 0, a
missing code, is ``CodeMap``'s comb; this effect is the case where every code is written.)

Stage (DN, after every offset, as the ADC): code ``c`` takes the inputs in
``[c - 1/2 + e[c mod P], c + 1/2 + e[(c + 1) mod P])``, ``e`` the decision levels' offsets
(|e| < 1, mean 0: a uniform input keeps its mean), so code ``j`` of a period is
``1 + e[j + 1] - e[j]`` wide. The output is that whole code.

Profile entry (one for the camera: the converter's, at every gain)::

    DNL: {period: 8, threshold_dn: [e_0, ..., e_7]}

Detected by ``code_dnl`` (the codes' log counts about a local quartic of their neighbours',
over the well-filled codes of a stack of whole codes). Estimated by ``estimate`` and
``combine``: each stack's log count ratio, measured over the model's syntheses, per
well-filled code; one periodic pattern of log widths fitted to every stack at once beside a
quartic of its own per stack (the model's shape errors are smooth), its period the one of
2 .. ``PERIOD_MAX`` codes with the least BIC; the widths give the decision levels.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..engine import layout as L
from ..statistics import DNL_MIN_COUNT, code_counts, well_filled
from .base import CLIP, NoiseEffect, register

STATISTICS = ("code_dnl",)
PERIOD_MAX = L.DNL_PERIOD_MAX
NUISANCE_DEGREE = 4  # each stack's smooth log ratio (a wrong read-noise scale makes it a parabola)


@register
class AdcDnl(NoiseEffect):
    token = "DNL"
    order = CLIP - 6  # the ADC: after every offset, before the code map
    flag = L.ADC_DNL
    columns = ("dnl_period", *(f"dnl_e{i}" for i in range(PERIOD_MAX)))

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        ones = torch.ones(ctx.batch, dtype=torch.float64, device=ctx.device)
        out = {"dnl_period": ones * float(p["period"])}
        for i, e in enumerate(p["threshold_dn"]):
            out[f"dnl_e{i}"] = ones * float(e)
        return out

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r}")
        unknown = set(params) - {"period", "threshold_dn"}
        if unknown:
            raise ValueError(f"effect {cls.token!r}: unknown keys {sorted(unknown)} (expected period, threshold_dn)")
        period = params.get("period")
        if isinstance(period, bool) or not isinstance(period, (int, float)) or period != int(period) \
                or not 1 <= period <= PERIOD_MAX:
            raise ValueError(f"effect {cls.token!r}: period must be a whole number of codes in [1, {PERIOD_MAX}], got {period!r}")
        e = params.get("threshold_dn")
        arr = np.asarray(e, dtype=np.float64) if isinstance(e, (list, tuple)) else None
        if arr is None or arr.shape != (int(period),) or not np.all(np.isfinite(arr)) or np.any(np.abs(arr) >= 1.0):
            raise ValueError(f"effect {cls.token!r}: threshold_dn must hold {int(period)} decision-level offsets in (-1, 1) "
                             f"(DN, one per code of the period), got {e!r:.80}")
        widths = 1.0 + np.roll(arr, -1) - arr
        if np.any(widths < 0.0):
            raise ValueError(f"effect {cls.token!r}: threshold_dn gives codes of negative width {widths.round(3).tolist()} "
                             "(each e[j + 1] - e[j] must be >= -1)")


def decision_offsets(widths) -> np.ndarray:
    """Decision-level offsets ``e`` (mean 0) of a period of code ``widths`` (mean 1):
    ``e[j + 1] = e[j] + widths[j] - 1``."""
    w = np.asarray(widths, dtype=np.float64)
    e = np.concatenate([[0.0], np.cumsum(w - 1.0)[:-1]])
    return e - e.mean()


def estimate(frames, synthesized, k: float, **_) -> dict:
    """One stack's log count ratio, measured over the mean of the model's syntheses, at each
    code both fill (``well_filled`` on the measured histogram), with its inverse variance and
    the slope of the model's log count there (a decision level's shift moves a code's cell
    along the density): ``{codes, log_ratio, weight, slope}`` for ``combine``."""
    measured = code_counts(frames)
    model = [code_counts(s) for s in synthesized]
    if measured is None or not model or any(m is None for m in model):
        raise ValueError("DNL is measured on stacks of whole codes, against their syntheses")
    codes, counts = measured
    run = well_filled(counts)
    if run is None:
        raise ValueError("DNL needs a histogram of at least DNL_MIN_CODES well-filled codes")
    codes, counts = codes[run], counts[run].astype(np.float64)
    lo = min(int(codes[0]), *(int(c[0]) for c, _ in model)) - 1
    hi = max(int(codes[-1]), *(int(c[-1]) for c, _ in model)) + 1
    mean = np.zeros(hi - lo + 1)
    for c, n in model:
        mean[c - lo] += n
    mean /= len(model)
    log_m = np.log(np.maximum(mean, 0.5 / len(model)))
    at = codes - lo
    slope = (log_m[at + 1] - log_m[at - 1]) / 2.0
    ok = mean[at] * len(model) >= DNL_MIN_COUNT
    return {"codes": codes[ok].tolist(), "log_ratio": np.log(counts[ok] / mean[at][ok]).tolist(),
            "weight": (1.0 / (1.0 / counts[ok] + 1.0 / (mean[at][ok] * len(model)))).tolist(), "slope": slope[ok].tolist()}


def _design(records):
    """Per record: (codes, normalized codes' powers (n, NUISANCE_DEGREE + 1), log ratios,
    square-root weights, slopes)."""
    out = []
    for rec in records:
        c = np.asarray(rec["codes"], dtype=np.int64)
        x = (c - c.mean()) / max(float(np.ptp(c)) / 2.0, 1.0)
        out.append((c, x[:, None] ** np.arange(NUISANCE_DEGREE + 1), np.asarray(rec["log_ratio"], dtype=np.float64),
                    np.sqrt(np.asarray(rec["weight"], dtype=np.float64)), np.asarray(rec.get("slope", np.zeros(c.size)))))
    return out


def code_log_ratio(e, codes, slope) -> np.ndarray:
    """Log of the count of each code with decision-level offsets ``e`` (period len(e)) over
    an ideal code's, under a density of log slope ``slope`` there: its width and the shift
    of its cell's centre."""
    period = len(e)
    lo, hi = e[codes % period], e[(codes + 1) % period]
    return np.log(np.maximum(1.0 + hi - lo, 1e-6)) + slope * (lo + hi) / 2.0


def _fit(design, period: int):
    """(chi-square, offsets e (period,), mean 0) of one periodic pattern of decision levels
    and a quartic per record, weighted least squares (``code_log_ratio``; linear start)."""
    from scipy.optimize import least_squares

    n_rec, width = len(design), NUISANCE_DEGREE + 1

    def residuals(theta):
        free = theta[n_rec * width:]
        e = np.concatenate([free, [-free.sum()]]) if period > 1 else np.zeros(1)
        parts = []
        for r, (c, powers, y, w, slope) in enumerate(design):
            parts.append((powers @ theta[r * width:(r + 1) * width] + code_log_ratio(e, c, slope) - y) * w)
        return np.concatenate(parts)

    theta = np.zeros(n_rec * width + period - 1)
    for r, (_, powers, y, w, _) in enumerate(design):  # each record's smooth part alone first
        theta[r * width:(r + 1) * width] = np.linalg.lstsq(powers * w[:, None], y * w, rcond=None)[0]
    if period > 1:
        theta = least_squares(residuals, theta, method="lm", x_scale="jac").x
    chi2 = float(np.sum(residuals(theta) ** 2))
    free = theta[n_rec * width:]
    return chi2, np.concatenate([free, [-free.sum()]]) if period > 1 else np.zeros(1)


def combine(records: list[dict]) -> dict:
    """``{period, threshold_dn}`` for the camera: the period of least BIC (chi-square + its
    pattern's parameters x log of the codes) and its decision levels, shrunk if need be to
    |e| < 1 and no negative width (a missing code is ``CodeMap``'s)."""
    records = [r for r in records if len(r["codes"]) > NUISANCE_DEGREE + 2]
    if not records:
        return {"period": 1, "threshold_dn": [0.0]}
    design = _design(records)
    n = sum(len(r["codes"]) for r in records)
    longest = max(len(r["codes"]) for r in records)
    best = (_fit(design, 1)[0], 1, np.zeros(1))
    for period in range(2, min(PERIOD_MAX, longest // 2) + 1):
        chi2, e = _fit(design, period)
        score = chi2 + (period - 1) * math.log(n)
        if score < best[0]:
            best = (score, period, e)
    _, period, e = best
    e = e - e.mean()
    scale = 1.0
    while scale > 0 and (np.any(np.abs(scale * e) >= 0.99) or np.any(1.0 + np.roll(scale * e, -1) - scale * e < 0.0)):
        scale -= 0.05
    return {"period": int(period), "threshold_dn": [float(v) for v in max(scale, 0.0) * e]}


def empty(params) -> bool:
    """True when every decision level is in place: every code equally wide."""
    return not np.any(np.asarray(params["threshold_dn"], dtype=np.float64))
