"""Diagonal banding (DiagBand): tones along both sensor axes, new in phase in every frame, or
fixed in phase (the same pattern in every frame).

Physics: where pixels are read out serially in time (a CCD's output register, a sensor with
few output amplifiers), interference during readout (a switching regulator, a clock) of
frequency f reaches pixel (X, Y) at time X tau + Y T (pixel time tau, line time T): a 2-D
tone of ``f tau`` cycles per sensor column whose phase advances ``f T`` cycles per sensor row,
seen as diagonal stripes ("herringbone"), with a phase of its own in every frame. A source
locked to the frame start (the sensor's own clock, a readout sequencer) puts the stripes at
the same place in every frame: a fixed pattern of one spatial frequency, which a white
fixed-pattern model cannot reproduce. ``Band`` (a column-parallel readout: ``f tau``
vanishes) and ``ColBand`` (a tone locked to the line rate: ``f T`` whole) are its cases along
one axis.

Synthesis: ``sum_j a_j cos(2 pi (fx_j X + fy_j Y) + phi_j) + f_j cos(2 pi (fx_j X + fy_j Y) + psi_j)``
on raw pixel (X, Y), ``phi_j`` uniform per frame and tone, ``psi_j`` uniform per sensor
instance and tone (its fixed patterns' realization: the same in every frame of a sensor); at
most ``rawaug.engine.layout.BAND_TONES``.

Profile entry (per-K records; ``freq_per_col`` in [0, 0.5], ``freq_per_row`` in [-0.5, 0.5];
``fixed_dn`` optional, 0 where absent)::

    DiagBand: {k: [K, ...], freq_per_col: [[fx1, ...], ...], freq_per_row: [[fy1, ...], ...],
               amplitude_dn: [[a1, ...], ...], fixed_dn: [[f1, ...], ...]}

Detected by ``diag_tone`` (the largest bin of the raw mosaics' Hann-windowed 2-D periodogram
off both axes above its median bin: a smooth field's leakage is not a tone). Estimated by
``estimate``: ``Band``'s search in two dimensions, on the windowed mosaics: bins
above the mean of the ring of bins around them (between 9 x 9 and 5 x 5) by more than chance
allows (F-test, family-wise p 1e-3: a tone is narrow, a smooth field's excess is not), each refined to the frequency pair that
maximizes the frames' power (21 x 21 grids of +-1, +-0.1 and +-0.01 bin in turn: the peak
bin's power, which ``diag_tone`` reads, depends on where a tone lies between bins), its amplitude from the circle of the frames'
Fourier coefficients (``banding.circle_amplitude``); where their mean stands out of their
spread, that is the tone's fixed part (``fixed_amplitude``) and the spread its part new in every
frame (``spread_amplitude``); each tone removed before the next. Judged with the
read noise re-fitted (calibration had counted the tone's power as read noise).
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from ..engine import layout as L
from ..statistics import CORE, LOCAL, diagonal_bins, frame_mosaic, hann_2d, local_background, windowed_periodogram
from .banding import FAMILY_P, circle_amplitude, draw_tones
from .base import BANDING, NoiseEffect, register
from .k_records import _number, validate_records

STATISTICS = ("diag_tone",)
SHARES_READ_NOISE = True  # calibration counted the tone's power as white read noise
HANN_BINS = 1.5  # the Hann window's equivalent noise bandwidth, bins
ZOOM = (1.0, 0.1, 0.01)  # half-widths (bins) of the 21 x 21 grids a tone's frequency is refined on, in turn
KEYS = ("freq_per_col", "freq_per_row", "amplitude_dn")
FIXED_KEY = "fixed_dn"


@register
class DiagonalBanding(NoiseEffect):
    token = "DiagBand"
    order = BANDING
    flag = L.DIAG_BAND
    columns = tuple(f"dband_{name}{j}" for name in ("fx", "fy", "a") for j in range(L.BAND_TONES))

    def draw(self, ctx):
        return draw_tones(self.profile.effects[self.token], ctx, dict(zip(("fx", "fy", "a", "f"), KEYS + (FIXED_KEY,))), "dband")

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, KEYS)
        keys = KEYS + ((FIXED_KEY,) if FIXED_KEY in params else ())
        if FIXED_KEY in params and (not isinstance(params[FIXED_KEY], (list, tuple)) or len(params[FIXED_KEY]) != len(params["k"])):
            raise ValueError(f"effect {cls.token!r}: {FIXED_KEY} needs one list per record (k), got {params[FIXED_KEY]!r}")
        for r, lists in enumerate(zip(*(params[key] for key in keys))):
            if not all(isinstance(v, (list, tuple)) for v in lists) or len({len(v) for v in lists}) != 1:
                raise ValueError(f"effect {cls.token!r}: record {r} needs equal lists {', '.join(KEYS)}, got {lists!r}")
            if len(lists[0]) > L.BAND_TONES:
                raise ValueError(f"effect {cls.token!r}: at most {L.BAND_TONES} tones per record, got {len(lists[0])}")
            for fx, fy, a, *fixed in zip(*lists):
                fx, fy = _number(fx, f"{cls.token}.freq_per_col[]"), _number(fy, f"{cls.token}.freq_per_row[]")
                if fixed and _number(fixed[0], f"{cls.token}.{FIXED_KEY}[]") < 0:
                    raise ValueError(f"effect {cls.token!r}: {FIXED_KEY} must be >= 0, got {fixed[0]}")
                if not (0.0 <= fx <= 0.5 and -0.5 <= fy <= 0.5) or fx == fy == 0.0:
                    raise ValueError(f"effect {cls.token!r}: a tone needs freq_per_col in [0, 0.5] and freq_per_row in "
                                     f"[-0.5, 0.5] (cycles per sensor column, row), not both 0, got ({fx}, {fy})")
                if _number(a, f"{cls.token}.amplitude_dn[]") < 0:
                    raise ValueError(f"effect {cls.token!r}: amplitude_dn must be >= 0, got {a}")


def _coefficients(raw, fy, fx):
    """Each frame's Fourier coefficients of the (windowed) raw mosaics ``raw`` (N, H, W) on the
    grid of ``fy`` (m,) x ``fx`` (p,) (cycles per sensor row, column): (N, m, p) complex."""
    ex = np.exp(-2j * np.pi * np.outer(np.arange(raw.shape[2]), fx))  # (W, p)
    ey = np.exp(-2j * np.pi * np.outer(fy, np.arange(raw.shape[1])))  # (m, H)
    return np.einsum("my,nyp->nmp", ey, raw @ ex)


FIXED_P = 1e-3  # a tone's fixed part is kept where its frames' mean coefficient stands out of their spread this surely


def _spread(c) -> float:
    """Variance (ddof 1) of complex values about their mean."""
    c = np.asarray(c)
    return float(np.sum(np.abs(c - c.mean()) ** 2)) / (c.shape[0] - 1)


def fixed_amplitude(x, x_models, coherent: float) -> float:
    """Amplitude (DN) of the part of a tone that is the same in every frame, from each frame's
    Fourier coefficient ``x`` (N,) and those of the model's syntheses (a list of (N,)): the
    squared mean |mean x|^2 less what its spread leaves in a mean of N (s^2 / N, s^2 the
    frames' variance about it: a phase new in every frame, noise), less the same of the
    syntheses (the model's own fixed patterns at that frequency), as 2 sqrt(.) / ``coherent``
    (sum of the window). 0 unless the mean stands out of the spread (N |mean|^2 / s^2 over
    the F(2, 2 (N - 1)) quantile at FIXED_P), and for fewer than 3 frames."""
    def excess(c):  # (|mean|^2, what the spread leaves in it)
        c = np.asarray(c)
        return float(abs(c.mean()) ** 2), _spread(c) / c.shape[0]

    x = np.asarray(x)
    n = x.shape[0]
    if n < 3:
        return 0.0
    power, spread = excess(x)
    if power <= stats.f.isf(FIXED_P, 2, 2 * (n - 1)) * max(spread, 1e-300):
        return 0.0
    model = float(np.mean([p - sp for p, sp in map(excess, x_models)])) if len(x_models) else 0.0
    f2 = power - spread - max(model, 0.0)
    return 2.0 * np.sqrt(f2) / coherent if f2 > 0 else 0.0


def spread_amplitude(x, x_models, coherent: float) -> float:
    """Amplitude (DN) of the part of a tone new in every frame, from the spread of the frames'
    Fourier coefficients ``x`` (N,) about their mean less that of the model's syntheses' (a
    list of (N,)): a tone of random phase and amplitude a adds (a coherent / 2)^2, whatever
    the shape its coefficients make (a circle, or an arc about a fixed part)."""
    r2 = _spread(x) - (float(np.mean([_spread(m) for m in x_models])) if len(x_models) else 0.0)
    return 2.0 * np.sqrt(r2) / coherent if r2 > 0 else 0.0


def estimate(frames, synthesized, k: float, level_dn=None, **_) -> dict:
    """DiagBand record at gain ``k`` from a bias or dark stack (N, 4, h, w) in DN: the tones of
    its raw mosaics off both axes that the model's syntheses lack. Searched on the Hann-windowed
    mosaics (``statistics.windowed_periodogram``: a smooth field's leakage is no tone), each
    tone removed from the mosaics as they are."""
    if level_dn is not None or not synthesized:
        raise ValueError("DiagBand is measured on bias and dark stacks, against syntheses")
    raw = frame_mosaic(frames)
    models = [frame_mosaic(s) for s in synthesized]
    n_frames, hh, ww = raw.shape
    window = hann_2d((hh, ww))
    noise_gain, tone_gain = float(np.sum(window**2)), float(np.sum(window))
    fy, fx, mask = diagonal_bins((hh, ww))

    def power(r, gy, gx):  # mean windowed periodogram over frames (DN^2) on a frequency grid
        return (np.abs(_coefficients(r * window, gy, gx)) ** 2).mean(axis=0) / noise_gain

    # a tone stands out of its neighbourhood: each bin over the mean of the ring of bins around
    # it (``local_background``), an F ratio of 2 N and 2 N x (the ring's independent bins)
    # degrees of freedom: the Hann window correlates neighbouring bins (its noise bandwidth,
    # HANN_BINS bins per axis)
    threshold = stats.f.isf(FAMILY_P / int(mask.sum()), 2 * n_frames, 2 * n_frames * (LOCAL**2 - CORE**2) / HANN_BINS**2)
    yy, xx = np.arange(hh)[:, None], np.arange(ww)[None, :]
    tones, amps, fixed_amps = [], [], []
    while len(tones) < L.BAND_TONES:
        p = windowed_periodogram(raw)
        ratio = np.where(mask, p / np.maximum(local_background(p), 1e-30), 0.0)
        i = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        if ratio[i] <= threshold:
            break
        best_y, best_x = float(fy[i]), float(fx[i])
        for span in ZOOM:  # the peak bin's power depends on where the tone lies between bins: refine it closely
            gy = best_y + span * np.linspace(-1, 1, 21) / hh
            gx = np.clip(best_x + span * np.linspace(-1, 1, 21) / ww, 0.0, 0.5)
            j = np.unravel_index(int(np.argmax(power(raw, gy, gx))), (gy.size, gx.size))
            best_y, best_x = float(gy[j[0]]), float(gx[j[1]])
        noise = float(np.mean([power(m, [best_y], [best_x])[0, 0] for m in models]))  # the model's power there, DN^2
        x = _coefficients(raw * window, [best_y], [best_x])[:, 0, 0]
        x_models = [_coefficients(m * window, [best_y], [best_x])[:, 0, 0] for m in models]
        fixed = fixed_amplitude(x, x_models, tone_gain)
        # with a fixed part, the coefficients need not lie on a circle about it (a phase that
        # jitters about a fixed one makes an arc): the part new in every frame from their spread
        amplitude = (spread_amplitude(x, x_models, tone_gain) if fixed > 0
                     else circle_amplitude(x, noise_gain, noise, coherent=tone_gain))
        if amplitude <= 0 and fixed <= 0:
            break
        tones.append((best_x, best_y))
        amps.append(float(amplitude))
        fixed_amps.append(float(fixed))
        arg = 2 * np.pi * (best_x * xx + best_y * yy)
        basis = np.stack([np.cos(arg).ravel(), np.sin(arg).ravel()], axis=1)
        coef, *_ = np.linalg.lstsq(basis, raw.reshape(n_frames, -1).T, rcond=None)
        raw = raw - (basis @ coef).T.reshape(raw.shape)
    out = {"k": [float(k)], "freq_per_col": [[t[0] for t in tones]], "freq_per_row": [[t[1] for t in tones]],
           "amplitude_dn": [amps]}
    if any(f > 0 for f in fixed_amps):
        out[FIXED_KEY] = [fixed_amps]
    return out


def empty(params) -> bool:
    """True when a record holds no tone of nonzero amplitude, in phase new or fixed: it would
    add nothing (the loop's)."""
    return not any(a for key in ("amplitude_dn", FIXED_KEY) for record in params.get(key, []) for a in record)


def combine(records: list[dict]) -> dict:
    """One record per gain: the tones of the first stack at that K (bias before dark), each
    amplitude the rms over the stacks at that K that found it (within 1/200 cycle on both
    axes), its fixed part the rms over those that found one (``fixed_amplitude``'s test)."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    ks = sorted(by_k)
    out = {"k": ks, "freq_per_col": [], "freq_per_row": [], "amplitude_dn": [], FIXED_KEY: []}
    for k in ks:
        first = by_k[k][0]
        out["freq_per_col"].append(list(first["freq_per_col"][0]))
        out["freq_per_row"].append(list(first["freq_per_row"][0]))
        for key, row in (("amplitude_dn", []), (FIXED_KEY, [])):
            for fx, fy in zip(first["freq_per_col"][0], first["freq_per_row"][0]):
                found = [a for r in by_k[k] for gx, gy, a in zip(r["freq_per_col"][0], r["freq_per_row"][0],
                                                                 r.get(key, [[0.0] * len(r["freq_per_col"][0])])[0])
                         if abs(gx - fx) < 0.005 and abs(gy - fy) < 0.005]
                if key == FIXED_KEY:  # a stack of few frames may not tell a fixed part from noise: not an absence
                    found = [a for a in found if a > 0] or [0.0]
                row.append(float(np.sqrt(np.mean(np.square(found)))))
            out[key].append(row)
    if not any(f > 0 for row in out[FIXED_KEY] for f in row):
        del out[FIXED_KEY]
    return out
