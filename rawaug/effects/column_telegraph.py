"""Column telegraph noise (ColRTS): a few sensor columns jump between two levels from frame to
frame.

Physics: a trap in a column amplifier's or column ADC's input transistor captures and
releases a carrier at random (random telegraph signal), so the whole column reads one of two
offsets, a new state in every frame. ``RTS`` is the same physics in a pixel's source
follower; ``Col`` is Gaussian column noise in every column.

Stage (DN, after read noise): in the sensor columns where a seeded U(0, 1) pattern falls
below ``density``, ``s -> s + step`` in the frames where the frame's U(0, 1) for the column
falls below ``high`` (the share of frames in the high state; the trap filled), with a
log-normal step ``median_dn(K) * exp(log_std * z)`` seeded by the column.

Profile entry::

    ColRTS: {seed: 79, density: 0.03, high: 0.5, log_std: 0.3, k: [K, ...], median_dn: [...]}

Detected on bias and dark stacks of >= 4 frames by ``col_flicker_fraction`` (sensor columns
whose frame means, less the column's mean and the frame's, have two states: ``two_state``
with the pixels' threshold; on the frames with their defect lines, as a column far off in
some frames is one of theirs) and ``defect_lines``. Estimated by ``estimate``: the two-state
columns (over all stacks: the columns seen in any, less the model's, over the chance that a
column shows two states in at least one: ``detection_probability``); their steps; the share
of high frames by maximum likelihood from the detected columns' counts
(``share_of_high_frames``). Steps near the column noise are seen less
often: density and median are those of the detectable population.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import flickering_columns
from .base import READ, NoiseEffect, pattern_key, register
from .k_records import _number, check_density, check_seed, validate_records, value_at_k

STATISTICS = ("col_flicker_fraction", "col_excess", "defect_lines")  # a column far off in a frame is that frame's defect line
RAW_FRAMES = True  # the defect-line repair would replace a column in the frames where it stands out


@register
class ColumnTelegraph(NoiseEffect):
    token = "ColRTS"
    order = READ + 7
    flag = L.COL_RTS
    columns = ("crts_density", "crts_median", "crts_log_std", "crts_high")
    lines = "sensor columns"  # what its density is a fraction of

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        n = ctx.k.shape[0]
        return {"crts_density": ctx.k.new_full((n,), float(p["density"])), "crts_median": value_at_k(p, "median_dn", ctx.k),
                "crts_log_std": ctx.k.new_full((n,), float(p["log_std"])), "crts_high": ctx.k.new_full((n,), float(p["high"]))}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"crts_where": pattern_key(seed, self.token, "where"), "crts_size": pattern_key(seed, self.token, "size")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("median_dn",), nonnegative=("median_dn",))
        check_seed(cls.token, params)
        check_density(cls.token, params, of=cls.lines)
        high = _number(params.get("high"), f"{cls.token}.high")
        if not 0.0 < high < 1.0:
            raise ValueError(f"effect {cls.token!r}: high (share of frames in the high state) must be in (0, 1), got {high}")
        if _number(params.get("log_std"), f"{cls.token}.log_std") < 0:
            raise ValueError(f"effect {cls.token!r}: log_std must be >= 0, got {params.get('log_std')}")


def estimate(frames, synthesized, k: float, kind=None, seed: int = 79, **_) -> dict:
    """ColRTS record at gain ``k`` from a bias or dark stack (N >= 4, 4, h, w) in DN, against
    stacks of the same shape synthesized by the model (``combine`` of this stack alone; what it
    saw is kept under ``"_seen"`` for ``combine`` over stacks)."""
    return line_estimate("ColRTS", flickering_columns, frames, synthesized, k, kind, seed)


def line_estimate(token, flickering, frames, synthesized, k, kind, seed) -> dict:
    """A telegraph-line record (``ColRTS``, ``RowRTS``) at gain ``k`` from a bias or dark stack
    (N >= 4, 4, h, w; DN), its two-state lines by ``flickering`` (mask, steps, shares), against
    the model's ``synthesized`` stacks."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 4:
        raise ValueError(f"{token} is measured on bias or dark stacks of >= 4 frames")
    seen, step, share = flickering(frames)
    base = float(np.mean([flickering(s)[0].mean() for s in synthesized])) if synthesized else 0.0
    n = frames.shape[0]
    record = {"seed": int(seed), "k": [float(k)], "_seen": {"n_frames": n, "detected": max(float(seen.mean()) - base, 0.0),
                                                            "false": base, "columns": np.flatnonzero(seen).tolist(), "width": int(seen.size),
                                                            "high_counts": np.rint(share * n).astype(int).tolist(),
                                                            "log_steps": np.log(np.maximum(step, 1e-6)).tolist()}}
    return {**combine([record]), "_seen": record["_seen"]}


