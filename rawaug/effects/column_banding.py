"""Column banding (ColBand): tones along the sensor columns, new in phase in every frame.

Physics: where a row is read out serially in time (a CCD's output register, a CMOS sensor
with few output amplifiers, a multiplexed column bus), interference picked up during readout
(a switching regulator, a clock) is a tone along the columns of each row; a tone locked to
the line start (a harmonic of the line rate, or a clock derived from the pixel clock) falls
at the same column phase in every row: vertical bands at a fixed spatial frequency, with a
phase that depends on when the frame started. The ELD model has no column noise, and
calibration counts the tone's power as read noise (it removes the row means only).

Synthesis: ``sum_j a_j cos(2 pi f_j X + phi_j)`` on sensor column ``X`` (both channels of the
column, every row), ``phi_j`` uniform per frame and tone; at most
``rawaug.engine.layout.BAND_TONES``. The fused kernels share ``Band``'s tone function.

Profile entry (per-K records)::

    ColBand: {k: [K, ...], freq_per_col: [[f1, f2], ...], amplitude_dn: [[a1, a2], ...], on_share: [[p1, p2], ...]}

(``on_share`` optional, default 1, as ``Band``'s.)

Detected by ``col_tone`` (the largest bin of the frames' sensor-column-mean periodogram above
its median bin). Estimated by ``estimate``: ``Band``'s tone search (``banding.line_tones``)
on the sensor-column means. Judged with the read noise re-fitted (the tone's power had gone
into it); ``Col`` (white column offsets) is its rival for the same column-mean variance.
"""
from __future__ import annotations

import numpy as np

from ..engine import layout as L
from ..statistics import frame_col_means
from .banding import align_tones, combine_tones, draw_tones, empty, line_tones, validate_tones  # noqa: F401 (empty: the loop's)
from .base import BANDING, NoiseEffect, register

STATISTICS = ("col_tone",)
AMPLITUDES = ("amplitude_dn",)  # corrected by simulation under a clip (rawaug.loop.clip_correction)
SHARES_READ_NOISE = True  # calibration counted the tone's power as white read noise


@register
class ColumnBanding(NoiseEffect):
    token = "ColBand"
    order = BANDING
    flag = L.COL_BAND
    columns = tuple(f"cband_f{j}" for j in range(L.BAND_TONES)) + tuple(f"cband_a{j}" for j in range(L.BAND_TONES))

    def draw(self, ctx):
        return draw_tones(self.profile.effects[self.token], ctx, {"f": "freq_per_col", "a": "amplitude_dn"}, "cband", jitter="f")

    @classmethod
    def validate_params(cls, params):
        validate_tones(cls.token, params, "freq_per_col", "sensor column")


def estimate(frames, synthesized, k: float, level_dn=None, **_) -> dict:
    """ColBand record at gain ``k`` from a bias or dark stack (N, 4, h, w) in DN: the tones of
    its sensor-column means (``banding.line_tones``)."""
    frames = np.asarray(frames, dtype=np.float64)
    if level_dn is not None or not synthesized:
        raise ValueError("ColBand is measured on bias and dark stacks, against syntheses")
    tones, amps, shares, sds = line_tones(frame_col_means(frames), [frame_col_means(np.asarray(s, dtype=np.float64)) for s in synthesized])
    return {"k": [float(k)], "freq_per_col": [tones], "amplitude_dn": [amps], "on_share": [shares], "freq_sd": [sds],
            "frames": [int(frames.shape[0])]}


def combine(records: list[dict]) -> dict:
    return combine_tones(records, "freq_per_col")


def aligned(simulated: dict, params: dict) -> dict:
    """``simulated`` arranged as the tones of ``params`` (``banding.align_tones``)."""
    return align_tones(simulated, params, "freq_per_col")
