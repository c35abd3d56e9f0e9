"""Column drift (ColDrift): column noise whose offsets drift slowly from column to column.

Physics: a readout that samples a reference with 1/f noise once per sensor column (a serial
readout's clamp, a column-parallel ADC's shared ramp while it steps along the columns) shows
it as column offsets that nearby columns share, new in every frame: column noise with a
low-frequency spectrum across the columns. ``Col`` is white from column to column; ``LowFreq``
is a 2-D field, not one that a whole column shares.

Synthesis: ``RowDrift``'s along the sensor columns, one octave finer. On sensor column ``X`` of
a frame, the sum over octaves j = 0 .. 7 of ``a_j`` times the linear interpolation of
standard normals on nodes every ``2^j`` sensor columns (octave 0: a white offset per
column), each octave's grid shifted by a whole number of columns drawn per frame. A 1/f
spectrum reaches the Nyquist frequency, so a white column term is part of it: the effect
holds it, rather than leaving it to ``Col`` (found first, ``Col`` would have taken the
drift's variance as white).

Profile entry (per-K records; the std of each octave's nodes, DN)::

    ColDrift: {k: [K, ...], octave_dn: [[8 values], ...]}

Detected by ``col_lowfreq`` and ``col_excess`` (the column variance: tried beside ``Col`` on
it). Estimated by ``estimate`` from bias and dark stacks: the cross-periodogram of each
frame's sensor-column means in the top and the bottom half of the rows, about the stack
mean, over the model's, fitted by non-negative octave powers (``row_drift.octave_fit``),
kept where the octaves beat the white octave alone at p < 1e-3: white column noise is
``Col``'s.
"""
from __future__ import annotations

from ..engine import layout as L
from .base import register
from .row_drift import OCT, RowDrift, combine, drift_record  # noqa: F401  (combine: the same per-gain pooling)

STATISTICS = ("col_lowfreq", "col_excess")


@register
class ColDrift(RowDrift):
    token = "ColDrift"
    flag = L.COL_DRIFT
    columns = tuple(f"cdrift_a{j}" for j in range(OCT))


def estimate(frames, synthesized, k: float, level_dn=None, **_) -> dict:
    """ColDrift record at gain ``k`` (``drift_record`` along the columns, octave 0 white)."""
    return drift_record("ColDrift", "col", 0, frames, synthesized, k, level_dn)
