"""Burst columns (ColBurst): a few sensor columns of every frame, new ones each frame, read with
extra white noise.

Physics: a column amplifier or column ADC that is disturbed for the time of one frame's
conversion (a marginal comparator, a supply glitch on one column's bias) adds noise to every
pixel of its column in that frame only. Unlike ``NoisyCol`` (columns noisy in every frame),
``Col`` (a column's offset) or ``RowBurst`` (the same along the sensor rows), the columns change
from frame to frame and their mean does not move.

Stage (DN, with the read noise): in frame ``b``, sensor column ``X`` is a burst column where a
U(0, 1) of ``(b, X)`` falls below ``density``; each of its pixels gets ``sigma_dn(K) * z``, ``z``
a standard normal new at every pixel and frame.

Profile entry (per-K records)::

    ColBurst: {density: 0.01, k: [K, ...], sigma_dn: [...]}

Detected on bias and dark stacks of >= 3 frames by ``burst_cols`` (frames' sensor columns whose
variance stands ``BURST_Z`` sds above the same column's median over the frames) and
``read_noise_spread``. Estimated by ``estimate`` as ``RowBurst`` is, along the columns.
"""
from __future__ import annotations

from ..engine import layout as L
from .base import READ, NoiseEffect, register
from .k_records import value_at_k
from .row_burst import burst_record, combine, empty, validate_bursts  # noqa: F401  (combine, empty: the loop's per-effect hooks)

STATISTICS = ("burst_cols", "read_noise_spread")
SHARES_READ_NOISE = True  # calibration's read noise holds the bursts' share of the variance


@register
class ColBurst(NoiseEffect):
    token = "ColBurst"
    order = READ + 1
    flag = L.COL_BURST
    columns = ("cburst_density", "cburst_sigma")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        return {"cburst_density": ctx.k.new_full(ctx.k.shape, float(p["density"])), "cburst_sigma": value_at_k(p, "sigma_dn", ctx.k)}

    @classmethod
    def validate_params(cls, params):
        validate_bursts(cls.token, params, "columns")


def estimate(frames, synthesized, k: float, kind=None, **_) -> dict:
    """ColBurst record at gain ``k`` from a bias or dark stack (N >= 3, 4, h, w) in DN, against
    stacks of the same shape synthesized by the model."""
    return burst_record("ColBurst", frames, synthesized, k, kind, columns=True)
