"""Periodic banding (Band): tones along the sensor rows, new in phase in every frame.

Physics: interference picked up during readout (a switching regulator, a clock) is a tone
in time; a rolling readout turns it into horizontal bands at a fixed spatial frequency
(cycles per sensor row = tone frequency x row time), with a phase that depends on when the
frame started: random from frame to frame. The ELD row noise is white along the rows, so
calibration counts the tone's power as row noise (sigma_r).

Synthesis: ``sum_j a_j cos(2 pi f_j Y + phi_j)`` on sensor row ``Y`` (both channels of the
row), ``phi_j`` uniform per frame and tone; at most ``rawaug.engine.layout.BAND_TONES``.

Profile entry (per-K records)::

    Band: {k: [K, ...], freq_per_row: [[f1, f2], ...], amplitude_dn: [[a1, a2], ...], on_share: [[p1, p2], ...]}

(``on_share``, optional, default 1: the share of frames in which each tone is on, for a source
that is switched on and off between frames; its amplitude is that of the frames where it is on.
``freq_sd``, optional, default 0: the sd of each tone's frequency over frames, cycles per row,
for a source whose frequency wanders with its load or temperature: drawn per frame and tone.)

Detected by ``row_tone`` (power of the largest bin of the frames' sensor-row-mean periodogram
above its median bin, above the low band). Estimated by ``estimate``: bins of that periodogram
above the model's and above the running median of their 9 neighbours (a tone is narrow; a
smooth field's leakage is not) by more than chance allows (F-tests, family-wise p 1e-3), each
refined (above the low band) to the
frequency that maximizes the frames' power (grid of 1/40 bin), its amplitude from a circle
fitted to the frames' Fourier coefficients there (radius: the tone; centre: a fixed part); a
tone that is off in some frames (their coefficients at the centre) is a mixture of the circle
and its centre, kept where it beats the circle at p 1e-3 (``tone_presence``). A tone whose
frequency wanders from frame to frame is measured at each frame's own peak
(``frequency_wander``): the peaks' spread beyond their noise, the amplitude from their power.
Judged with the row noise re-fitted (the tone's power had gone into it).
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage, optimize, special, stats

from ..engine import layout as L
from ..statistics import frame_row_means, line_tone_spectrum
from .base import BANDING, NoiseEffect, register
from .k_records import _number, record_index, validate_records

STATISTICS = ("row_tone",)
AMPLITUDES = ("amplitude_dn",)  # corrected by simulation under a clip (rawaug.loop.clip_correction)
SHARES_ROW_NOISE = True  # the tone's power is row noise calibration counted as white
FAMILY_P = 1e-3  # a bin counts as a tone when its power above the model's has this chance over all bins
SMOOTH = 9  # bins of the model's spectrum in its running median
LOCAL = 9  # bins of the measured spectrum's running median a tone must stand out of
PRESENCE_P = 1e-3  # a tone is on in a share of the frames only where the mixture beats the circle at this p
MIN_PRESENCE_FRAMES = 4  # frames a stack needs for its tone's share of frames to be fitted
JITTER_WINDOW = 16  # bins either side of a tone where each frame's own peak is looked for
JITTER_P = 1e-3  # a tone's frequency wanders where the frames' peaks scatter beyond their noise at this p
CLEAR_SHARE = 0.75  # of the frames that must show the tone's peak clearly for its wander to be measured


@register
class Banding(NoiseEffect):
    token = "Band"
    order = BANDING
    flag = L.BAND
    columns = tuple(f"band_f{j}" for j in range(L.BAND_TONES)) + tuple(f"band_a{j}" for j in range(L.BAND_TONES))

    def draw(self, ctx):
        return draw_tones(self.profile.effects[self.token], ctx, {"f": "freq_per_row", "a": "amplitude_dn"}, "band", jitter="f")

    @classmethod
    def validate_params(cls, params):
        validate_tones(cls.token, params, "freq_per_row", "sensor row")


def draw_tones(p, ctx, fields: dict, prefix: str, jitter: str | None = None) -> dict:
    """Per-sample columns ``{prefix}_{name}{j}`` (j < BAND_TONES) of a tone record ``p``, one
    per ``fields`` entry ``name: key`` (its lists of per-tone values under ``key``), at the
    record nearest each drawn K; missing tones, and a key the record lacks, are 0 (amplitude 0:
    no tone). With ``jitter`` (the frequency field's name), a record's ``freq_sd`` moves each
    tone's frequency by a normal draw per frame (sample) and tone, kept in (0, 0.5]."""
    idx = record_index(p, ctx.k)
    out = {}
    for name, key in fields.items():
        table = np.zeros((len(p["k"]), L.BAND_TONES))
        for r, values in enumerate(p.get(key) or []):
            table[r, : len(values)] = values
        for j in range(L.BAND_TONES):
            out[f"{prefix}_{name}{j}"] = ctx.k.new_tensor(table[:, j])[idx]
    if jitter is not None and p.get("freq_sd") is not None:  # a source whose frequency wanders from frame to frame
        sd = np.zeros((len(p["k"]), L.BAND_TONES))
        for r, values in enumerate(p["freq_sd"]):
            sd[r, : len(values)] = values
        for j in range(L.BAND_TONES):
            f = out[f"{prefix}_{jitter}{j}"] + ctx.k.new_tensor(sd[:, j])[idx] * ctx.normal(f"{prefix}_fj{j}").to(ctx.k.dtype)
            out[f"{prefix}_{jitter}{j}"] = (0.5 - (0.5 - f.abs()).abs()).clamp(min=1e-6)  # folded into (0, 0.5]
    if p.get("on_share") is not None and "a" in fields:  # a tone switched on in a share of the frames
        share = np.ones((len(p["k"]), L.BAND_TONES))
        for r, values in enumerate(p["on_share"]):
            share[r, : len(values)] = values
        for j in range(L.BAND_TONES):
            on = ctx.uniform(f"{prefix}_on{j}").to(ctx.k.dtype) < ctx.k.new_tensor(share[:, j])[idx]
            out[f"{prefix}_a{j}"] = out[f"{prefix}_a{j}"] * on
    return out


def validate_tones(token: str, params, freq_key: str, line: str) -> None:
    """Check a tone record: per K equal lists of frequencies (cycles per ``line``, in (0, 0.5])
    and amplitudes (DN, >= 0), at most BAND_TONES each."""
    validate_records(token, params, (freq_key, "amplitude_dn"))
    for r, (fs, amps) in enumerate(zip(params[freq_key], params["amplitude_dn"])):
        if not isinstance(fs, (list, tuple)) or not isinstance(amps, (list, tuple)) or len(fs) != len(amps):
            raise ValueError(f"effect {token!r}: record {r} needs equal lists {freq_key} and amplitude_dn, got {fs!r} / {amps!r}")
        if len(fs) > L.BAND_TONES:
            raise ValueError(f"effect {token!r}: at most {L.BAND_TONES} tones per record, got {len(fs)}")
        for f in fs:
            if not 0.0 < _number(f, f"{token}.{freq_key}[]") <= 0.5:
                raise ValueError(f"effect {token!r}: {freq_key} (cycles per {line}) must be in (0, 0.5], got {f}")
        for a in amps:
            if _number(a, f"{token}.amplitude_dn[]") < 0:
                raise ValueError(f"effect {token!r}: amplitude_dn must be >= 0, got {a}")
    _per_tone(token, params, "freq_sd", 0.25, f"sd of a tone's frequency over frames, cycles per {line}")
    _per_tone(token, params, "on_share", 1.0, "the share of frames a tone is on")


def _per_tone(token: str, params, key: str, most: float, meaning: str) -> None:
    """An optional per-tone list ``key`` of a tone record: one list per record, as long as its
    amplitudes, each value in [0, most]."""
    values = params.get(key)
    if values is None:
        return
    if not isinstance(values, (list, tuple)) or len(values) != len(params["k"]):
        raise ValueError(f"effect {token!r}: {key} needs one list per record ({len(params['k'])}), got {values!r}")
    for r, (row, amps) in enumerate(zip(values, params["amplitude_dn"])):
        if not isinstance(row, (list, tuple)) or len(row) != len(amps):
            raise ValueError(f"effect {token!r}: record {r} needs {key} as long as amplitude_dn ({len(amps)}), got {row!r}")
        for v in row:
            if not 0.0 <= _number(v, f"{token}.{key}[]") <= most:
                raise ValueError(f"effect {token!r}: {key} ({meaning}) must be in [0, {most:g}], got {v}")


def _power_at(m, f):
    """Mean over frames of |sum_Y m(Y) exp(-2 pi i f Y)|^2 / n at each frequency ``f``: (len(f),) DN^2."""
    y = np.arange(m.shape[1])
    basis = np.exp(-2j * np.pi * np.outer(f, y))
    return (np.abs(m @ basis.T) ** 2).mean(axis=0) / m.shape[1]


def _tone_amplitude(raw, f: float, noise: float) -> tuple[float, float]:
    """(amplitude in DN, share of frames on) of a tone at ``f`` in the frames' sensor-line means
    ``raw`` (N, n): ``tone_presence`` of each frame's Fourier coefficient there."""
    return tone_presence(raw @ np.exp(-2j * np.pi * f * np.arange(raw.shape[1])), raw.shape[1], noise)


def _log_ring(x, centre, radius: float, sigma: float):
    """Log density (per unit area of the complex plane) of each point ``x`` under a point of a
    circle of ``radius`` about ``centre`` at a uniform angle plus complex Gaussian noise of
    ``sigma`` per component (radius 0: the noise alone about the centre)."""
    d = np.abs(x - centre)
    z = d * radius / (sigma * sigma)
    return -np.log(2 * np.pi * sigma * sigma) - (d * d + radius * radius) / (2 * sigma * sigma) + np.log(special.i0e(z)) + z


def tone_presence(x, n: float, noise: float) -> tuple[float, float]:
    """(amplitude in DN, share of frames on) of a tone from each frame's Fourier coefficient
    ``x`` (N,) over ``n`` values, ``noise`` the model's periodogram there (DN^2): a source
    switched off in some frames leaves their coefficients at the circle's centre. The mixture of
    the circle and its centre (share ``p`` on) and the circle alone are fitted by maximum
    likelihood (the noise per component at least the model's, fitted); the mixture is kept
    where twice its log-likelihood gain passes chi2(1) at ``PRESENCE_P``, else the share is 1
    and the amplitude ``circle_amplitude``'s."""
    x = np.asarray(x, dtype=np.complex128)
    circle = circle_amplitude(x, n, noise)
    if x.shape[0] < MIN_PRESENCE_FRAMES or circle <= 0:
        return circle, 1.0
    sigma0 = max(float(np.sqrt(n * noise / 2.0)), 1e-12)
    scale = max(float(np.abs(x - x.mean()).max()), sigma0)

    def nll(q, mixture: bool):
        centre, radius, sigma = (q[0] + 1j * q[1]) * scale, np.exp(q[2]) * scale, sigma0 * np.exp(abs(q[3]))
        on = _log_ring(x, centre, radius, sigma)
        if not mixture:
            return -float(on.sum())
        p = float(np.clip(special.expit(q[4]), 1e-12, 1.0 - 1e-12))
        return -float(np.logaddexp(np.log(p) + on, np.log1p(-p) + _log_ring(x, centre, 0.0, sigma)).sum())

    def fit(starts, mixture: bool):
        best = None
        for q0 in starts:
            sol = optimize.minimize(nll, q0, args=(mixture,), method="Nelder-Mead",
                                    options={"xatol": 1e-6, "fatol": 1e-9, "maxiter": 4000})
            best = sol if best is None or sol.fun < best.fun else best
        return best

    log_r = np.log(max(circle * n / 2.0, 1e-12) / scale)
    kasa = x.mean()
    one = fit([np.array([kasa.real / scale, kasa.imag / scale, log_r, 0.5])], False)
    starts = []
    for c in x:  # each frame as the centre an off frame sits at
        r = float(np.median(np.abs(x - c)[np.abs(x - c) > 0])) if np.any(np.abs(x - c) > 0) else scale
        starts.append(np.array([c.real / scale, c.imag / scale, np.log(max(r, 1e-12) / scale), 0.5, 0.0]))
    mix = fit(starts, True)
    share = float(special.expit(mix.x[4]))
    if 2.0 * (one.fun - mix.fun) <= stats.chi2.isf(PRESENCE_P, 1) or share >= 1.0:
        return circle, 1.0
    return float(2.0 * np.exp(mix.x[2]) * scale / n), share


def circle_amplitude(x, n: float, noise: float, coherent: float | None = None) -> float:
    """Amplitude (DN) of a tone from each frame's Fourier coefficient ``x`` (N,) over ``n``
    values: the coefficients lie on a circle, its centre what is the same in every frame (a
    fixed pattern), its radius n a / 2 (the tone, its phase new in every frame). The circle is
    fitted by least squares (Kasa); the noise power ``noise`` (DN^2, a periodogram value) adds
    n * noise to the squared radius and is taken off. Under a window w, ``n`` is sum(w^2) (the
    noise's gain) and ``coherent`` sum(w) (the tone's; default n). With two frames the radius is
    |X_1 - X_2| / sqrt(2); with one, |X_1|. At Nyquist (real X_b = n a cos(phase)) the squared
    radius is half the variance of X_b over the frames."""
    x = np.asarray(x)
    n_frames = x.shape[0]
    if n_frames >= 2 and np.abs(x.imag).max() <= 1e-9 * max(float(np.abs(x).max()), 1e-30):
        # at Nyquist the coefficient is real, a cos(phase) n: the points lie on a line, not a circle
        r2 = float(np.var(x.real, ddof=1)) / 2.0 - n * noise / 2.0 + n * noise  # var = 2 (n a / 2)^2 + n noise
    elif n_frames >= 3:
        design = np.stack([2 * x.real, 2 * x.imag, np.ones(n_frames)], axis=1)
        (cx, cy, d), *_ = np.linalg.lstsq(design, np.abs(x) ** 2, rcond=None)
        r2 = d + cx * cx + cy * cy
    elif n_frames == 2:
        r2 = float(np.abs(x[0] - x[1]) ** 2) / 2.0
    else:
        r2 = float(np.abs(x[0]) ** 2)  # one frame: a fixed part cannot be told apart
    r2 -= n * noise
    return 2.0 * np.sqrt(r2) / (n if coherent is None else coherent) if r2 > 0 else 0.0


def line_tones(m, m_model) -> tuple[list[float], list[float], list[float], list[float]]:
    """(frequencies in cycles per sensor line, amplitudes in DN, shares of frames on, sds of
    the frequency over frames (``frequency_wander``; its frames' amplitudes at their own peaks)) of the tones in each frame's
    sensor-line means ``m`` (N, n; rows or columns) that the model's (``m_model``: one such
    array per synthesis) lacks. Tones are taken one at a time, strongest first, each removed
    from every frame's line means (least squares) before the next is looked for, so a tone's
    leakage is not taken for another."""
    f, _ = line_tone_spectrum(m)
    # the model's spectrum, smoothed over SMOOTH bins (it has no tone: its shape is smooth)
    model = ndimage.median_filter(np.mean([line_tone_spectrum(mm)[1] for mm in m_model], axis=0), size=SMOOTH, mode="nearest")
    n_frames, n = m.shape
    # a bin's power over N frames has 2 N degrees of freedom; the model's, over its syntheses'
    # frames and SMOOTH bins, many more: their ratio is F-distributed. A tone is narrow: the bin
    # must also stand out of the running median of its LOCAL neighbours (about LOCAL N degrees
    # of freedom), which a smooth field's leakage or a broad excess moves with it
    threshold = stats.f.isf(FAMILY_P / len(f), 2 * n_frames, 2 * sum(len(mm) for mm in m_model) * SMOOTH)
    narrow = stats.f.isf(FAMILY_P / len(f), 2 * n_frames, n_frames * LOCAL)
    step = 1.0 / n
    y = np.arange(n)
    tones, amps, shares, sds = [], [], [], []
    m = np.array(m, dtype=np.float64)
    while len(tones) < L.BAND_TONES:
        measured = _power_at(m, f)
        local = ndimage.median_filter(measured, size=LOCAL, mode="mirror")
        over = np.where(measured > narrow * local, measured / np.maximum(model, 1e-30), 0.0)
        i = int(np.argmax(over))
        if over[i] <= threshold:
            break
        grid = np.clip(f[i] + step * np.linspace(-1, 1, 81), f[0], 0.5)  # not into the low band
        best = float(grid[int(np.argmax(_power_at(m, grid)))])
        noise = float(np.mean([_power_at(mm, [best])[0] for mm in m_model]))  # the model's power there, DN^2
        sd, peaks, frame_amps = frequency_wander(m, best, noise, f[0])
        if sd > 0:  # each frame's tone at its own frequency, the tone's the frames' mean
            amplitude, share, best = float(np.sqrt(np.mean(frame_amps ** 2))), 1.0, float(np.mean(peaks))
        else:
            amplitude, share = _tone_amplitude(m, best, noise)
            peaks = np.full(n_frames, best)
        if amplitude <= 0:
            break
        tones.append(best)
        amps.append(float(amplitude))
        shares.append(share)
        sds.append(sd)
        for b, fb in enumerate(peaks):
            basis = np.stack([np.cos(2 * np.pi * fb * y), np.sin(2 * np.pi * fb * y)], axis=1)
            coef, *_ = np.linalg.lstsq(basis, m[b], rcond=None)
            m[b] = m[b] - basis @ coef
    return tones, amps, shares, sds


def frequency_wander(m, f0: float, noise: float, low: float):
    """(sd of the tone's frequency over frames, cycles per line; each frame's peak frequency
    (N,); each frame's amplitude there, DN) of a tone near ``f0`` in the line means ``m`` (N, n),
    ``noise`` the model's periodogram there (DN^2), ``low`` the low band's edge: each frame's
    peak within JITTER_WINDOW bins (a grid of 1/8 bin, refined by a parabola). The sd is kept
    where at least CLEAR_SHARE of the frames show their peak clearly (above the noise's largest
    of the window's bins at p 1e-3), the peaks' variance over those passes the Cramer-Rao
    variance of a frequency estimate (6 noise / ((2 pi a)^2 n (n^2 - 1)), a the tone) plus the
    grid's at JITTER_P (chi2), and the sd is at least a quarter bin; else 0."""
    n_frames, n = m.shape
    step = 1.0 / (8 * n)
    grid = np.clip(f0 + step * np.arange(-8 * JITTER_WINDOW, 8 * JITTER_WINDOW + 1), low, 0.5)
    power = np.abs(m @ np.exp(-2j * np.pi * np.outer(grid, np.arange(n))).T) ** 2 / n  # (N, G), DN^2
    i = np.clip(np.argmax(power, axis=1), 1, grid.size - 2)
    rows = np.arange(n_frames)
    left, mid, right = power[rows, i - 1], power[rows, i], power[rows, i + 1]
    curve = left - 2 * mid + right
    shift = np.where(curve < 0, 0.5 * (left - right) / np.where(curve < 0, curve, -1.0), 0.0)
    peaks = grid[i] + np.clip(shift, -1.0, 1.0) * step
    frame_amps = 2.0 * np.sqrt(np.maximum(mid - noise, 0.0) / n)  # |X|^2 / n = n a^2 / 4 + noise
    clear = mid > noise * np.log((2 * JITTER_WINDOW + 1) / 1e-3)
    if clear.sum() < max(3, CLEAR_SHARE * n_frames):
        return 0.0, peaks, frame_amps
    a2 = float(np.mean(frame_amps[clear] ** 2))
    null = 6.0 * noise / ((2 * np.pi) ** 2 * a2 * n * (n * n - 1.0)) + step * step / 12.0
    s2 = float(np.var(peaks[clear], ddof=1))
    dof = int(clear.sum()) - 1
    if dof * s2 / null <= stats.chi2.isf(JITTER_P, dof) or np.sqrt(s2) < 0.25 / n:
        return 0.0, peaks, frame_amps
    return float(np.sqrt(max(s2 - null, 0.0))), peaks, frame_amps


def estimate(frames, synthesized, k: float, level_dn=None, **_) -> dict:
    """Band record at gain ``k`` from a bias or dark stack (N, 4, h, w) in DN: the tones of its
    sensor-row means (``line_tones``)."""
    frames = np.asarray(frames, dtype=np.float64)
    if level_dn is not None or not synthesized:
        raise ValueError("Band is measured on bias and dark stacks, against syntheses")
    tones, amps, shares, sds = line_tones(frame_row_means(frames), [frame_row_means(np.asarray(s, dtype=np.float64)) for s in synthesized])
    return {"k": [float(k)], "freq_per_row": [tones], "amplitude_dn": [amps], "on_share": [shares], "freq_sd": [sds],
            "frames": [int(frames.shape[0])]}


def combine(records: list[dict]) -> dict:
    return combine_tones(records, "freq_per_row")


def aligned(simulated: dict, params: dict) -> dict:
    """``simulated`` (an estimate from syntheses) with its amplitudes arranged as the tones of
    ``params`` (``rawaug.loop.clip_correction``): per K, each tone's amplitude where a tone
    within 1/200 cycle was found, else None."""
    return align_tones(simulated, params, "freq_per_row")


def align_tones(simulated: dict, params: dict, freq_key: str) -> dict:
    found = {float(k): (f, a) for k, f, a in zip(simulated["k"], simulated[freq_key], simulated["amplitude_dn"])}
    amps = []
    for k, freqs in zip(params["k"], params[freq_key]):
        f_sim, a_sim = found.get(float(k), ((), ()))
        amps.append([next((a for g, a in zip(f_sim, a_sim) if abs(g - f) < 0.005), None) for f in freqs])
    return {**simulated, "k": list(params["k"]), freq_key: params[freq_key], "amplitude_dn": amps}


def empty(params) -> bool:
    """True when a record holds no tone of nonzero amplitude: it would add nothing."""
    return not any(a for record in params["amplitude_dn"] for a in record)


def combine_tones(records: list[dict], freq_key: str) -> dict:
    """One record per gain: the tones of the first stack at that K (bias before dark), each
    one's mean power (share on x amplitude^2) and share on averaged over the stacks at that K
    that found it (within 1/200 cycle per line), weighed by the degrees of freedom of each
    stack's circle fit (``frames`` - 3: a circle through 4 frames' coefficients is far less
    certain than one through 8; equal weights where none has more than 3 frames); the
    amplitude is that power over the share, a wandering frequency's variance pooled alike. ``on_share`` is kept where some tone is off in a
    share of the frames."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r)
    ks = sorted(by_k)
    freqs, amps, shares, sds = [], [], [], []
    for k in ks:
        first = by_k[k][0]
        freqs.append(list(first[freq_key][0]))
        row, row_share, row_sd = [], [], []
        for f in first[freq_key][0]:
            found = [(a, p, d, max(r.get("frames", [4])[0] - 3, 0)) for r in by_k[k]
                     for g, a, p, d in zip(r[freq_key][0], r["amplitude_dn"][0],
                                           (r.get("on_share") or [[]])[0] or [1.0] * len(r[freq_key][0]),
                                           (r.get("freq_sd") or [[]])[0] or [0.0] * len(r[freq_key][0]))
                     if abs(g - f) < max(0.005, 3.0 * d)]  # a wandering tone's stacks find it where their frames put it
            a, p, d, w = (np.array(v, dtype=np.float64) for v in zip(*found))
            w = w if w.sum() > 0 else np.ones_like(w)
            share = float(np.average(p, weights=w))
            row.append(float(np.sqrt(np.average(p * a * a, weights=w) / share)) if share > 0 else 0.0)
            row_share.append(share)
            row_sd.append(float(np.sqrt(np.average(d * d, weights=w))))  # the variances pooled
        amps.append(row)
        shares.append(row_share)
        sds.append(row_sd)
    out = {"k": ks, freq_key: freqs, "amplitude_dn": amps}
    if any(v < 1.0 for row in shares for v in row):
        out["on_share"] = shares
    if any(v > 0.0 for row in sds for v in row):
        out["freq_sd"] = sds
    return out
