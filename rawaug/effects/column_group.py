"""Column groups (ColGroup): groups of adjacent sensor columns that share an offset, new in every
frame.

Physics: column-parallel ADCs are built in groups that share a ramp, a reference buffer or a
bias line; that shared node's noise moves every column of the group together in each frame.
Unlike ``Col`` (each column's own offset) or ``TapBlack`` (a few readout taps' black levels), the
groups are many and narrow (a few to tens of columns), and their offsets are new in every frame.

Stage (DN): in frame ``b``, sensor column ``X`` adds ``sigma_dn(K) * z[b, (X + width - start) //
width]``, ``z`` a standard normal per frame and group (groups of ``width`` columns, one starting
at column ``start`` < ``width``).

Profile entry (per-K records)::

    ColGroup: {width: 16, start: 0, k: [K, ...], sigma_dn: [...]}

Detected on bias and dark stacks of >= 3 frames by ``col_neighbour_corr`` (neighbouring sensor
columns' temporal parts move together) and ``col_excess``. Estimated by ``estimate``: the
covariance of the columns' temporal parts at lag 1 less the model's, kept where it stands ``Z``
standard errors above 0; the width (2 .. ``MAX_WIDTH``) and start of the groups whose offsets
fit the temporal parts best, by the likelihood of a normal offset per group and frame beside
each column's own noise (two variances, whatever the width); the offset's variance, the
groups' means' less what the columns' own noise gives them.
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import col_lag_covariances, temporal_col_deviations
from .base import BANDING, NoiseEffect, register
from .k_records import _number, combine_sigma, validate_records, value_at_k

STATISTICS = ("col_neighbour_corr", "col_excess")
MAX_WIDTH = 64  # the widest group looked for (sensor columns)
Z = 5.0  # standard errors of the lag-1 covariance a group's excess must reach


@register
class ColumnGroups(NoiseEffect):
    token = "ColGroup"
    order = BANDING
    flag = L.COL_GROUP
    columns = ("cgroup_sigma", "cgroup_width", "cgroup_start")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {"cgroup_sigma": value_at_k(p, "sigma_dn", ctx.k), "cgroup_width": ctx.k.new_full(ctx.k.shape, float(p["width"])),
                "cgroup_start": ctx.k.new_full(ctx.k.shape, float(p.get("start", 0)))}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("sigma_dn",), nonnegative=("sigma_dn",))
        width = _number(params.get("width"), f"{cls.token}.width")
        if width != int(width) or not 1 <= width <= 1 << 20:
            raise ValueError(f"effect {cls.token!r}: width (sensor columns per group) must be a whole number >= 1, got {width}")
        start = _number(params.get("start", 0), f"{cls.token}.start")
        if start != int(start) or not 0 <= start < width:
            raise ValueError(f"effect {cls.token!r}: start (first group's first sensor column) must be a whole number in [0, width), got {start}")


def _group_loglik(cs, cs2, n: int, width: int, start: int):
    """(log-likelihood, variance of the groups' offsets, columns' own variance) of the columns'
    temporal parts (cumulative sums ``cs``, ``cs2`` over ``n`` columns, per frame) as groups of
    ``width`` columns from ``start``, each with a normal offset per frame (a random effect, two
    variances, not a parameter per group: with many narrow groups a parameter per group and
    frame costs more than a strong grouping gains); the variances fitted on the full groups."""
    edges = np.unique(np.r_[0, np.arange(start, n, width), n])
    sums, m = cs[:, edges[1:]] - cs[:, edges[:-1]], np.diff(edges).astype(np.float64)
    within = cs2[:, edges[1:]] - cs2[:, edges[:-1]] - sums**2 / m  # (N, groups) sum of squares about each group's mean
    full = m == width
    frames = cs.shape[0]
    own = max(float(within[:, full].sum()) / (frames * full.sum() * (width - 1)), 1e-30)
    tau = max(float(np.mean(sums[:, full] ** 2 / width)), own)  # own + width x the offsets' variance
    var = (tau - own) / width
    total = own + m * var  # each group's mean times its size: variance own + m var, per column
    loglik = -0.5 * float(np.sum((m - 1) * np.log(own) + within / own + np.log(total) + sums**2 / (m * total)))
    return loglik, var, own


def group_fit(d: np.ndarray) -> tuple[int, int, float]:
    """(width, start, variance DN^2) of the groups of adjacent columns whose per-frame offsets
    fit the columns' temporal parts ``d`` (N, n) best: every width 2 .. ``MAX_WIDTH`` and
    start < width, by the likelihood of a normal offset per group and frame beside each
    column's own noise (``_group_loglik``); the variance, the offsets'."""
    n_frames, n = d.shape
    zero = np.zeros((n_frames, 1))
    cs, cs2 = np.concatenate([zero, np.cumsum(d, axis=1)], axis=1), np.concatenate([zero, np.cumsum(d * d, axis=1)], axis=1)
    best = None
    for width in range(2, min(MAX_WIDTH, n // 2) + 1):
        for start in range(width):
            loglik, var, _ = _group_loglik(cs, cs2, n, width, start)
            if best is None or loglik > best[0]:
                best = (loglik, width, start, var)
    _, width, start, var = best
    return width, start, max(var, 0.0)


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """ColGroup record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w; DN) against the
    model's syntheses of it."""
    frames = np.asarray(frames, dtype=np.float64)
    n = frames.shape[0]
    if kind not in ("bias", "dark") or n < 3:
        raise ValueError("ColGroup is measured on bias or dark stacks of >= 3 frames")
    measured = col_lag_covariances(frames, 1)
    model = np.mean([col_lag_covariances(np.asarray(s, dtype=np.float64), 1) for s in synthesized], axis=0) if synthesized else 0.0
    se = measured[0] / np.sqrt(n * 2 * frames.shape[3])  # a mean of products of two values of variance c0
    record = {"width": 1, "start": 0, "k": [float(k)], "sigma_dn": [0.0]}
    if not measured[1] - model[1] > Z * se:
        return record
    width, start, var = group_fit(temporal_col_deviations(frames))
    return {"width": int(width), "start": int(start), "k": [float(k)], "sigma_dn": [float(np.sqrt(var * n / (n - 1)))]}  # the stack's mean took 1/N


def combine(records: list[dict]) -> dict:
    """The groups' width and start: the most common among the stacks that found groups; the
    offset per gain, the rms over those stacks."""
    found = [r for r in records if r["sigma_dn"][0] > 0]
    if not found:
        return {"width": 1, "start": 0, "k": [float(records[0]["k"][0])], "sigma_dn": [0.0]}
    layouts = [(r["width"], r["start"]) for r in found]
    width, start = max(set(layouts), key=lambda w: (layouts.count(w), -w[0], -w[1]))
    return {"width": int(width), "start": int(start), **combine_sigma(found)}


def empty(params) -> bool:
    """True when the groups add nothing (no offset, or groups of one column: ``Col``'s)."""
    return int(params["width"]) <= 1 or not any(float(s) > 0 for s in params["sigma_dn"])
