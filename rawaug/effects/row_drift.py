"""Row drift (RowDrift): row noise whose offsets drift slowly from row to row.

Physics: the readout's reference (a clamp, a ramp generator, the column amplifiers' bias)
has 1/f noise. A rolling readout samples it once per sensor row, so it shows as row offsets
that nearby rows share: row noise with a low-frequency spectrum, new in every frame. The
ELD row noise ``R`` is white from row to row; calibration measures the variance of both.

Synthesis: on sensor row ``Y`` of a frame, the sum over octaves j = 0 .. 7 of ``a_j`` times
the linear interpolation of standard normals on nodes every ``s_j = 2^(j + 1)`` sensor rows,
each octave's grid shifted by ``floor(s_j U)`` rows (``U`` uniform per frame and octave, so
the field is stationary). Octave amplitudes shape any low-frequency row spectrum: 1/f
noise, a drift, a smooth excess nobody named.

Profile entry (per-K records; the std of each octave's nodes, DN)::

    RowDrift: {k: [K, ...], octave_dn: [[8 values], ...]}

Detected by ``row_lowfreq``. Estimated by ``estimate`` from bias and
dark stacks: the cross-periodogram of each frame's sensor-row means in the left and the right
half of the columns, about the stack mean (what a whole row shares, new in every frame: not a
fixed pattern, not pixel noise, not a 2-D field), over the model's, in log-spaced bands, fitted by non-negative
octave powers (each octave's spectrum simulated over the frame's rows) plus a white row
term of either sign (calibration's sigma_r took some of the drift's variance), kept where
the fit beats none by chance at p < 1e-3. Judged with sigma_r re-fitted.
"""
from __future__ import annotations

import functools

import numpy as np
from scipy import optimize, stats

from ..engine import layout as L
from ..statistics import sensor_col_means, sensor_row_means
from .base import BANDING, NoiseEffect, register
from .k_records import record_index, validate_records

STATISTICS = ("row_lowfreq",)  # its power is along one axis: the 2-D statistics are FPN's, Glow's and LowFreq's
SHARES_ROW_NOISE = True  # calibration's sigma_r holds the drift's row variance
OCT = L.DRIFT_OCTAVES
P_VALUE = 1e-3  # the octave fit is kept where it beats none by more than chance allows at this p
BANDS = 16  # log-spaced frequency bands of the fit
SIMULATED = 64  # realizations per octave of its simulated spectrum


@register
class RowDrift(NoiseEffect):
    token = "RowDrift"
    order = BANDING
    flag = L.ROW_DRIFT
    columns = tuple(f"drift_a{j}" for j in range(OCT))

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        table = ctx.k.new_tensor(np.asarray(p["octave_dn"], dtype=np.float64).reshape(len(p["k"]), OCT))
        idx = record_index(p, ctx.k)
        return {name: table[idx, j] for j, name in enumerate(self.columns)}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("octave_dn",))
        for r, values in enumerate(params["octave_dn"]):
            if not isinstance(values, (list, tuple)) or len(values) != OCT:
                raise ValueError(f"effect {cls.token!r}: octave_dn record {r} must list {OCT} values (DN), got {values!r:.80}")
            for v in values:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                    raise ValueError(f"effect {cls.token!r}: octave_dn values must be finite and >= 0 (DN), got {v!r}")


