"""Dark current (Dark): thermally generated electrons, growing with exposure time, with their
shot noise and their pixel-to-pixel non-uniformity (DSNU), as EMVA 1288 measures them.

Physics: every pixel collects ``rate * t`` electrons in the dark during an exposure of ``t``
seconds; they are Poisson like photo-electrons (so their shot noise comes from the shot
stage), and the rate differs from pixel to pixel (a fixed pattern whose spread grows with
``t``: DSNU). The ELD paper lumps dark current into the read noise of its short bias frames;
dark frames at longer exposures show it apart.

Stage (DN, before shot noise): ``s -> s + K * dark_e * f_c * exp(b g - b^2 / 2)`` with
``dark_e = rate(K) * exposure_s`` electrons, ``f_c`` the relative rate of the pixel's colour
channel (the pixels of a 2x2 tile differ in layout: a shared readout, a transfer gate on
another side; mean 1 over R, G1, B, G2, 1 each when the entry has none), ``g`` a standard-normal map keyed by the
profile's seed and the pixel position and ``b = sqrt(log(1 + dsnu^2))``: a log-normal rate
map of mean 1 and relative spread ``dsnu``. Dark current is skewed (a few pixels leak far
more than most), and a rate is never negative. Optionally (``col_dsnu``) the rate has a
factor per sensor column too, log-normal of mean 1 and relative spread ``col_dsnu`` (keyed by
the sensor column): column DSNU, a column's own leakage or a process gradient across the
columns, dense where ``DarkCol``'s leaky columns are few; and (``row_dsnu``, since the
thirty-third session) a factor per sensor row, alike: a row driver's or reset line's own
leakage, dense where ``DarkRow``'s leaky rows are few. The exposure is a synthesis setting
(``RawNoiseAugment(fixed={"exposure_s": t})``, default 0: no dark signal).

Profile entry (per-K records, nearest record in log K)::

    Dark: {seed: 19, k: [K, ...], rate_e_per_s: [...], dsnu: [...], col_dsnu: [...], row_dsnu: [...],
           channel: [f_R, f_G1, f_B, f_G2]}

(``channel`` optional: one set for the camera, a property of the pixels' layout; ``col_dsnu``
and ``row_dsnu`` optional, 0 by default.)

Detected on dark stacks (``FrameStack(kind="dark", exposure_s=t)``, synthesized with the
offsets and read noise of the bias frames of the same ISO) by ``mean_dn`` (the dark signal),
``temporal_std`` (its shot noise), ``fixed_std`` and ``fixed_pixel_var`` (DSNU), ``fixed_col_excess`` (column
DSNU), ``fixed_row_excess`` (row DSNU). Estimated by ``estimate``: the
mean excess over the model gives the rate, the excess white fixed-pattern variance
(``fixed_pixel_var``: the dark shot noise left in an N-frame mean, ``Glow`` and ``FPN``
shading cancel) gives DSNU, solved for through the same statistic (``log_normal_spread``:
it leaves out a heavy tail's far cells), and each channel's mean excess over their mean its
relative rate (``combine``: averaged over the stacks, weighted by their signal); the column
DSNU from the spread of the sensor columns' relative dark signal less what their pixels' spread
leaves in a column mean, kept where a chi-square test of the columns passes p 1e-3
(``column_spread``), the row DSNU alike from the sensor rows (``row_spread``).
"""
from __future__ import annotations

import math

import numpy as np
import torch
from scipy import optimize, stats

from ..engine import layout as L
from ..engine.layout import COLUMN_SET, ROW_SET
from ..statistics import fixed_pixel_var
from .base import PHOTON, NoiseEffect, pattern_key, register
from .k_records import check_seed, validate_records, value_at_k

STATISTICS = ("mean_dn", "temporal_std", "fixed_std", "fixed_pixel_var", "fixed_col_excess", "fixed_row_excess")
COLUMN_P = 1e-3  # a column pattern of the dark signal counts where pixels alone make one as large less often
AMPLITUDES = ("rate_e_per_s", "dsnu")  # corrected by simulation under a clip (rawaug.loop.clip_correction)


