"""Row-noise map (RowMap): row noise of its own level in each row block of the frame.

Physics: a row's offset noise comes from the reference and clamp lines its pixels are read
against; where a reference settles during the readout, or the row drivers sit farther from
their supply down the array, or two halves of the frame are read by circuits of their own,
the row noise grows or falls along the frame. The ELD row noise has one level; calibration
measures the frame's average.

Synthesis: extra row noise ``r[by] * z`` on every pixel of a sensor row, ``z`` standard normal
per sensor row and frame, ``by`` the row block (``READ_MAP_BLOCKS`` equal runs of the measured
frame's packed rows) of the row; an input smaller than the measured frame is a window of it
at an offset drawn per sample (as ``ReadMap``).

Profile entry (per-K records; extra sigma in DN, frame height in packed rows)::

    RowMap: {k: [K, ...], row_block_dn: [[8 values], ...], frame_h: H}

Detected by ``row_noise_spread`` (the spread over the row blocks of the log temporal variance
of the sensor-row means). Estimated by ``estimate`` from bias and dark stacks of 3 frames or
more: per row block, the measured variance of the row means less the model's; kept where an
F-test puts the log block variances' pattern beyond the syntheses' spread at p < 1e-3, shifted
to start at 0. Judged with the row noise re-fitted (calibration counted the extra noise in the
frame's average).
"""
from __future__ import annotations

import numpy as np
from ..engine import layout as L
from ..statistics import row_noise_blocks
from .base import BANDING, NoiseEffect, register
from .k_records import _number, all_zero, record_index, validate_records, window_columns
from .read_map import pattern_beyond

STATISTICS = ("row_noise_spread",)
SHARES_ROW_NOISE = True  # calibration counted its variance in the frame's row noise
P_VALUE = 1e-3  # the blocks' pattern counts where the model makes one as large less often
NB = L.READ_MAP_BLOCKS


@register
class RowMap(NoiseEffect):
    token = "RowMap"
    order = BANDING
    flag = L.ROW_MAP
    columns = tuple(f"rowmap_y{i}" for i in range(NB)) + ("rowmap_oy", "rowmap_h")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        table = ctx.k.new_tensor(np.asarray(p["row_block_dn"], dtype=np.float64).reshape(len(p["k"]), NB))[record_index(p, ctx.k)]
        out = {f"rowmap_y{i}": table[:, i] for i in range(NB)}
        # a window along the rows only: a frame 1 column wide is never narrower than the input
        window = window_columns(ctx, self.token, {"frame_h": p["frame_h"], "frame_w": 1} if "frame_h" in p else {},
                                ("rowmap_oy", "rowmap_ox", "rowmap_h", "rowmap_w"))
        out["rowmap_oy"], out["rowmap_h"] = window["rowmap_oy"], window["rowmap_h"]
        return out

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("row_block_dn",))
        for r, values in enumerate(params["row_block_dn"]):
            if not isinstance(values, (list, tuple)) or len(values) != NB:
                raise ValueError(f"effect 'RowMap': row_block_dn record {r} must list {NB} values (extra sigma, DN), got {values!r:.80}")
            for v in values:
                if _number(v, "RowMap.row_block_dn[]") < 0:
                    raise ValueError(f"effect 'RowMap': row_block_dn values must be >= 0 (DN), got {v!r}")
        if "frame_h" in params:
            h = params["frame_h"]
            if not isinstance(h, int) or isinstance(h, bool) or not 1 <= h <= 1 << 20:
                raise ValueError(f"effect 'RowMap': frame_h must be a whole number of packed rows in [1, 2^20], got {h!r}")


def _significant(measured, synth) -> bool:
    """Is the measured pattern of the log block variances (each less its mean) beyond the
    model's (``read_map.pattern_beyond``, at ``P_VALUE``)?"""
    meas = np.log(np.maximum(measured, 1e-12))
    m = np.log(np.maximum(synth, 1e-12))
    return pattern_beyond(meas - meas.mean(), m - m.mean(axis=1, keepdims=True), P_VALUE)


def estimate(frames, synthesized, k: float, level_dn=None, kind: str = "bias", **_) -> dict:
    """RowMap record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w) in DN, against
    syntheses of it (at least 3)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or level_dn is not None or frames.shape[0] < 3 or len(synthesized) < 3:
        raise ValueError("RowMap is measured on bias and dark stacks of >= 3 frames, against >= 3 syntheses")
    measured = row_noise_blocks(frames)
    synth = np.array([row_noise_blocks(s) for s in synthesized])
    excess = measured - synth.mean(axis=0)  # DN^2 per row block
    var = excess - excess.min() if _significant(measured, synth) else np.zeros(NB)
    return {"k": [float(k)], "row_block_dn": [[float(v) for v in np.sqrt(np.maximum(var, 0.0))]], "frame_h": int(frames.shape[2])}


def combine(records: list[dict]) -> dict:
    """One record per gain: the stacks at one K averaged in variance."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    ks = sorted(by_k)
    return {"k": ks, "row_block_dn": [[float(v) for v in np.sqrt(np.mean([np.square(r["row_block_dn"][0]) for r in by_k[k]], axis=0))]
                                      for k in ks],
            "frame_h": records[0]["frame_h"]}


def empty(params) -> bool:
    """True when every amplitude is 0: it would add nothing."""
    return all_zero(params, ("row_block_dn",))
