"""Column gain non-uniformity (ColGain): each sensor column's amplifier has its own gain, fixed
and from frame to frame.

Physics: a column-parallel readout amplifies (and converts) every column through circuits of
its own, whose gains differ by a fraction of a per cent (fixed); where a column's gain rests on
a bias or a reference of its own that settles anew for every frame, it also moves from frame to
frame. The photo signal and its shot noise are multiplied by the column's gain: vertical
stripes that grow in proportion to the signal, invisible in bias frames. A column amplifier
with a programmable gain switches capacitors of its own at each analog gain, so its mismatch
may differ from ISO to ISO (none at unity gain, some at the highest). EMVA 1288 (Release 4)
splits PRNU into this column part, a row part and the pixel part (``PRNU``); ``Col`` is the
column offsets, the same at every signal; ``RowGain`` the same along the rows.

Stage (DN, after shot noise and ``NonLin``, before read noise): ``s -> s (1 + sigma g[X] +
frame z[b, X])`` with ``g`` a seeded standard normal per sensor column ``X`` (both channels of
the column), the same in every frame, and ``z`` one per sensor column and frame; ``sigma`` and
``frame`` one value for every ISO, or one per record of gain ``k`` (the record nearest the
frame's K), the pattern ``g`` the same.

Profile entry::  ``ColGain: {seed: 67, sigma: 0.005, frame: 0.002}``  (fractions of the signal;
``frame`` optional, 0 by default), or per gain
``ColGain: {seed: 67, k: [0.75, 3.0], sigma: [0.0, 0.008], frame: [0.0, 0.0]}``

Detected by ``fixed_col_excess`` (the stack mean's column means vary more than pixels alone
make them) and ``col_excess`` (each frame's, less the stack mean) on flat stacks. Estimated by
``estimate``: the variance of the column means relative to the level (``line_mean_variance``:
from neighbouring columns, so a smooth illumination does not count) in excess of the model's,
of the frames less their stack mean (the per-frame part) and of the stack mean (the fixed part,
less what the per-frame part leaves in a mean of N frames), as ``RowGain``'s along the rows;
``combine``: per gain. Bias and dark frames cannot show it.
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import line_rel_parts
from .base import PHOTON, NoiseEffect, pattern_key, register
from .k_records import _number, check_gain_pattern, check_seed, validate_records, value_at_k

STATISTICS = ("fixed_col_excess", "col_excess")
KEYS = ("sigma", "frame")


@register
class ColumnGain(NoiseEffect):
    token = "ColGain"
    order = PHOTON + 30  # after shot noise (its column's amplifier), before read noise
    flag = L.COL_GAIN
    columns = ("colgain_sigma", "colgain_frame")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        if "k" in p:
            return {col: value_at_k(p, key, ctx.k) if key in p else ctx.k.new_zeros((ctx.k.shape[0],))
                    for col, key in zip(self.columns, KEYS)}
        return {col: ctx.k.new_full((ctx.k.shape[0],), float(p.get(key, 0.0))) for col, key in zip(self.columns, KEYS)}

    def pattern_streams(self):
        return {"colgain_pattern": pattern_key(self.profile.effects[self.token]["seed"], self.token)}

    @classmethod
    def validate_params(cls, params):
        if isinstance(params, dict) and "k" in params:  # one record per gain
            validate_records(cls.token, params, tuple(key for key in KEYS if key in params or key == "sigma"))
            check_seed(cls.token, params)
            for key in KEYS:
                for value in params.get(key, []):
                    check_gain_pattern(cls.token, {"seed": params["seed"], key: value}, (key,))
            return
        if isinstance(params, dict):
            _number(params.get("sigma"), f"{cls.token}.sigma")  # required
        check_gain_pattern(cls.token, params, KEYS)


def column_rel_parts(frames, level_dn) -> tuple[float, float]:
    """(per-frame, stack-mean) relative variance of the sensor-column means (``line_rel_parts``)."""
    return line_rel_parts(frames, level_dn, rows=False)


def estimate(frames, synthesized, k: float, level_dn=None, seed: int = 67, **_) -> dict:
    """ColGain from a flat stack (N, 4, h, w) in DN at clean level ``level_dn`` (DN, scalar or
    per channel), against stacks of the same shape synthesized by the current model."""
    frames = np.asarray(frames, dtype=np.float64)
    if level_dn is None or not synthesized:
        raise ValueError("ColGain needs a flat stack with its clean level level_dn (DN), against syntheses")
    n = frames.shape[0]
    t_meas, f_meas = column_rel_parts(frames, level_dn)
    base = [column_rel_parts(s, level_dn) for s in synthesized]
    frame2 = max(t_meas - float(np.mean([b[0] for b in base])), 0.0) if n >= 2 else 0.0
    # a stack mean's column variance holds the fixed part and a 1/N share of the per-frame part
    fixed2 = max(f_meas - float(np.mean([b[1] for b in base])) - frame2 / n, 0.0)
    weight = float(np.mean(np.broadcast_to(np.asarray(level_dn, dtype=np.float64), (4,)))) ** 2
    return {"seed": int(seed), "k": [float(k)], "sigma": float(np.sqrt(fixed2)), "frame": float(np.sqrt(frame2)),
            "weight": weight}


def combine(records: list[dict]) -> dict:
    """One gain pattern from the flat stacks (the same columns at every ISO and level), its
    spreads per gain: the stacks of each K's variances averaged with weights ``level^2`` (the
    relative variance of a brighter flat is the sharper); records without a K: one spread."""
    def pooled(group):
        w = np.array([r.get("weight", 1.0) for r in group], dtype=np.float64)
        w = w / w.sum()
        return {key: float(np.sqrt(np.sum(w * np.array([r.get(key, 0.0) ** 2 for r in group])))) for key in KEYS}

    if not all("k" in r for r in records):
        return {"seed": records[0]["seed"], **pooled(records)}
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    ks = sorted(by_k)
    per_k = [pooled(by_k[k]) for k in ks]
    return {"seed": records[0]["seed"], "k": ks, **{key: [p[key] for p in per_k] for key in KEYS}}


def empty(params) -> bool:
    """True when the gains do not vary (both parts 0 at every gain): it would add nothing."""
    return all(float(v) == 0.0 for key in KEYS for v in np.atleast_1d(params.get(key, 0.0)))