@register
class DarkCurrent(NoiseEffect):
    token = "Dark"
    order = PHOTON + 5
    flag = L.DARK_CURRENT
    columns = ("dark_e", "dsnu_log", "dark_c0", "dark_c1", "dark_c2", "dark_c3", "dsnu_col_log", "dsnu_row_log")
    exposure = True

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        exposure = ctx.fixed.get("exposure_s", 0.0)
        exposure = torch.as_tensor(exposure, dtype=torch.float64, device=ctx.device).expand(ctx.batch)
        dsnu = value_at_k(p, "dsnu", ctx.k)
        out = {"dark_e": value_at_k(p, "rate_e_per_s", ctx.k) * exposure, "dsnu_log": torch.sqrt(torch.log1p(dsnu * dsnu))}
        col = value_at_k(p, "col_dsnu", ctx.k) if "col_dsnu" in p else torch.zeros_like(ctx.k)
        out["dsnu_col_log"] = torch.sqrt(torch.log1p(col * col))
        row = value_at_k(p, "row_dsnu", ctx.k) if "row_dsnu" in p else torch.zeros_like(ctx.k)
        out["dsnu_row_log"] = torch.sqrt(torch.log1p(row * row))
        for c, f in enumerate(p.get("channel", (1.0,) * 4)):
            out[f"dark_c{c}"] = ctx.k.new_full((ctx.batch,), float(f))
        return out

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"dsnu_pattern": pattern_key(seed, self.token), "dsnu_col_pattern": pattern_key(seed, self.token, "column"),
                "dsnu_row_pattern": pattern_key(seed, self.token, "row")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("rate_e_per_s", "dsnu"), nonnegative=("rate_e_per_s", "dsnu"))
        for key in ("col_dsnu", "row_dsnu"):
            if key in params:
                validate_records(cls.token, params, (key,), nonnegative=(key,))
        check_seed(cls.token, params)
        if "channel" in params:
            f = params["channel"]
            ok = isinstance(f, (list, tuple)) and len(f) == 4 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                                      and math.isfinite(x) and x >= 0 for x in f)
            if not ok or abs(sum(f) / 4.0 - 1.0) > 1e-6:
                raise ValueError(f"effect {cls.token!r}: channel (relative dark rates of R, G1, B, G2) must be 4 numbers "
                                 f">= 0 with mean 1, got {f!r}")


def estimate(frames, synthesized, k: float, exposure_s=None, seed: int = 19, kind: str = "dark", **_) -> dict:
    """Dark-current record at gain ``k`` from a dark stack (N >= 2, 4, h, w) in DN of
    ``exposure_s`` seconds and stacks of the same shape synthesized by the current model. A
    flat's exposure carries light: its excess is not dark current."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "dark" or not exposure_s or frames.shape[0] < 2:
        raise ValueError("Dark needs a dark stack of >= 2 frames and its exposure_s")
    base = [np.asarray(s, dtype=np.float64) for s in synthesized]
    channel_dn = frames.mean(axis=(0, 2, 3)) - np.mean([s.mean(axis=(0, 2, 3)) for s in base], axis=0)
    signal_dn = float(channel_dn.mean())
    if signal_dn <= 0:
        return {"seed": int(seed), "k": [float(k)], "rate_e_per_s": [0.0], "dsnu": [0.0], "channel": [1.0] * 4,
                "signal_dn": 0.0}
    channel = np.maximum(channel_dn, 0.0)
    channel = channel / channel.mean()
    # the white fixed spread over the model's: its dark shot noise, glow and shading cancel
    excess = fixed_pixel_var(frames) - float(np.mean([fixed_pixel_var(s) for s in base]))
    dsnu = log_normal_spread(excess, base[0], signal_dn / k * channel[:, None, None], k)
    mean_map = frames.mean(axis=0) - np.mean([s.mean(axis=0) for s in base], axis=0)
    return {"seed": int(seed), "k": [float(k)], "rate_e_per_s": [signal_dn / (k * float(exposure_s))], "dsnu": [dsnu],
            "col_dsnu": [column_spread(mean_map, channel_dn, frames, base)],
            "row_dsnu": [row_spread(mean_map, channel_dn, frames, base)],
            "channel": [float(f) for f in channel], "signal_dn": signal_dn}


def _line_means(frames, channel_dn, chans, rows: bool):
    """(N, lines) each frame's sensor-line means of the channels ``chans`` (one line set),
    each channel relative to its mean dark signal ``channel_dn``."""
    return np.mean([np.asarray(frames[:, c], dtype=np.float64).mean(axis=2 if rows else 1) / channel_dn[c] for c in chans], axis=0)


def _line_spread(signal_map, channel_dn, rows: bool, frames=None, base=()) -> float:
    """Relative spread (sd over mean) of the sensor columns' (with ``rows``, the sensor rows')
    factors on a dark signal, from its map (4, h, w; DN) and each channel's mean (4,): the
    variance of the lines' means of the map relative to its channel's mean (a sensor line: its
    packed channels, all pixels along it) less what their pixels' own spread leaves in a mean
    and, with the stack ``frames`` and the model's stacks ``base`` the map was measured from,
    what the lines' temporal offsets (row or column noise) leave in the means of both; 0 unless
    the lines' chi-square against that passes ``COLUMN_P``. Channels with a quarter of the
    strongest one's signal or less are left out (a colour without dark current has no line
    factor to show), and with them the lines of a line set that keeps none."""
    channel_dn = np.asarray(channel_dn, dtype=np.float64)
    shown = channel_dn > 0.25 * channel_dn.max()
    sets = ROW_SET if rows else COLUMN_SET
    means, noise = [], []
    for line_set in (0, 1):
        chans = [c for c in range(4) if sets[c] == line_set and shown[c]]
        if not chans:
            continue
        pixels = np.concatenate([(signal_map[c].T if rows else signal_map[c]) / channel_dn[c] for c in chans], axis=0)
        means.append(pixels.mean(axis=0))  # (lines,): along its pixels
        v = pixels.var(axis=0, ddof=1) / pixels.shape[0]
        for stack, share in ([(frames, 1.0)] if frames is not None else []) + [(b, 1.0 / len(base)) for b in base]:
            if stack.shape[0] > 1:  # the lines' temporal offsets left in the stack's mean (the map's or the model's),
                t = _line_means(stack, channel_dn, chans, rows)  # pooled over the lines (a line's own has N - 1 degrees)
                v = v + share * share * float(t.var(axis=0, ddof=1).mean()) / t.shape[0]
        noise.append(v)
    f, v = np.concatenate(means), np.concatenate(noise)
    chi2 = float(np.sum((f - f.mean()) ** 2 / np.maximum(v, 1e-300)))
    if stats.chi2.sf(chi2, f.size - 1) >= COLUMN_P:
        return 0.0
    return float(math.sqrt(max(f.var(ddof=1) - v.mean(), 0.0)) / max(f.mean(), 1e-12))


def column_spread(signal_map, channel_dn, frames=None, base=()) -> float:
    """Column DSNU: the relative spread of the sensor columns' factors (``_line_spread``)."""
    return _line_spread(signal_map, channel_dn, False, frames, base)