def detection_probability(high: float, n: int) -> float:
    """Probability that a telegraph column (its step well above the column noise) in the high
    state with probability ``high`` shows two states in ``n`` >= 4 frames: at least 2 frames in
    each (``two_state``)."""
    return float(stats.binom.cdf(n - 2, n, high) - stats.binom.cdf(1, n, high))


def share_of_high_frames(counts_by_n: list[tuple[int, list[int]]]) -> float:
    """Maximum-likelihood share of high frames from the detected columns' counts of high frames
    (``[(n frames, [count, ...]), ...]``), each count binomial given 2 <= count <= n - 2 (what
    ``two_state`` detects); 1/2 where they say nothing (4 frames: every detected column has 2)."""
    grid = np.linspace(0.02, 0.98, 481)
    loglik = np.zeros_like(grid)
    for n, counts in counts_by_n:
        if counts:
            c = np.asarray(counts)[:, None]
            loglik += (stats.binom.logpmf(c, n, grid[None, :]) - np.log([detection_probability(h, n) for h in grid])[None, :]).sum(axis=0)
    if np.ptp(loglik) < 0.5:  # flat: no information on the share
        return 0.5
    return float(grid[np.argmax(loglik)])


def combine(records: list[dict]) -> dict:
    """One population (the same columns at every gain and exposure): the share of high frames
    by maximum likelihood over every stack's detected columns; the density from the columns
    seen in any stack (less the model's chance detections) over the chance that a column
    shows in at least one; the log spreads pooled; the step
    per gain. Stacks that found none count for the density only."""
    seen = [r["_seen"] for r in records]
    high = share_of_high_frames([(s["n_frames"], s["high_counts"]) for s in seen if s["detected"] > 0])
    # the same columns in every stack of the sensor's width: those seen in any, over the chance
    # that a telegraph column shows two states in at least one
    width = max((s["width"] for s in seen), key=lambda w: sum(t["width"] == w for t in seen))
    same = [s for s in seen if s["width"] == width]
    union = len(set().union(*(s["columns"] for s in same))) / width - sum(s["false"] for s in same)
    missed = float(np.prod([1.0 - detection_probability(high, s["n_frames"]) for s in same]))
    density = max(union, 0.0) / (1.0 - missed) if any(s["detected"] > 0 for s in same) else 0.0
    found = [(r["k"][0], s["log_steps"]) for r, s in zip(records, seen) if s["detected"] > 0 and s["log_steps"]]
    if density == 0.0 or not found:
        return {"seed": records[0]["seed"], "density": 0.0, "high": 0.5, "log_std": 0.0, "k": [records[0]["k"][0]], "median_dn": [0.0]}
    by_k: dict = {}
    for k, logs in found:
        by_k.setdefault(k, []).extend(logs)
    spreads = [np.var(logs, ddof=1) for _, logs in found if len(logs) > 1]
    ks = sorted(by_k)
    return {"seed": records[0]["seed"], "density": min(density, 0.1), "high": high,
            "log_std": float(math.sqrt(np.mean(spreads))) if spreads else 0.0,
            "k": ks, "median_dn": [float(math.exp(np.mean(by_k[k]))) for k in ks]}


def empty(params) -> bool:
    """True when no column is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
