"""Row telegraph noise (RowRTS): a few sensor rows jump between two levels from frame to frame.

Physics: a trap in a row's select or reset driver, or in the reference a row is converted
against, captures and releases a carrier at random (random telegraph signal), so the whole
row reads one of two offsets, a new state in every frame. ``ColRTS`` is the same physics in a
column's amplifier; ``R`` is Gaussian row noise in every row, ``RowFix`` a fixed row offset.

Stage (DN, after read noise): in the sensor rows where a seeded U(0, 1) pattern falls below
``density``, ``s -> s + step`` in the frames where the frame's U(0, 1) for the row falls below
``high`` (the share of frames in the high state), with a log-normal step
``median_dn(K) * exp(log_std * z)`` seeded by the row.

Profile entry::

    RowRTS: {seed: 107, density: 0.01, high: 0.5, log_std: 0.3, k: [K, ...], median_dn: [...]}

Detected on bias and dark stacks of >= 4 frames by ``row_flicker_fraction`` (sensor rows
whose frame means, less the row's mean and the frame's, have two states, on the frames with
their defect lines) and ``defect_lines`` (a row far off in some frames is theirs).
Estimated as ``ColRTS`` along the rows (``line_estimate``, ``combine``).
"""
from __future__ import annotations

from ..engine import layout as L
from ..statistics import flickering_rows
from .base import READ, pattern_key, register
from .column_telegraph import ColumnTelegraph, combine, empty, line_estimate  # noqa: F401  (combine, empty: the loop's)

STATISTICS = ("row_flicker_fraction", "row_excess", "defect_lines")  # a row far off in a frame is that frame's defect line
RAW_FRAMES = True  # the defect-line repair would replace a row in the frames where it stands out


@register
class RowTelegraph(ColumnTelegraph):
    token = "RowRTS"
    order = READ + 7
    flag = L.ROW_RTS
    columns = ("rrts_density", "rrts_median", "rrts_log_std", "rrts_high")
    lines = "sensor rows"

    def draw(self, ctx):
        d = super().draw(ctx)
        return {"rrts" + key[4:]: value for key, value in d.items()}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"rrts_where": pattern_key(seed, self.token, "where"), "rrts_size": pattern_key(seed, self.token, "size")}


def estimate(frames, synthesized, k: float, kind=None, seed: int = 107, **_) -> dict:
    """RowRTS record at gain ``k`` from a bias or dark stack (N >= 4, 4, h, w) in DN
    (``line_estimate`` along the sensor rows)."""
    return line_estimate("RowRTS", flickering_rows, frames, synthesized, k, kind, seed)
