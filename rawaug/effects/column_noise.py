"""Column noise (Col): offsets shared by every pixel of a sensor column.

Physics: each column of a CMOS sensor has its own amplifier and ADC; their offsets add
a fixed column pattern (the same in every frame) and a temporal part (new in every
frame). Packed channels (R, G2) share one sensor column, (G1, B) the other.

A column amplifier's 1/f noise makes the temporal part of consecutive frames alike: over a
sequence it wanders (an AR(1) of correlation ``rho`` from frame to frame), so that a stack's
mean keeps more of it than 1/N and a column may seem to sit at two levels. A single frame
is the same either way.

Synthesis: ``fixed_dn * c_fixed[col] + sigma_dn * c_frame[col]`` with standard-normal
``c_fixed`` drawn once from ``seed`` (fixed pattern) and ``c_frame`` drawn per frame; with
``fixed={"sequence": 1}`` and ``rho`` > 0, ``c_frame`` of the batch's frames 0, 1, ... is the
AR(1) ``c_0 = z_0``, ``c_b = rho c_{b-1} + sqrt(1 - rho^2) z_b`` (the loop synthesizes a
measured stack so).

Profile entry (per-K records, nearest record in log K)::

    Col: {seed: 7, k: [K, ...], sigma_dn: [temporal std, ...], fixed_dn: [fixed std, ...],
          rho: [frame-to-frame correlation, ...]}  # rho optional (0)

Detected by the statistics ``col_excess`` (per-frame column-mean variance over what
independent pixels give) and ``fixed_col_excess`` (the same on the stack mean), see
``rawaug.statistics``.
Estimated by ``estimate``: the excess of those two statistics over the current model.
With a single frame the fixed and temporal parts cannot be told apart; all of the
excess is then recorded as temporal (``sigma_dn``). With 3 frames or more, ``rho`` from the
ratio of the excess column variance of successive frames' differences to that about the
stack mean (2 for new offsets in every frame; ``frame_correlation``), kept where it stands
``RHO_Z`` standard errors (from ``RHO_GROUPS`` groups of columns) above 0.
"""
from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import brentq

from ..engine import layout as L
from ..statistics import difference_scale, line_mean_variance
from .base import BANDING, NoiseEffect, pattern_key, register
from .k_records import check_seed, merge_records, validate_records, value_at_k

STATISTICS = ("col_excess", "fixed_col_excess")
AMPLITUDES = ("sigma_dn", "fixed_dn")  # corrected by simulation under a clip (rawaug.loop.clip_correction)
SHARES_READ_NOISE_UNDER_CLIP = True  # the censored read-noise fit took the pattern's spread (rawaug.loop.frames_loop)


