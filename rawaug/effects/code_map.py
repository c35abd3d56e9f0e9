"""Measured code mapping (CodeMap), a measured fallback: the raw codes the camera actually
writes.

Not a named physical effect: digital gain after the ADC, a non-linear or dithered
re-quantization in firmware or a lossy raw compression leave some codes unused (a comb in
the histogram, ``missing_codes``) that no noise stage reproduces. The loop tries this
component only when no physical effect explains the comb; the report lists it as
reproduced by measurement.

Stage (DN, after every offset): ``s -> map[round(s) - lo]``: ``s`` is rounded to a whole
DN and, inside the mapped range ``[lo_dn, lo_dn + n)``, replaced by the code the camera
writes for it; outside it is left rounded.

Profile entry (per-K records)::  ``CodeMap: {k: [K, ...], lo_dn: [...], map_dn: [[c, ...], ...]}``
(``map_dn[i]``: the code written for ``lo_dn + i``, DN relative to black, non-decreasing).

Estimated by ``estimate``, by histogram matching: each whole DN ``r`` the current model
writes goes to the measured code at the model's (mid-)probability of ``r``, so the model's
codes take the measured histogram, comb and mean included.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from .base import CLIP, NoiseEffect, register
from .k_records import record_index, validate_records, value_at_k

STATISTICS = ("missing_codes",)
MEASURED = True


@register
class CodeMap(NoiseEffect):
    token = "CodeMap"
    order = CLIP - 5
    flag = L.CODE_MAP
    columns = ("codemap_record", "codemap_lo", "codemap_n")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        lengths = {"k": p["k"], "n": [float(len(m)) for m in p["map_dn"]]}
        return {"codemap_record": record_index(p, ctx.k).to(torch.float64), "codemap_lo": value_at_k(p, "lo_dn", ctx.k),
                "codemap_n": value_at_k(lengths, "n", ctx.k)}

    def tables(self):
        p = self.profile.effects[self.token]
        luts = [np.asarray(m, dtype=np.float64) for m in p["map_dn"]]
        table = np.zeros((len(luts), max(len(t) for t in luts)))
        for i, t in enumerate(luts):
            table[i, : len(t)] = t
        return {"code_lut": torch.from_numpy(table)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("lo_dn", "map_dn"))
        for i, codes in enumerate(params["map_dn"]):
            arr = np.asarray(codes, dtype=np.float64) if isinstance(codes, (list, tuple)) else None
            if arr is None or arr.ndim != 1 or not 1 <= arr.size <= 65536 or not np.all(np.isfinite(arr)) \
                    or np.any(arr != np.rint(arr)) or np.any(np.diff(arr) < 0):
                raise ValueError(f"effect 'CodeMap': map_dn[{i}] must be 1 to 65536 non-decreasing whole DN, got {codes!r:.80}")
            if params["lo_dn"][i] != np.rint(params["lo_dn"][i]):
                raise ValueError(f"effect 'CodeMap': lo_dn must be whole DN, got {params['lo_dn'][i]}")


def estimate(frames, synthesized, k: float, **_) -> dict:
    """Code map at gain ``k`` from a stack of whole-DN values (N, 4, h, w) and stacks the
    current model synthesized for it (rounded)."""
    v = np.asarray(frames, dtype=np.float64)
    if not np.all(v == np.rint(v)):
        raise ValueError("CodeMap needs frames of whole DN (real raw codes)")
    model = np.rint(np.asarray(synthesized, dtype=np.float64)).ravel()
    lo, hi = np.percentile(model, [0.05, 99.95])
    r = np.arange(np.floor(lo), np.ceil(hi) + 1.0)
    below = np.searchsorted(np.sort(model), r, side="left") / model.size
    at = np.searchsorted(np.sort(model), r, side="right") / model.size
    codes = np.quantile(v.ravel(), np.clip(0.5 * (below + at), 0.0, 1.0), method="inverted_cdf")
    return {"k": [float(k)], "lo_dn": [float(r[0])], "map_dn": [[float(c) for c in codes]]}


def combine(records: list[dict]) -> dict:
    """One map per gain: the maps of the stacks at one K (bias, dark, flats cover different
    code ranges) joined over their union; where two overlap the first stack's holds, and
    codes between them map to themselves."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(r["k"][0], []).append(r)
    ks, los, maps = sorted(by_k), [], []
    for k in ks:
        parts = by_k[k]
        lo = min(p["lo_dn"][0] for p in parts)
        hi = max(p["lo_dn"][0] + len(p["map_dn"][0]) - 1 for p in parts)
        joined = np.arange(lo, hi + 1.0)
        filled = np.zeros(joined.size, dtype=bool)
        for p in parts:
            start = int(p["lo_dn"][0] - lo)
            m = np.asarray(p["map_dn"][0], dtype=np.float64)
            free = ~filled[start : start + m.size]
            joined[start : start + m.size][free] = m[free]
            filled[start : start + m.size] = True
        los.append(float(lo))
        maps.append([float(c) for c in np.maximum.accumulate(joined)])  # non-decreasing where ranges meet
    return {"k": ks, "lo_dn": los, "map_dn": maps}