def octave_field(n: int, j: int, rng, count: int = 1, first: int = 1) -> np.ndarray:
    """(count, n) realizations of octave ``j`` with unit node std over ``n`` sensor lines, as
    the kernels make it (nodes every 2^(j + first) lines, linear between, the grid shifted by a
    whole number of lines)."""
    s = 1 << (j + first)
    t = np.arange(n)[None, :] + rng.integers(0, s, size=(count, 1))
    i = t // s
    f = (t - i * s) / s
    nodes = rng.standard_normal((count, n // s + 3))
    rows = np.arange(count)[:, None]
    return nodes[rows, i] * (1.0 - f) + nodes[rows, i + 1] * f


def _periodogram(m) -> np.ndarray:
    """Mean over rows of ``m`` (count, n), each less its mean, of |rfft|^2 / n, bins 1 .. n // 2."""
    m = m - m.mean(axis=1, keepdims=True)
    return (np.abs(np.fft.rfft(m, axis=1)) ** 2 / m.shape[1]).mean(axis=0)[1:]


@functools.lru_cache(maxsize=16)
def octave_spectra(n: int, first: int = 1) -> np.ndarray:
    """(OCT, n // 2) mean periodogram of each octave (unit node std) over ``n`` sensor lines."""
    rng = np.random.default_rng(0)
    return np.stack([_periodogram(octave_field(n, j, rng, SIMULATED, first)) for j in range(OCT)])


def _half_line_means(frames, axis="row"):
    """(first, second): (N, 2n) temporal sensor-line means about the stack mean (times
    sqrt(N / (N - 1)): the temporal part at full variance), DN: for ``axis`` "row" the sensor
    rows' means over the left and the right half of the columns, for "col" the sensor columns'
    over the top and the bottom half of the rows."""
    frames = np.asarray(frames, dtype=np.float64)
    n = frames.shape[0]
    if axis == "row":
        w = frames.shape[3]
        halves, means = (frames[..., : w // 2], frames[..., w // 2 :]), sensor_row_means
    else:
        h = frames.shape[2]
        halves, means = (frames[:, :, : h // 2], frames[:, :, h // 2 :]), sensor_col_means
    out = []
    for half in halves:
        m = means(half)
        out.append((m - m.mean(axis=0, keepdims=True)) * np.sqrt(n / (n - 1)))
    return out


def temporal_line_spectrum(frames, axis="row") -> np.ndarray:
    """Cross-periodogram (bins 1 .. n // 2, DN^2) of the temporal sensor-line means of the two
    halves of each frame (``_half_line_means``, each less its frame mean), mean over frames:
    the power of what a whole line shares (line offsets, a drift); pixel noise and a 2-D
    field whose phase changes across the frame average out of it."""
    first, second = (m - m.mean(axis=1, keepdims=True) for m in _half_line_means(frames, axis))
    cross = np.real(np.fft.rfft(first, axis=1) * np.conj(np.fft.rfft(second, axis=1))) / first.shape[1]
    return cross.mean(axis=0)[1:]


def temporal_row_spectrum(frames) -> np.ndarray:
    """``temporal_line_spectrum`` along the sensor rows."""
    return temporal_line_spectrum(frames, "row")


def half_line_spectrum(frames, axis="row") -> np.ndarray:
    """Mean periodogram of the two halves' temporal sensor-line means (bins 1 .. n // 2, DN^2):
    the scale of the cross-periodogram's spread."""
    return np.mean([_periodogram(m) for m in _half_line_means(frames, axis)], axis=0)


def octave_fit(frames, synthesized, axis="row", first=1) -> np.ndarray:
    """(OCT,) octave amplitudes (DN) of the temporal line spectrum's excess over the model's
    along ``axis`` ("row" or "col"), nodes every 2^(j + first) lines, in log-spaced bands,
    fitted by non-negative octave powers; ValueError where the fit beats a white line term
    alone only by chance (p >= P_VALUE). With ``first`` 1 (RowDrift) that white term joins
    the fit with either sign (calibration's sigma_r holds part of the drift's variance); with
    ``first`` 0 (ColDrift) it is octave 0 itself (a node every line)."""
    frames = np.asarray(frames, dtype=np.float64)
    measured = temporal_line_spectrum(frames, axis)
    model = np.mean([temporal_line_spectrum(s, axis) for s in synthesized], axis=0)
    spread = np.mean([half_line_spectrum(s, axis) for s in synthesized], axis=0)
    n_lines = 2 * frames.shape[2 if axis == "row" else 3]
    shapes = octave_spectra(n_lines, first)
    edges = np.unique(np.geomspace(1, measured.size + 1, BANDS + 1).astype(int)) - 1
    band = lambda x: np.add.reduceat(x, edges[:-1], axis=-1) / np.diff(edges)  # noqa: E731
    count = np.diff(edges)
    excess = band(measured - model)
    usable = [j for j in range(OCT) if (1 << (j + first)) <= n_lines // 4]  # an octave spans a few nodes of the frame
    signed = first > 0  # a white term of either sign beside the octaves
    shape = np.column_stack([band(shapes[j]) for j in usable] + ([np.ones(excess.size)] if signed else []))
    lower = [0.0] * len(usable) + ([-np.inf] if signed else [])
    power = np.zeros(excess.size)  # the excess the fit finds: it spreads the cross power too
    for _ in range(2):  # fitted, then fitted again with the found excess's own scatter (a strong white line term's)
        # a band's cross power: N frames x count bins, each spreading by about the halves' power; the model's mean adds a little
        se = (band(spread) + power) * np.sqrt(1.0 / (frames.shape[0] * count) + 1.0 / (len(synthesized) * frames.shape[0] * count))
        design, target = shape / se[:, None], excess / se
        fit = optimize.lsq_linear(design, target, bounds=(lower, [np.inf] * len(lower)))
        power = np.maximum(shape @ fit.x, 0.0)
    white = design[:, -1:] if signed else design[:, :1]  # the white line term alone
    white_only = optimize.lsq_linear(white, target, bounds=(lower[-1:] if signed else [0.0], [np.inf]))
    drop = float(np.sum((white @ white_only.x - target) ** 2) - np.sum((design @ fit.x - target) ** 2))
    if drop <= stats.chi2.isf(P_VALUE, max(len(usable) - (0 if signed else 1), 1)):
        raise ValueError(f"the {axis} spectrum's excess is within chance: this stack shows no {axis} drift")
    octave = np.zeros(OCT)
    octave[usable] = np.sqrt(np.maximum(fit.x[: len(usable)], 0.0))
    return octave


def drift_record(token: str, axis: str, first: int, frames, synthesized, k: float, level_dn=None) -> dict:
    """A line drift's record at gain ``k`` from a bias or dark stack (N >= 2, 4, h, w) in DN
    (``octave_fit`` along ``axis``); ValueError where the excess is within chance."""
    if level_dn is not None or not len(synthesized) or np.shape(frames)[0] < 2:
        raise ValueError(f"{token} is measured on bias and dark stacks of >= 2 frames, against syntheses")
    octave = octave_fit(frames, synthesized, axis, first)
    return {"k": [float(k)], "octave_dn": [[float(a) for a in octave]]}


def estimate(frames, synthesized, k: float, level_dn=None, **_) -> dict:
    """RowDrift record at gain ``k`` (``drift_record`` along the rows)."""
    return drift_record("RowDrift", "row", 1, frames, synthesized, k, level_dn)


def combine(records: list[dict]) -> dict:
    """One record per gain: the stacks at one K averaged in power, octave by octave."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(np.square(r["octave_dn"][0]))
    ks = sorted(by_k)
    return {"k": ks, "octave_dn": [np.sqrt(np.mean(by_k[k], axis=0)).tolist() for k in ks]}