def row_spread(signal_map, channel_dn, frames=None, base=()) -> float:
    """Row DSNU: the relative spread of the sensor rows' factors (``_line_spread``)."""
    return _line_spread(signal_map, channel_dn, True, frames, base)


DSNU_MAX = 20.0  # relative spread searched up to (log-normal b = 2.45)


def log_normal_spread(excess_dn2: float, base, signal_e, k: float, seed: int = 0) -> float:
    """Relative spread ``dsnu`` of a log-normal rate map of mean ``signal_e`` electrons (a
    number, or per channel (4, 1, 1)) whose
    ``fixed_pixel_var`` excess over the stack ``base`` (N, 4, h, w) in DN is ``excess_dn2``.
    ``fixed_pixel_var`` leaves out cells beyond ``OUTLIER_SIGMAS`` robust sigmas, and a
    log-normal's tail reaches there (a sigma of 0.8 in log loses a third of its variance):
    the map is planted on ``base`` with its shot noise (Gaussian, common random numbers) and
    its spread solved for, so that the excess is measured as the frames' was."""
    if excess_dn2 <= 0.0 or not np.mean(signal_e) > 0.0:
        return 0.0
    rng = np.random.default_rng(seed)
    g = rng.standard_normal(base.shape[1:])
    z = rng.standard_normal(base.shape)
    floor = fixed_pixel_var(base)

    def excess_of(b):
        lam = signal_e * np.exp(b * g - 0.5 * b * b)
        return fixed_pixel_var(base + k * (lam + np.sqrt(lam) * z)) - floor - excess_dn2

    # the trimmed excess rises with b, then falls once most of the tail is left out: the
    # smallest root, on a grid in b first
    grid = np.linspace(0.0, math.sqrt(math.log1p(DSNU_MAX**2)), 13)
    values = [excess_of(grid[0])]
    if values[0] >= 0.0:
        return 0.0
    for lo, hi in zip(grid[:-1], grid[1:]):
        values.append(excess_of(hi))
        if values[-1] >= 0.0:
            b = optimize.brentq(excess_of, lo, hi, xtol=1e-4)
            return float(math.sqrt(math.expm1(b * b)))
    b = grid[int(np.argmax(values))]  # more than any log-normal leaves: the spread that leaves most
    return float(math.sqrt(math.expm1(b * b)))


def combine(records: list[dict]) -> dict:
    """One record per gain: the rate and DSNU of the stacks at one K (several exposures)
    averaged, weighted by nothing but their count; one set of relative channel rates for the
    camera, the stacks' weighted by their dark signal (DN)."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(r["k"][0], []).append(r)
    ks = sorted(by_k)
    out = {"seed": records[0]["seed"], "k": ks,
           "rate_e_per_s": [float(np.mean([r["rate_e_per_s"][0] for r in by_k[k]])) for k in ks],
           "dsnu": [float(np.mean([r["dsnu"][0] for r in by_k[k]])) for k in ks]}
    for key in ("col_dsnu", "row_dsnu"):
        line = [float(np.mean([r.get(key, [0.0])[0] for r in by_k[k]])) for k in ks]
        if any(line):
            out[key] = line
    weights = np.array([max(float(r.get("signal_dn", 0.0)), 0.0) for r in records])
    if weights.sum() > 0.0:
        channel = np.average([r.get("channel", [1.0] * 4) for r in records], axis=0, weights=weights)
        out["channel"] = [float(f) for f in channel / channel.mean()]
    return out