@register
class ColumnNoise(NoiseEffect):
    token = "Col"
    order = BANDING
    flag = L.COL
    columns = ("col_sigma", "col_fixed", "col_rho")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        sequence = "rho" in p and float(ctx.fixed.get("sequence", 0))
        return {"col_sigma": value_at_k(p, "sigma_dn", ctx.k), "col_fixed": value_at_k(p, "fixed_dn", ctx.k),
                "col_rho": value_at_k(p, "rho", ctx.k) if sequence else torch.zeros_like(ctx.k)}

    def pattern_streams(self):
        return {"col_pattern": pattern_key(self.profile.effects[self.token]["seed"], self.token)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn", "fixed_dn"), nonnegative=("sigma_dn", "fixed_dn"))
        check_seed(cls.token, params)
        if "rho" in params:
            validate_records(cls.token, params, ("rho",), nonnegative=("rho",))
            bad = [r for r in params["rho"] if not float(r) < 1.0]
            if bad:
                raise ValueError(f"effect 'Col': every rho must be in [0, 1) (a correlation between consecutive frames), got {bad}")


RHO_GROUPS = 8  # groups of columns whose estimates of rho give its standard error
RHO_Z = 4.0  # standard errors rho must stand above 0
RHO_MAX = 0.95


def frame_sums(frames) -> np.ndarray:
    """(RHO_GROUPS, 2) per group of packed columns: the column-mean variance (as
    ``line_mean_variance``: from neighbouring columns' differences) summed over the frames of
    their deviation from the stack mean, and of their successive differences, DN^2, averaged
    over channels."""
    means = np.asarray(frames, dtype=np.float64).mean(axis=2)  # (N, 4, w): one pass over the stack
    dev, step = means - means.mean(axis=0), np.diff(means, axis=0)
    var = lambda c: float((difference_scale(np.diff(c, axis=-1)) ** 2 / 2.0).mean(axis=-1).sum())  # noqa: E731
    return np.array([(var(dev[..., cols]), var(step[..., cols]))
                     for cols in np.array_split(np.arange(means.shape[2]), RHO_GROUPS)])


def spread_factor(n: int, rho: float) -> float:
    """``black_drift.spread_factor`` (imported when called: importing it here would register
    ``BlackDrift`` before the effects listed ahead of it, and reorder the loop's candidates)."""
    from .black_drift import spread_factor as factor

    return factor(n, rho)


def correlation_of(ss: float, ssd: float, n: int) -> float:
    """rho of an AR(1) over n frames whose sums about the mean and of successive differences
    are in the ratio ssd / ss (2 (n - 1) (1 - rho) / spread_factor(n, rho); 2 at rho 0)."""
    if ss <= 0:
        return 0.0
    ratio = ssd / ss
    f = lambda rho: 2.0 * (n - 1) * (1.0 - rho) / spread_factor(n, rho) - ratio  # noqa: E731
    if f(0.0) <= 0:
        return 0.0
    if f(RHO_MAX) >= 0:
        return RHO_MAX
    return float(brentq(f, 0.0, RHO_MAX))


def frame_correlation(frames, synthesized) -> float:
    """rho of the column offsets' excess over the model's from frame to frame (0 where it does
    not stand RHO_Z standard errors above 0, or with fewer than 3 frames)."""
    n = np.asarray(frames).shape[0]
    if n < 3 or not synthesized:
        return 0.0
    excess = frame_sums(frames) - np.mean([frame_sums(s) for s in synthesized], axis=0)
    rho = correlation_of(*excess.sum(axis=0), n)
    groups = np.array([correlation_of(ss, ssd, n) for ss, ssd in excess])
    se = groups.std(ddof=1) / np.sqrt(len(groups))
    return rho if rho > RHO_Z * se else 0.0


def _column_parts(frames):
    """(temporal variance, fixed variance) of column means, DN^2, averaged over channels,
    from neighbouring-column differences (smooth shading does not count)."""
    mean_map = frames.mean(axis=0)
    fixed_var = float(line_mean_variance(mean_map, 1).mean())
    if frames.shape[0] < 2:
        return float(line_mean_variance(frames, 2).mean()), 0.0
    n = frames.shape[0]
    temporal_var = float(line_mean_variance(frames - mean_map[None], 2).mean()) * n / (n - 1)
    # the fixed part of a stack mean still holds temporal / N
    return temporal_var, fixed_var


def estimate(frames, synthesized, k: float, seed: int = 7, **_) -> dict:
    """Column-noise record at gain ``k`` from measured frames (N, 4, h, w), DN.

    ``synthesized`` is a list of stacks of the same shape from the current model; the
    column variance it already explains is subtracted. With N = 1 everything is temporal.
    """
    frames = np.asarray(frames, dtype=np.float64)
    t_meas, f_meas = _column_parts(frames)
    base = [_column_parts(np.asarray(s, dtype=np.float64)) for s in synthesized]
    t_base = float(np.mean([b[0] for b in base]))
    f_base = float(np.mean([b[1] for b in base]))
    n = frames.shape[0]
    if n < 2:
        return {"seed": int(seed), "k": [float(k)], "sigma_dn": [float(np.sqrt(max(t_meas - t_base, 0.0)))], "fixed_dn": [0.0]}
    sigma2 = max(t_meas - t_base, 0.0)
    rho = frame_correlation(frames, synthesized)
    kept = 1.0 / n  # the share of the temporal variance a stack mean keeps
    if rho > 0:  # the frames' deviations from their mean hold spread_factor / (n - 1) of an AR(1)'s variance
        sigma2 = sigma2 * (n - 1) / spread_factor(n, rho)
        i = np.arange(n)
        kept = float(np.sum(rho ** np.abs(i[:, None] - i[None, :]))) / n**2
    # stack-mean column variance = fixed^2 + what it keeps of the temporal column variance
    fixed2 = max(f_meas - f_base - sigma2 * kept, 0.0)
    out = {"seed": int(seed), "k": [float(k)], "sigma_dn": [float(np.sqrt(sigma2))], "fixed_dn": [float(np.sqrt(fixed2))]}
    return out | ({"rho": [rho]} if rho > 0 else {})


def combine(records: list[dict]) -> dict:
    """The stacks' records as one entry (``merge_records``); where any stack's columns wander
    from frame to frame, ``rho`` for every record (0 where a stack showed none)."""
    if any("rho" in r for r in records):
        records = [{**r, "rho": r.get("rho", [0.0])} for r in records]
    return merge_records(records)
