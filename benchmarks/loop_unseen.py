"""The loop on cameras with one effect made outside rawaug, each through `rawaug loop` end to end.

Each camera is the SonyA7S2 ELD model (another ELD camera with ``--base``; NikonD850's black level
is 0, so its files clip the read noise at code 0) at two ISOs (K 0.75 and 3.0 DN/e-), as a manifest of
6 bias frames, 4 dark frames of 4 s and flat pairs at 2 % and 10 % of white (64 x 64 packed
per channel, 16-bit, the base camera's black and white levels; ``rawaug.calibration.synthetic.write_manifest_camera``), plus
one effect written here in NumPy, not by a rawaug stage. Printed per camera: what the loop added, each added step's evidence error before ->
after, and what stayed significant. A camera counts as fixed when the loop added something
whose evidence error fell to half or less and nothing significant was left; a camera whose
right answer is to add nothing (``NOTHING_TO_ADD``) when nothing was added and nothing left.

    python benchmarks/loop_unseen.py [CASE ...] [--seed S] [--sessions N] [--geometry small|issue] [--base CAMERA] [--keep DIR]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from rawaug import NoiseProfile
from rawaug.calibration.synthetic import write_manifest_camera
from rawaug.cli import main as cli

BASE = "SonyA7S2"  # the ELD camera each test camera starts from (--base)


def _raw_to_packed(raw):
    return np.stack([raw[0::2, 0::2], raw[0::2, 1::2], raw[1::2, 1::2], raw[1::2, 0::2]])  # R, G1, B, G2 (RGGB)


def coupled_readout(dn, rng, **_):
    """Read noise coupled between raw neighbours: 1.5 DN plus 0.6 of the left and 0.4 of the upper neighbour's."""
    _, h, w = dn.shape
    n = rng.normal(0.0, 1.5, (2 * h + 1, 2 * w + 1))
    return dn + _raw_to_packed(n[1:, 1:] + 0.6 * n[1:, :-1] + 0.4 * n[:-1, 1:])


def shared_pixel(dn, rng, **_):
    """A 2x2 shared-pixel readout: the four pixels of a Bayer tile share 1.5 DN of read noise."""
    return dn + rng.normal(0.0, 1.5, dn.shape[1:])[None]


def tone(dn, rng, **_):
    """Interference during readout: 1.2 DN at 0.0813 cycles per sensor row, a phase per frame."""
    h = dn.shape[1]
    t = 1.2 * np.cos(2 * np.pi * 0.0813 * np.arange(2 * h) + rng.uniform(0, 2 * np.pi))
    return dn + np.stack([t[0::2], t[0::2], t[1::2], t[1::2]])[:, :, None]


def two_tones(dn, rng, **_):
    """Two interference tones, 1.0 and 0.7 DN at 0.19 and 0.41 cycles per sensor row."""
    h = dn.shape[1]
    y = np.arange(2 * h)
    t = sum(a * np.cos(2 * np.pi * f * y + rng.uniform(0, 2 * np.pi)) for a, f in ((1.0, 0.19), (0.7, 0.41)))
    return dn + np.stack([t[0::2], t[0::2], t[1::2], t[1::2]])[:, :, None]


_WALK: dict = {}  # black_drift's level, per frame generator (cleared for every camera)


def black_drift(dn, rng, **_):
    """The black level drifting as a random walk, 1 DN per frame."""
    _WALK[id(rng)] = _WALK.get(id(rng), 0.0) + rng.normal(0.0, 1.0)
    return dn + _WALK[id(rng)]


def telegraph(dn, rng, **_):
    """Random telegraph pixels: 1 % of the pixels jump by +20 DN in about half the frames."""
    where = np.random.default_rng(99).random(dn.shape) < 0.01
    return dn + 20.0 * (where & (rng.random(dn.shape) < 0.5))


def channel_read(dn, rng, **_):
    """One green channel reads 3 DN noisier (an amplifier of its own)."""
    out = dn.copy()
    out[1] += rng.normal(0.0, 3.0, dn.shape[1:])
    return out


def split_readout(dn, rng, **_):
    """Two readout amplifiers: the right half of the columns has 2.5 DN more read noise."""
    out = dn.copy()
    w = dn.shape[2]
    out[:, :, w // 2:] += rng.normal(0.0, 2.5, out[:, :, w // 2:].shape)
    return out


def parity_rows(dn, rng, **_):
    """Row noise of its own per column parity (two ADC banks): 1.5 DN per channel row and frame."""
    return dn + rng.normal(0.0, 1.5, (dn.shape[0], dn.shape[1], 1))


def fixed_rows(dn, rng, **_):
    """A fixed row pattern: 1.5 DN per sensor row, the same in every frame."""
    r = np.random.default_rng(7).normal(0.0, 1.5, (2, dn.shape[1], 1))
    return dn + r[[0, 0, 1, 1]]


def column_tone(dn, rng, **_):
    """Interference along the sensor columns: 1.2 DN at 0.093 cycles per sensor column, a phase per frame."""
    w = dn.shape[2]
    t = 1.2 * np.cos(2 * np.pi * 0.093 * np.arange(2 * w) + rng.uniform(0, 2 * np.pi))
    return dn + np.stack([t[0::2], t[1::2], t[1::2], t[0::2]])[:, None, :]  # R, G2 on even sensor columns


def dead_pixels(dn, rng, **_):
    """Dead pixels: 0.2 % of the pixels (fixed) read 40 DN below black."""
    where = np.random.default_rng(5).random(dn.shape) < 0.002
    return np.where(where, -40.0, dn)


def row_flicker(dn, rng, **_):
    """Row noise with a 1/f spectrum along the sensor rows (a drifting reference): 1.5 DN rms, new in every frame."""
    h = dn.shape[1]
    f = np.fft.rfftfreq(2 * h)
    amp = np.where(f > 0, 1.0 / np.sqrt(np.maximum(f, 1e-9)), 0.0)
    spec = amp * (rng.normal(size=f.size) + 1j * rng.normal(size=f.size))
    r = np.fft.irfft(spec, n=2 * h)
    r *= 1.5 / r.std()
    return dn + np.stack([r[0::2], r[0::2], r[1::2], r[1::2]])[:, :, None]


def adc_dnl(dn, rng, **_):
    """ADC differential non-linearity: codes 4k + 3 never written, their inputs read as 4k + 2 or 4k + 4."""
    q = np.floor(dn + 0.5)
    low = (q % 4) == 3
    return np.where(low, q + np.where(rng.random(dn.shape) < 0.5, -1.0, 1.0), q)


def column_gain(dn, rng, **_):
    """Column amplifiers' gain mismatch: each sensor column's gain off by 0.5 % rms (fixed), so flats show a column pattern in proportion to the signal and bias frames none."""
    g = 1.0 + np.random.default_rng(11).normal(0.0, 0.005, 2 * dn.shape[2])
    return dn * np.stack([g[0::2], g[1::2], g[1::2], g[0::2]])[:, None, :]  # R, G2 on even sensor columns


def dark_hot_pixels(dn, rng, exposure=0.0, k=1.0, **_):
    """Hot pixels of dark current: 0.3 % of the pixels (fixed) collect 40 e-/s more, with its shot noise, so they grow with exposure and bias frames show none."""
    where = np.random.default_rng(13).random(dn.shape) < 0.003
    return dn + where * k * rng.poisson(40.0 * exposure, dn.shape)


def diagonal_tone(dn, rng, **_):
    """Interference not locked to the line rate in a serial readout: 1.0 DN at 0.11 cycles per sensor column whose phase advances 0.23 cycles per sensor row (diagonal stripes), a phase per frame."""
    _, h, w = dn.shape
    y, x = np.arange(2 * h)[:, None], np.arange(2 * w)[None, :]
    t = 1.0 * np.cos(2 * np.pi * (0.11 * x + 0.23 * y) + rng.uniform(0, 2 * np.pi))
    return dn + np.stack([t[0::2, 0::2], t[0::2, 1::2], t[1::2, 1::2], t[1::2, 0::2]])


def green_imbalance(dn, rng, **_):
    """Green imbalance: G2's analog gain 3 % above G1's, on the signal and on the read noise alike (6 % more read-noise variance: ReadMap)."""
    return dn * np.array([1.0, 1.0, 1.0, 1.03])[:, None, None]


def leaky_columns(dn, rng, exposure=0.0, k=1.0, **_):
    """Leaky columns: sensor columns 37 and 90 collect 15 e-/s more dark current, Poisson, so they show in long exposures and not in bias frames."""
    leaky = np.isin(np.arange(2 * dn.shape[2]), (37, 90))
    cols = np.stack([leaky[0::2], leaky[1::2], leaky[1::2], leaky[0::2]])[:, None, :]  # R, G2 on even sensor columns
    return dn + cols * k * rng.poisson(15.0 * exposure, dn.shape)


def clamp_sag(dn, rng, exposure=0.0, **_):
    """The black clamp sags in long exposures: the black level of 4 s frames 3 DN below that of bias frames (a negative dark signal)."""
    return dn - 3.0 * min(exposure / 4.0, 1.0)


def gain_jitter(dn, rng, **_):
    """Analog gain jitter: each frame's gain off by 0.3 % rms (signal and noise alike), so flat means vary in proportion to their level."""
    return dn * (1.0 + rng.normal(0.0, 0.003))


def coarse_adc(dn, rng, **_):
    """A 12-bit ADC in a 14-bit container: every code a multiple of 4 DN (the camera writes only those)."""
    return 4.0 * np.floor(dn / 4.0 + 0.5)


def impulses(dn, rng, **_):
    """Impulsive noise (cosmic rays, charge bursts): 0.05 % of the pixels of every frame, at new places each frame, 30-200 DN brighter."""
    hit = rng.random(dn.shape) < 5e-4
    return dn + hit * rng.uniform(30.0, 200.0, dn.shape)


def column_flicker(dn, rng, **_):
    """Column telegraph noise: sensor columns 21, 58, 77 and 110 sit 4 DN high or low, a new choice in every frame."""
    w = dn.shape[2]
    flick = np.isin(np.arange(2 * w), (21, 58, 77, 110))
    step = flick * np.where(rng.random(2 * w) < 0.5, 4.0, -4.0)
    return dn + np.stack([step[0::2], step[1::2], step[1::2], step[0::2]])[:, None, :]  # R, G2 on even sensor columns


def reset_transient(dn, rng, **_):
    """A reset transient: the first sensor rows of every frame read high, 6 DN decaying over 4 rows (the same in every frame)."""
    h = dn.shape[1]
    y = np.arange(2 * h)
    rows = 6.0 * np.exp(-y / 4.0)
    return dn + np.stack([rows[0::2], rows[0::2], rows[1::2], rows[1::2]])[:, :, None]  # R, G1 on even sensor rows


def noisy_frames(dn, rng, **_):
    """Supply noise of its own level in every frame: 1.5 DN of white noise times a per-frame factor drawn from 0.2 to 2."""
    return dn + rng.uniform(0.2, 2.0) * rng.normal(0.0, 1.5, dn.shape)


# 2026-11-26: a fresh batch, written before the loop ran on any of them.

def _packed_to_raw(dn):
    """The raw mosaic (2h, 2w) of a packed frame (4, h, w): R, G1, B, G2 at their RGGB places."""
    _, h, w = dn.shape
    raw = np.empty((2 * h, 2 * w))
    for i, (r, c) in enumerate(((0, 0), (0, 1), (1, 1), (1, 0))):
        raw[r::2, c::2] = dn[i]
    return raw


def _raw_mask_to_packed(mask):
    return np.stack([mask[0::2, 0::2], mask[0::2, 1::2], mask[1::2, 1::2], mask[1::2, 0::2]])  # R, G1, B, G2 (RGGB)


def _thin(dn, keep, rng, k):
    """A photo signal thinned to the fraction ``keep`` (binomially, so its shot noise stays Poisson)."""
    electrons = np.maximum(np.rint(dn / k), 0).astype(np.int64)
    return dn - k * rng.binomial(electrons, 1.0 - keep)


def pdaf_pixels(dn, rng, kind="", k=1.0, **_):
    """Phase-detection AF pixels: on every 12th sensor row every 8th sensor column is half masked and collects half the light (fixed), so flats show a grid of dim pixels and bias frames none."""
    if kind != "flat":
        return dn
    _, h, w = dn.shape
    y, x = np.arange(2 * h)[:, None], np.arange(2 * w)[None, :]
    af = _raw_mask_to_packed((y % 12 == 6) & (x % 8 == 3))
    return np.where(af, _thin(dn, 0.5, rng, k), dn)


def row_gain(dn, rng, **_):
    """Row gain mismatch: each sensor row's gain off by 0.4 % rms (fixed: row drivers, transfer gates), so flats show a row pattern in proportion to the signal and bias frames none."""
    g = 1.0 + np.random.default_rng(17).normal(0.0, 0.004, 2 * dn.shape[1])
    return dn * np.stack([g[0::2], g[0::2], g[1::2], g[1::2]])[:, :, None]  # R, G1 on even sensor rows


def charge_sharing(dn, rng, kind="", **_):
    """Charge diffusion: in flats each pixel's charge spreads 3 % to each of its four raw neighbours, so flat noise is correlated between neighbours and its variance falls below the Poisson one; bias frames show nothing."""
    if kind != "flat":
        return dn
    _, h, w = dn.shape
    raw = _packed_to_raw(dn)
    p = np.pad(raw, 1, mode="reflect")
    raw = 0.88 * raw + 0.03 * (p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:])
    return _raw_mask_to_packed(raw)


def lens_shading(dn, rng, kind="", k=1.0, **_):
    """Lens vignetting in the flats: the light falls off towards the corners (cos^4 law, 25 % darker there); bias and dark frames untouched. Illumination, not sensor noise: nothing should be added."""
    if kind != "flat":
        return dn
    _, h, w = dn.shape
    y, x = np.mgrid[0:2 * h, 0:2 * w]
    r2 = ((y - h + 0.5) ** 2 + (x - w + 0.5) ** 2) / ((h - 0.5) ** 2 + (w - 0.5) ** 2)
    keep = np.cos(np.arctan(r2 ** 0.5 * np.tan(np.arccos(0.75 ** 0.25)))) ** 4
    return _thin(dn, _raw_mask_to_packed(keep), rng, k)


def companded_raw(dn, rng, **_):
    """Lossy raw compression (a companding curve): codes step by 1 DN below 1024 DN, by 2 DN up to 4096 DN and by 4 DN above, so flats show combs of missing codes and bias frames none."""
    q = np.floor(dn + 0.5)
    step = np.where(q < 1024, 1.0, np.where(q < 4096, 2.0, 4.0))
    return step * np.floor(q / step + 0.5)


def channel_black(dn, rng, **_):
    """A black-level clamp per colour channel (four ADCs): each channel's black level moves by 0.8 DN rms from frame to frame, independently of the others."""
    return dn + rng.normal(0.0, 0.8, (4, 1, 1))


def ramp_jitter(dn, rng, **_):
    """Ramp-ADC slope jitter: each sensor row of each frame is converted with a gain off by 0.2 % rms, so flats show row noise in proportion to the signal and bias frames none."""
    g = 1.0 + rng.normal(0.0, 0.002, 2 * dn.shape[1])
    return dn * np.stack([g[0::2], g[0::2], g[1::2], g[1::2]])[:, :, None]  # R, G1 on even sensor rows


# 2026-11-27 (sixth session): a fresh batch of EMVA 1288 and defect effects, written before the
# loop ran on any of them.

def _fixed(seed, shape):
    """A fixed pattern of the sensor: the same in every frame of every setting."""
    return np.random.default_rng(seed).standard_normal(shape)


def pixel_prnu(dn, rng, kind="", **_):
    """Photo response non-uniformity: each pixel's response to light off by 1 % rms (fixed), so flats show a per-pixel pattern in proportion to the signal and bias frames none."""
    if kind != "flat":
        return dn
    return dn * (1.0 + 0.01 * _fixed(31, dn.shape))


def dark_current(dn, rng, exposure=0.0, k=1.0, **_):
    """Dark current: 1.5 e-/s in every pixel, with its shot noise, so the 4 s darks sit 6 e- above the bias and are noisier."""
    return dn + k * rng.poisson(1.5 * exposure, dn.shape)


def dsnu(dn, rng, exposure=0.0, k=1.0, **_):
    """Dark signal non-uniformity: each pixel's dark current drawn once from a lognormal around 1 e-/s (sigma 0.8 in log), with its shot noise."""
    rate = np.exp(np.log(1.0) + 0.8 * _fixed(37, dn.shape))
    return dn + k * rng.poisson(rate * exposure)


def pixel_offsets(dn, rng, **_):
    """Offset fixed pattern: each pixel's black level off by 0.8 DN rms, the same in every frame (bias, dark and flat)."""
    return dn + 0.8 * _fixed(41, dn.shape)


def column_offsets(dn, rng, **_):
    """Column offset fixed pattern: each sensor column's black level off by 0.8 DN rms, the same in every frame."""
    c = 0.8 * _fixed(43, 2 * dn.shape[2])
    return dn + np.stack([c[0::2], c[1::2], c[1::2], c[0::2]])[:, None, :]  # R, G2 on even sensor columns


def soft_knee(dn, rng, span=15871.0, **_):
    """Gain non-linearity: the response falls short of a line in proportion to the signal, 1.5 % at 10 % of white and 6 % at 40 %."""
    return dn * (1.0 - 0.15 * np.maximum(dn, 0.0) / span)


def hot_pixels(dn, rng, **_):
    """Hot pixels of offset: 0.1 % of the pixels (fixed) read 20 to 100 DN high in every frame, whatever the exposure."""
    where = np.random.default_rng(47).random(dn.shape) < 0.001
    return dn + where * np.random.default_rng(53).uniform(20.0, 100.0, dn.shape)


def black_clip(dn, rng, **_):
    """The camera clips at its black level: every value below black is written as black, so half a bias frame's values pile up at 0 DN."""
    return np.maximum(dn, 0.0)


def fixed_tone(dn, rng, **_):
    """A fixed interference pattern: 0.8 DN at 0.07 cycles per sensor row and 0.13 per sensor column, the same in every frame."""
    _, h, w = dn.shape
    y, x = np.arange(2 * h)[:, None], np.arange(2 * w)[None, :]
    t = 0.8 * np.cos(2 * np.pi * (0.07 * y + 0.13 * x) + 1.0)
    return dn + np.stack([t[0::2, 0::2], t[0::2, 1::2], t[1::2, 1::2], t[1::2, 0::2]])


def locked_tone(dn, rng, **_):
    """Interference locked to the frame start with a little timing jitter: 0.6 DN at 0.19 cycles per sensor column and -0.11 per sensor row, its phase the same in every frame up to 0.3 rad (rms) of jitter."""
    _, h, w = dn.shape
    y, x = np.arange(2 * h)[:, None], np.arange(2 * w)[None, :]
    t = 0.6 * np.cos(2 * np.pi * (0.19 * x - 0.11 * y) + 2.0 + rng.normal(0.0, 0.3))
    return dn + np.stack([t[0::2, 0::2], t[0::2, 1::2], t[1::2, 1::2], t[1::2, 0::2]])


def noisy_pixels(dn, rng, **_):
    """Noisy pixels: 0.5 % of the pixels (fixed) read with 6 DN more temporal noise (Gaussian, new in every frame), in every kind of frame."""
    where = np.random.default_rng(61).random(dn.shape) < 0.005
    return dn + where * rng.normal(0.0, 6.0, dn.shape)


def thermal_gradient(dn, rng, exposure=0.0, k=1.0, **_):
    """Dark current rising across the sensor (a warm readout chain on the right): 0.5 e-/s at the left edge to 4 e-/s at the right, with its shot noise."""
    x = np.arange(2 * dn.shape[2]) / (2 * dn.shape[2] - 1)
    rate = 0.5 + 3.5 * x
    rate = np.stack([rate[0::2], rate[1::2], rate[1::2], rate[0::2]])[:, None, :]  # R, G2 on even sensor columns
    return dn + k * rng.poisson(np.broadcast_to(rate * exposure, dn.shape))


def leaky_rows(dn, rng, exposure=0.0, k=1.0, **_):
    """Leaky rows: sensor rows 41 and 100 collect 12 e-/s more dark current, Poisson, so they show in long exposures and not in bias frames."""
    leaky = np.isin(np.arange(2 * dn.shape[1]), (41, 100))
    rows = np.stack([leaky[0::2], leaky[0::2], leaky[1::2], leaky[1::2]])[:, :, None]  # R, G1 on even sensor rows
    return dn + rows * k * rng.poisson(12.0 * exposure, dn.shape)


def dark_telegraph(dn, rng, exposure=0.0, k=1.0, **_):
    """Telegraph dark current: 0.5 % of the pixels (fixed) switch between two dark-current rates 25 e-/s apart, a state per frame (high in half the frames), with its shot noise: long exposures show two states, bias frames nothing."""
    where = np.random.default_rng(71).random(dn.shape) < 0.005
    high = rng.random(dn.shape) < 0.5
    return dn + k * rng.poisson(where * high * 25.0 * exposure)


def noisy_columns(dn, rng, **_):
    """Noisy columns: 1 % of the sensor columns (fixed) read with 4 DN more temporal noise, Gaussian, new at every pixel and frame (not a column offset)."""
    noisy = np.random.default_rng(73).random(2 * dn.shape[2]) < 0.01
    cols = np.stack([noisy[0::2], noisy[1::2], noisy[1::2], noisy[0::2]])[:, None, :]  # R, G2 on even sensor columns
    return dn + cols * rng.normal(0.0, 4.0, dn.shape)


def adc_banks(dn, rng, level=0.0, **_):
    """Four interleaved column ADCs: sensor column c read with gain 1.00, 1.012, 0.99, 1.006 (c mod 4) on the whole signal, black-subtracted."""
    gain = np.array([1.0, 1.012, 0.99, 1.006])[np.arange(2 * dn.shape[2]) % 4]
    g = np.stack([gain[0::2], gain[1::2], gain[1::2], gain[0::2]])[:, None, :]
    return dn * g


def row_telegraph(dn, rng, **_):
    """Row telegraph noise: 1 % of the sensor rows (fixed) sit 3 DN high or low, a new choice in every frame (a trap in a row driver)."""
    flick = np.random.default_rng(79).random(2 * dn.shape[1]) < 0.01
    step = flick * np.where(rng.random(2 * dn.shape[1]) < 0.5, 3.0, -3.0)
    return dn + np.stack([step[0::2], step[0::2], step[1::2], step[1::2]])[:, :, None]  # R, G1 on even sensor rows


def wide_codes(dn, rng, **_):
    """ADC differential non-linearity with wide codes: every code 8k + 4 is 1.8 codes wide, taking 0.4 of each neighbour's input range (no code missing)."""
    v = dn + 0.5  # whole codes by the floor
    q = np.floor(v)
    f, r = v - q, q % 8
    return np.where((r == 3) & (f >= 0.6), q + 1.0, np.where((r == 5) & (f < 0.4), q - 1.0, q))


def split_black(dn, rng, **_):
    """Two readout halves with a black-level clamp each: the left and the right half of the sensor columns each move by 0.7 DN rms from frame to frame, independently."""
    w = dn.shape[2]
    off = rng.normal(0.0, 0.7, 2)
    return dn + np.where(np.arange(w) < w // 2, off[0], off[1])[None, None, :]


def split_gain(dn, rng, **_):
    """Two readout amplifiers of their own gain: the right half of the sensor columns read with 1.5 % more gain, on the signal and the noise alike (black-subtracted)."""
    out = dn.copy()
    out[:, :, dn.shape[2] // 2:] *= 1.015
    return out


def top_bottom_black(dn, rng, **_):
    """A readout from both ends: the top and the bottom half of the sensor rows each with a black-level clamp of its own, moving by 0.6 DN rms from frame to frame, independently."""
    h = dn.shape[1]
    off = rng.normal(0.0, 0.6, 2)
    return dn + np.where(np.arange(h) < h // 2, off[0], off[1])[None, :, None]


def clamp_ramp(dn, rng, **_):
    """The black clamp settling during readout: each frame's black level ramps linearly down the sensor rows, by 0.8 DN rms from the top row to the bottom one, a new slope in every frame."""
    h = dn.shape[1]
    return dn + rng.normal(0.0, 0.8) * (np.arange(h) / max(h - 1, 1) - 0.5)[None, :, None]


def channel_gain(dn, rng, **_):
    """A colour channel of its own gain: the blue pixels converted with 6 % more gain than the others (a channel's own pre-gain), on the signal and the noise alike (black-subtracted)."""
    return dn * np.array([1.0, 1.0, 1.06, 1.0])[:, None, None]


def weak_columns(dn, rng, **_):
    """Weak column amplifiers: 1 % of the sensor columns (fixed) convert with 8 % less gain, on the signal and the noise alike, so flats show a few dim columns in proportion to the signal and bias frames almost nothing."""
    weak = np.random.default_rng(53).random(2 * dn.shape[2]) < 0.01
    gain = 1.0 - 0.08 * weak
    return dn * np.stack([gain[0::2], gain[1::2], gain[1::2], gain[0::2]])[:, None, :]  # R, G2 on even sensor columns


def warming_dark(dn, rng, kind="bias", exposure=0.0, k=1.0, **_):
    """A sensor warming during a dark series: its dark current starts at 1 e-/s and grows by 20 % from each dark frame to the next (with its shot noise); bias frames untouched."""
    if kind != "dark":
        return dn
    key = ("darks", id(rng), k)
    _WALK[key] = _WALK.get(key, -1.0) + 1.0
    return dn + k * rng.poisson(1.0 * 1.2 ** _WALK[key] * exposure, dn.shape)


# 2026-11-29 (nineteenth session): a fresh batch, written and committed before the loop ran on any
# of them: classic effects of a calibration engineer's list that no earlier probe planted.

def _sensor_grid(dn):
    """Sensor-pixel coordinates (y, x) of the raw mosaic behind a packed frame."""
    _, h, w = dn.shape
    return np.mgrid[0:2 * h, 0:2 * w]


def amp_glow(dn, rng, exposure=0.0, k=1.0, **_):
    """Amplifier glow: dark current from the readout amplifier in the top-right corner, 30 e-/s there and falling off as exp(-d / 48 sensor pixels), with its shot noise; bias frames show none."""
    y, x = _sensor_grid(dn)
    rate = 30.0 * np.exp(-np.hypot(y, x - x.max()) / 48.0)
    return dn + k * rng.poisson(_raw_to_packed(rate) * exposure)


_MISSING = np.random.default_rng(71).random(40000) < 0.05  # codes -8000 .. 31999 DN
_WRITTEN = np.minimum.accumulate(np.where(_MISSING, 40000, np.arange(40000))[::-1])[::-1] - 8000  # next code written


def random_missing_codes(dn, rng, **_):
    """ADC differential non-linearity without a period: 5 % of the codes (a fixed random set) never written, their inputs read as the next code up."""
    return _WRITTEN[(np.floor(dn + 0.5) + 8000).astype(np.int64)].astype(float)


def defect_couplets(dn, rng, **_):
    """Couplet defects: 0.03 % of the sensor pixels (fixed) start a pair of hot pixels with their right-hand neighbour, each of the two 25 to 60 DN high in every frame."""
    _, h, w = dn.shape
    g = np.random.default_rng(83)
    start = g.random((2 * h, 2 * w)) < 0.0003
    start[:, -1] = False
    pair = start | np.roll(start, 1, axis=1)
    return dn + _raw_to_packed(np.where(pair, g.uniform(25.0, 60.0, pair.shape), 0.0))


def black_shading(dn, rng, **_):
    """Black shading: a smooth fixed offset, 2 DN at the sensor's centre and falling off as a Gaussian of a quarter of the sensor's width, the same in every frame (bias, dark and flat)."""
    y, x = _sensor_grid(dn)
    s = (x.max() + 1) / 4.0
    bump = 2.0 * np.exp(-((y - y.mean()) ** 2 + (x - x.mean()) ** 2) / (2 * s * s))
    return dn + _raw_to_packed(bump)


def gain_drift(dn, rng, k=1.0, **_):
    """The analog gain drifting as the camera warms: at each ISO every frame's gain is 0.15 % above the previous frame's (signal and noise alike), so a flat series climbs."""
    key = ("gain", id(rng), k)
    _WALK[key] = _WALK.get(key, -1.0) + 1.0
    return dn * (1.0 + 0.0015 * _WALK[key])


def column_noise(dn, rng, **_):
    """Temporal column noise: each sensor column's level moves by 0.7 DN rms, new in every frame (a column amplifier's own noise), in every kind of frame."""
    c = rng.normal(0.0, 0.7, 2 * dn.shape[2])
    return dn + np.stack([c[0::2], c[1::2], c[1::2], c[0::2]])[:, None, :]  # R, G2 on even sensor columns



# 2026-11-29 (twentieth session): a second fresh batch, written and committed before the loop ran on
# any of them.

def stuck_pixels(dn, rng, **_):
    """Stuck pixels: 0.05 % of the sensor pixels (fixed) always read the same code, 150 to 400 DN above black, with no noise and no response to light, in every kind of frame."""
    where = np.random.default_rng(89).random(dn.shape) < 0.0005
    return np.where(where, np.floor(np.random.default_rng(97).uniform(150.0, 400.0, dn.shape)), dn)


def charge_transfer(dn, rng, kind="", **_):
    """Horizontal charge-transfer inefficiency: along each sensor row, in readout order, every pixel leaves 2 % of its charge behind, read with the next pixel (a trail to the right), in frames that hold charge (darks and flats)."""
    if kind == "bias":
        return dn
    raw = np.empty((2 * dn.shape[1], 2 * dn.shape[2]))
    for i, (r, c) in enumerate(((0, 0), (0, 1), (1, 1), (1, 0))):
        raw[r::2, c::2] = dn[i]
    left = np.concatenate([np.zeros((raw.shape[0], 1)), raw[:, :-1]], axis=1)
    return _raw_mask_to_packed(0.98 * raw + 0.02 * left)


def dark_read_noise(dn, rng, kind="", **_):
    """Noise that grows with the exposure and not with the dark signal: the 4 s darks read 1.2 DN more white noise (Gaussian, new in every frame, no change of level), as from an amplifier warmed by the long exposure; bias frames and flats untouched."""
    if kind != "dark":
        return dn
    return dn + rng.normal(0.0, 1.2, dn.shape)


def read_noise_gradient(dn, rng, **_):
    """Read noise rising across the sensor, away from the amplifier: extra white noise growing linearly from 0 DN at the left edge to 2 DN at the right one, new in every frame, in every kind of frame."""
    _, x = _sensor_grid(dn)
    return dn + rng.normal(0.0, 1.0, dn.shape) * _raw_to_packed(2.0 * x / x.max())


def parity_row_gain(dn, rng, **_):
    """Two-phase row drivers: sensor row pairs alternate in gain, +0.6 % on rows 4n and 4n+1, -0.6 % on rows 4n+2 and 4n+3 (fixed), so flats show a period-2 row pattern in each channel, in proportion to the signal."""
    g = np.where(np.arange(2 * dn.shape[1]) % 4 < 2, 1.006, 0.994)
    return dn * np.stack([g[0::2], g[0::2], g[1::2], g[1::2]])[:, :, None]  # R, G1 on even sensor rows


def channel_dark(dn, rng, exposure=0.0, k=1.0, **_):
    """Dark current of one colour's pixel design: the blue pixels collect 4 e-/s of dark current, with its shot noise, the others none."""
    out = dn.copy()
    out[2] = dn[2] + k * rng.poisson(4.0 * exposure, dn.shape[1:])
    return out


# 2026-11-29 (twenty-first session): a third fresh batch, written and committed before the loop ran
# on any of them.

def image_lag(dn, rng, k=1.0, **_):
    """Image lag: each pixel keeps 1 % of the previous frame's charge and reads it with the next frame (incomplete transfer from the photodiode), in the order the frames were taken (bias, darks, then the flats by level), so the second flat of a pair and the first of a new level carry part of the one before."""
    key = ("lag", id(rng), k)
    out = dn + 0.01 * _WALK.get(key, 0.0)
    _WALK[key] = np.maximum(dn, 0.0)
    return out


def black_by_iso(dn, rng, k=1.0, **_):
    """An offset before the analog gain: 0.8 e- in every pixel of every frame, so black reads 0.8 K DN high, more at each higher ISO (the black clamp acts after the gain and does not see it)."""
    return dn + 0.8 * k


def cosmic_rays(dn, rng, exposure=0.0, k=1.0, **_):
    """Cosmic-ray hits: 2e-5 per sensor pixel per second, each a short straight track of 1 to 4 sensor pixels in a random direction, 300 to 3000 e- per pixel, new in every frame (so about 16 in a 4 s dark of the issue's size and almost none in bias frames)."""
    _, h, w = dn.shape
    raw = np.zeros((2 * h, 2 * w))
    for _hit in range(rng.poisson(2e-5 * raw.size * exposure)):
        y, x, a = rng.integers(0, 2 * h), rng.integers(0, 2 * w), rng.uniform(0, np.pi)
        for t in range(rng.integers(1, 5)):
            yy, xx = int(round(y + t * np.sin(a))), int(round(x + t * np.cos(a)))
            if 0 <= yy < 2 * h and 0 <= xx < 2 * w:
                raw[yy, xx] += rng.uniform(300.0, 3000.0)
    return dn + k * _raw_to_packed(raw)


def row_gain_noise(dn, rng, **_):
    """Temporal row gain noise: each sensor row's gain moves by 0.1 % rms, new in every frame (noise on a row's reference voltage), so flats show row banding growing with the signal and bias frames none."""
    g = 1.0 + 0.001 * rng.normal(0.0, 1.0, 2 * dn.shape[1])
    return dn * np.stack([g[0::2], g[0::2], g[1::2], g[1::2]])[:, :, None]  # R, G1 on even sensor rows


def column_telegraph(dn, rng, **_):
    """Random telegraph noise of column amplifiers: 2 % of the sensor columns (fixed) switch between two levels 3 DN apart, each frame in one of the two at random, in every kind of frame."""
    cols = np.random.default_rng(101).random(2 * dn.shape[2]) < 0.02
    c = 3.0 * cols * (rng.random(cols.shape) < 0.5)
    return dn + np.stack([c[0::2], c[1::2], c[1::2], c[0::2]])[:, None, :]  # R, G2 on even sensor columns


def low_light_toe(dn, rng, k=1.0, kind="", **_):
    """Charge trapping at low light: a pixel loses t (1 - exp(-q / t)) of its photo-charge q, with t = 15 e- (traps that fill first), so the response has a toe and, above a few hundred electrons, a constant 15 e- short; in flats (the darks' charge here is too small to matter)."""
    if kind != "flat":
        return dn
    q = np.maximum(dn / k, 0.0)
    return dn - k * 15.0 * (1.0 - np.exp(-q / 15.0))

def pixel_gain_noise(dn, rng, **_):
    """Temporal gain noise of each pixel: every pixel's gain moves by 0.5 % rms, new in every frame and independent between pixels (noise on the pixel's conversion), so a flat's temporal variance grows with the square of its signal and bias frames show none."""
    return dn * (1.0 + 0.005 * rng.standard_normal(dn.shape))


def stuck_bit(dn, rng, **_):
    """A stuck ADC bit: bit 3 (value 8) of every code reads 0, so codes come in runs of 8 with gaps of 8 between them (black is a multiple of 16)."""
    c = np.rint(dn).astype(np.int64) + 4096
    return (c & ~8) - 4096.0


def alternating_black(dn, rng, **_):
    """Black alternating between frames: +0.8 DN in one frame, -0.8 DN in the next, in the order the frames were taken (two readout phases)."""
    key = ("alternate", id(rng))
    _WALK[key] = _WALK.get(key, 0) + 1
    return dn + (0.8 if _WALK[key] % 2 else -0.8)


def blotchy_fpn(dn, rng, **_):
    """A blotchy fixed pattern: white noise smoothed over 2 sensor pixels (Gaussian sigma), scaled to 1 DN rms, the same in every frame of every setting (mura of the readout)."""
    from scipy.ndimage import gaussian_filter

    _, h, w = dn.shape
    raw = gaussian_filter(_fixed(113, (2 * h, 2 * w)), 2.0, mode="wrap")
    return dn + _raw_to_packed(raw / raw.std())


def dim_pixels(dn, rng, kind="", **_):
    """Dim pixels: 0.3 % of the pixels (fixed) respond to light at half the rate, so flats show dark outliers in proportion to the signal and bias frames none."""
    if kind != "flat":
        return dn
    return np.where(np.random.default_rng(127).random(dn.shape) < 0.003, 0.5 * dn, dn)


def laplace_rows(dn, rng, **_):
    """Heavy-tailed row noise: each sensor row offset by a Laplace draw of 1 DN rms, new in every frame, on top of the model's Gaussian row noise."""
    r = rng.laplace(0.0, 1.0 / np.sqrt(2.0), 2 * dn.shape[1])
    return dn + np.stack([r[0::2], r[0::2], r[1::2], r[1::2]])[:, :, None]


# 2026-11-29 (twenty-third session): a fifth fresh batch, written and committed before the loop ran
# on any of them.

def pixel_wander(dn, rng, k=1.0, **_):
    """1/f-like pixel noise: each pixel's offset wanders from frame to frame as an AR(1) process (0.9 of the previous frame's plus a new draw, 1 DN rms stationary), in the order the frames were taken at each ISO, in every kind of frame."""
    key = ("wander", id(rng), k)
    prev = _WALK.get(key)
    w = rng.standard_normal(dn.shape) if prev is None else 0.9 * prev + np.sqrt(1.0 - 0.81) * rng.standard_normal(dn.shape)
    _WALK[key] = w
    return dn + w


def dropouts(dn, rng, **_):
    """Readout dropouts: 0.05 % of the pixels of every frame, at new places each frame, read 60 to 200 DN below what they should (a lost charge packet), in every kind of frame."""
    hit = rng.random(dn.shape) < 5e-4
    return dn - hit * rng.uniform(60.0, 200.0, dn.shape)


def triple_adc_columns(dn, rng, **_):
    """Three interleaved column ADCs with offsets of their own: sensor column c reads +1, 0 and -1 DN for c mod 3 = 0, 1, 2, the same in every frame."""
    c = np.array([1.0, 0.0, -1.0])[np.arange(2 * dn.shape[2]) % 3]
    return dn + np.stack([c[0::2], c[1::2], c[1::2], c[0::2]])[:, None, :]  # R, G2 on even sensor columns


def column_flicker_1f(dn, rng, **_):
    """Column noise with a 1/f spectrum across the sensor columns (a drifting column reference): 1 DN rms, new in every frame."""
    n = 2 * dn.shape[2]
    f = np.fft.rfftfreq(n)
    amp = np.where(f > 0, 1.0 / np.sqrt(np.maximum(f, 1e-9)), 0.0)
    c = np.fft.irfft(amp * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)), n)
    c = c / c.std()
    return dn + np.stack([c[0::2], c[1::2], c[1::2], c[0::2]])[:, None, :]


def repeated_rows(dn, rng, **_):
    """A readout glitch: in every frame, 0.5 % of the sensor rows (new places each frame) repeat the sensor row above them (the same colour's row two lines up in the mosaic)."""
    raw = np.zeros((2 * dn.shape[1], 2 * dn.shape[2]))
    raw[0::2, 0::2], raw[0::2, 1::2], raw[1::2, 1::2], raw[1::2, 0::2] = dn
    for y in np.flatnonzero(rng.random(raw.shape[0]) < 0.005):
        if y >= 2:
            raw[y] = raw[y - 2]
    return _raw_to_packed(raw)


def quadrant_offsets(dn, rng, **_):
    """Four readout quadrants with a black offset each: +0.9, -0.6, +0.3 and -0.6 DN (top left, top right, bottom left, bottom right), the same in every frame."""
    _, h, w = dn.shape
    q = np.zeros((h, w))
    q[: h // 2, : w // 2], q[: h // 2, w // 2 :], q[h // 2 :, : w // 2], q[h // 2 :, w // 2 :] = 0.9, -0.6, 0.3, -0.6
    return dn + q


# 2026-11-29 (twenty-fourth session): a sixth fresh batch, written and committed before the loop ran
# on any of them.

def noisy_third_columns(dn, rng, **_):
    """A noisier shared ADC: every third sensor column (c mod 3 = 0) reads with 1.5 DN of extra white noise, new at every pixel and frame."""
    extra = np.where(np.arange(2 * dn.shape[2]) % 3 == 0, 1.5, 0.0)
    e = np.stack([extra[0::2], extra[1::2], extra[1::2], extra[0::2]])[:, None, :]  # R, G2 on even sensor columns
    return dn + e * rng.standard_normal(dn.shape)


def hot_clusters(dn, rng, exposure=0.0, k=1.0, **_):
    """Damaged regions: 20 clusters of 3 x 3 raw pixels (fixed places) with a dark current of 40 e-/s each, with its shot noise."""
    raw = np.zeros((2 * dn.shape[1], 2 * dn.shape[2]))
    where = np.random.default_rng(123)
    for _ in range(20):
        y, x = where.integers(0, raw.shape[0] - 3), where.integers(0, raw.shape[1] - 3)
        raw[y : y + 3, x : x + 3] = 1.0
    mask = _raw_to_packed(raw) > 0
    return dn + mask * k * rng.poisson(40.0 * exposure, dn.shape)


def bit_flips(dn, rng, **_):
    """Single-bit errors on the data link: 0.01 % of the codes of every frame have bit 9 (512) flipped (raw code = DN + 512, the SonyA7S2 black)."""
    code = np.rint(dn).astype(np.int64) + 512
    hit = rng.random(dn.shape) < 1e-4
    return np.where(hit, (code ^ 512) - 512.0, dn)


def black_ramp(dn, rng, **_):
    """Clamp droop during readout: a black level ramp from the top to the bottom sensor row, its size new in every frame (normal, 1.5 DN sd from top to bottom)."""
    h = dn.shape[1]
    ramp = rng.normal(0.0, 1.5) * (np.arange(2 * h) / (2 * h - 1) - 0.5)
    return dn + np.stack([ramp[0::2], ramp[0::2], ramp[1::2], ramp[1::2]])[:, :, None]


def intermittent_tone(dn, rng, **_):
    """Interference from a device that is on in about half the frames: 1.0 DN at 0.137 cycles per sensor row, a phase per frame, in the frames where it is on."""
    if rng.random() >= 0.5:
        return dn
    t = 1.0 * np.cos(2 * np.pi * 0.137 * np.arange(2 * dn.shape[1]) + rng.uniform(0, 2 * np.pi))
    return dn + np.stack([t[0::2], t[0::2], t[1::2], t[1::2]])[:, :, None]


def pixel_ringing(dn, rng, **_):
    """A slow readout amplifier: each raw pixel carries 0.25 of the previous pixel's output along its row (an IIR in readout order), signal and noise alike."""
    raw = np.zeros((2 * dn.shape[1], 2 * dn.shape[2]))
    raw[0::2, 0::2], raw[0::2, 1::2], raw[1::2, 1::2], raw[1::2, 0::2] = dn
    for x in range(1, raw.shape[1]):
        raw[:, x] += 0.25 * raw[:, x - 1]
    return _raw_to_packed(raw)

# the seventh fresh batch (twenty-fifth session), written and committed before the loop ran on it
def bank_gain(dn, rng, **_):
    """Column-parallel amplifiers in two banks: the odd sensor columns convert with a 3 % higher gain than the even ones (signal and noise alike), so flats show a two-column stripe in proportion to the signal."""
    g = np.where(np.arange(2 * dn.shape[2]) % 2 == 1, 1.03, 1.0)
    return dn * np.stack([g[0::2], g[1::2], g[1::2], g[0::2]])[:, None, :]  # R, G2 on even sensor columns


def burst_rows(dn, rng, **_):
    """Readout bursts: in every frame 1 % of the sensor rows (new ones each frame) read with 3 DN of extra white noise, pixel by pixel."""
    h = dn.shape[1]
    hit = rng.random(2 * h) < 0.01
    extra = np.stack([hit[0::2], hit[0::2], hit[1::2], hit[1::2]])[:, :, None] * 3.0  # R, G1 on even sensor rows
    return dn + extra * rng.standard_normal(dn.shape)


def excess_shot_noise(dn, rng, kind="", k=1.0, **_):
    """An excess noise factor in the charge path: flats carry 1.2 x the Poisson variance of their signal (K x signal x 1.2), the mean unchanged."""
    if kind != "flat":
        return dn
    return dn + np.sqrt(0.2 * k * np.clip(dn, 0.0, None)) * rng.standard_normal(dn.shape)


def black_col_ramp(dn, rng, **_):
    """A black level ramp from the left to the right sensor column, its size new in every frame (normal, 1.5 DN sd from left to right): a clamp droop along a serial readout."""
    w = dn.shape[2]
    ramp = rng.normal(0.0, 1.5) * (np.arange(2 * w) / (2 * w - 1) - 0.5)
    return dn + np.stack([ramp[0::2], ramp[1::2], ramp[1::2], ramp[0::2]])[:, None, :]


def partial_dead_columns(dn, rng, **_):
    """Broken column lines: 4 sensor columns (fixed) read code 0 (512 DN below black) from a fixed row down to the bottom, in every kind of frame."""
    raw = np.zeros((2 * dn.shape[1], 2 * dn.shape[2]), dtype=bool)
    where = np.random.default_rng(131)
    for _ in range(4):
        x, y = where.integers(0, raw.shape[1]), where.integers(raw.shape[0] // 4, 3 * raw.shape[0] // 4)
        raw[y:, x] = True
    return np.where(_raw_to_packed(raw), -512.0, dn)


def noisy_row_bank(dn, rng, **_):
    """Row-bank readout: every 16th sensor row (r mod 16 = 5) reads with 2 DN of extra white noise, new at every pixel and frame."""
    extra = np.where(np.arange(2 * dn.shape[1]) % 16 == 5, 2.0, 0.0)
    e = np.stack([extra[0::2], extra[0::2], extra[1::2], extra[1::2]])[:, :, None]  # R, G1 on even sensor rows
    return dn + e * rng.standard_normal(dn.shape)


# the eighth fresh batch (twenty-sixth session), written and committed before the loop ran on it
def wandering_tone(dn, rng, **_):
    """Interference from a switching regulator whose frequency wanders: 1.0 DN along the sensor rows at 0.12 cycles per sensor row, the frequency off by a normal 0.01 in each frame, a phase per frame."""
    f = 0.12 + rng.normal(0.0, 0.01)
    t = 1.0 * np.cos(2 * np.pi * f * np.arange(2 * dn.shape[1]) + rng.uniform(0, 2 * np.pi))
    return dn + np.stack([t[0::2], t[0::2], t[1::2], t[1::2]])[:, :, None]


def paired_columns(dn, rng, **_):
    """Column ADCs shared by pairs of sensor columns: one fixed offset per pair (sensor columns 2j and 2j + 1), 1.0 DN rms, the same in every frame."""
    pair = np.random.default_rng(141).normal(0.0, 1.0, dn.shape[2])  # packed column j holds sensor columns 2j, 2j + 1
    return dn + pair[None, None, :]


def row_noise_ramp(dn, rng, **_):
    """Row noise whose level grows down the frame (a reference line settling during readout): each sensor row offset by a normal draw whose sd rises from 0.3 DN at the top to 2.5 DN at the bottom, new in every frame."""
    y = np.arange(2 * dn.shape[1])
    r = rng.standard_normal(y.size) * (0.3 + 2.2 * y / (y.size - 1))
    return dn + np.stack([r[0::2], r[0::2], r[1::2], r[1::2]])[:, :, None]


def noisy_edge_columns(dn, rng, **_):
    """An edge of the array reads noisier: the leftmost 24 sensor columns carry 2 DN of extra white noise, new at every pixel and frame."""
    extra = np.where(np.arange(2 * dn.shape[2]) < 24, 2.0, 0.0)
    e = np.stack([extra[0::2], extra[1::2], extra[1::2], extra[0::2]])[:, None, :]  # R, G2 on even sensor columns
    return dn + e * rng.standard_normal(dn.shape)


def hot_tiles(dn, rng, **_):
    """Shared-pixel defects: 0.1 % of the 2x2 Bayer tiles (fixed) read 30 DN high in all four of their pixels (a shared source follower with an offset of its own), in every frame."""
    tile = np.random.default_rng(151).random(dn.shape[1:]) < 1e-3  # a tile is one packed position
    return dn + 30.0 * tile[None]


def red_compression(dn, rng, kind="", **_):
    """The red channel's amplifier compresses: R reads its signal x (1 - 0.03 x signal / 6000 DN), 3 % low at 6000 DN; the other channels are linear."""
    out = dn.copy()
    out[0] = dn[0] * (1.0 - 0.03 * np.clip(dn[0], 0.0, None) / 6000.0)
    return out


# the ninth fresh batch (twenty-seventh session), written and committed before the loop ran on it
def ar_row_noise(dn, rng, **_):
    """Row noise with a memory: each sensor row's offset is 0.85 of the row above's plus a new normal draw (a clamp whose time constant spans several lines), 1.5 DN rms, new in every frame."""
    n = 2 * dn.shape[1]
    e = rng.normal(0.0, 1.5 * np.sqrt(1.0 - 0.85**2), n)
    r = np.empty(n)
    r[0] = rng.normal(0.0, 1.5)
    for i in range(1, n):
        r[i] = 0.85 * r[i - 1] + e[i]
    return dn + np.stack([r[0::2], r[0::2], r[1::2], r[1::2]])[:, :, None]


def skewed_read_noise(dn, rng, **_):
    """Read noise with a one-sided tail (a source follower with a trap that only adds): 3 % of the readings, new at every pixel and frame, get an extra exponential of mean 4 DN."""
    return dn + (rng.random(dn.shape) < 0.03) * rng.exponential(4.0, dn.shape)


def checker_tiles(dn, rng, **_):
    """A checkerboard fixed pattern: 4 x 4 sensor-pixel tiles alternately 0.8 DN high and low (two interleaved layouts of a shared readout), the same in every frame."""
    y, x = np.mgrid[0:2 * dn.shape[1], 0:2 * dn.shape[2]]
    return dn + _raw_to_packed(np.where((y // 4 + x // 4) % 2 == 0, 0.8, -0.8))


def partial_hot_columns(dn, rng, **_):
    """Partial hot columns: 6 sensor columns (fixed) read 15 DN high from a row of their own down to the bottom (a leak from a defect point), in every kind of frame."""
    raw = np.zeros((2 * dn.shape[1], 2 * dn.shape[2]))
    where = np.random.default_rng(161)
    for _ in range(6):
        x, y = where.integers(0, raw.shape[1]), where.integers(0, 3 * raw.shape[0] // 4)
        raw[y:, x] = 15.0
    return dn + _raw_to_packed(raw)


def bimodal_black(dn, rng, **_):
    """A clamp toggling between two references: each frame's black level is 3 DN higher in a random half of the frames (a coin per frame)."""
    return dn + (3.0 if rng.random() < 0.5 else 0.0)


def column_dark_current(dn, rng, exposure=0.0, k=1.0, **_):
    """Dark current of every sensor column's own: a column rate of 1 e-/s times a lognormal (sigma 0.5 in log), the same in every frame, with its shot noise (columns of a process gradient)."""
    rate = np.exp(0.5 * np.random.default_rng(171).standard_normal(2 * dn.shape[2]))
    cols = np.stack([rate[0::2], rate[1::2], rate[1::2], rate[0::2]])[:, None, :]  # R, G2 on even sensor columns
    return dn + k * rng.poisson(np.broadcast_to(cols * exposure, dn.shape))


# the tenth fresh batch (twenty-eighth session), written and committed before the loop ran on it
def noisy_patch(dn, rng, **_):
    """A damaged region of the readout: one rectangle of the sensor (rows 1/4 to 1/2, columns 1/2 to 3/4 of the frame, 1/16 of its area) reads with 2 DN of extra white noise, new at every pixel and frame."""
    _, h, w = dn.shape
    extra = np.zeros((h, w))
    extra[h // 4 : h // 2, w // 2 : 3 * w // 4] = 2.0
    return dn + extra * rng.standard_normal(dn.shape)


def row_spikes(dn, rng, **_):
    """Row decoder glitches: in every frame 0.2 % of the sensor rows (new ones each frame) read 15 to 40 DN off, up or down, along their whole length."""
    n = 2 * dn.shape[1]
    r = (rng.random(n) < 0.002) * rng.choice([-1.0, 1.0], n) * rng.uniform(15.0, 40.0, n)
    return dn + np.stack([r[0::2], r[0::2], r[1::2], r[1::2]])[:, :, None]  # R, G1 on even sensor rows


def first_frame_black(dn, rng, kind="", exposure=0.0, k=1.0, **_):
    """A clamp that settles after each change of setting: the first frame after a change (the first bias frame of an ISO, the first dark, the first flat of each level) reads 2 DN high."""
    key = ("first", id(rng), kind, exposure, k)
    first = key not in _WALK
    _WALK[key] = True
    return dn + (2.0 if first else 0.0)


def exposure_black_shift(dn, rng, exposure=0.0, **_):
    """A clamp that leaks during integration: black rises 0.25 DN per second of exposure (1 DN in a 4 s dark), with no noise of its own, at every ISO alike."""
    return dn + 0.25 * exposure


def column_wander(dn, rng, k=1.0, **_):
    """Column offsets that wander from frame to frame: each sensor column's offset is 0.8 of its offset in the frame before plus a new draw (AR(1), 1 DN rms stationary), in the order the frames were taken at each ISO, in every kind of frame."""
    key = ("column_wander", id(rng), k)
    prev = _WALK.get(key)
    n = 2 * dn.shape[2]
    c = rng.standard_normal(n) if prev is None else 0.8 * prev + 0.6 * rng.standard_normal(n)
    _WALK[key] = c
    return dn + np.stack([c[0::2], c[1::2], c[1::2], c[0::2]])[:, None, :]  # R, G2 on even sensor columns


def smooth_dsnu(dn, rng, exposure=0.0, k=1.0, **_):
    """Dark current that varies smoothly over the sensor (a process or temperature gradient): 0.5 e-/s times exp(0.6 z), z a fixed Gaussian field smoothed over 16 sensor pixels and scaled to unit sd, with its shot noise."""
    from scipy.ndimage import gaussian_filter

    _, h, w = dn.shape
    z = gaussian_filter(_fixed(181, (2 * h, 2 * w)), 16.0, mode="wrap")
    rate = _raw_to_packed(0.5 * np.exp(0.6 * z / z.std()))
    return dn + k * rng.poisson(rate * exposure)


# the eleventh fresh batch (twenty-ninth session), written and committed before the loop ran on it
def column_bank_flicker(dn, rng, **_):
    """Column ADC banks with a reference of their own: each group of 16 adjacent sensor columns shares an offset of 1.2 DN rms, new in every frame, in every kind of frame."""
    _, h, w = dn.shape
    c = np.repeat(rng.normal(0.0, 1.2, -(-2 * w // 16)), 16)[: 2 * w]
    return dn + _raw_to_packed(np.broadcast_to(c, (2 * h, 2 * w)))


def full_well(dn, rng, k=1.0, **_):
    """Pixel saturation below the ADC's range: each pixel holds at most its full well, 17000 e- times (1 + 0.03 z), z fixed per pixel, so at K 0.375 DN/e- the 40 % flats (6350 DN) clip about half their pixels (a saturated pixel reads its full well, without read noise); other frames untouched."""
    well = k * 17000.0 * (1.0 + 0.03 * _fixed(191, dn.shape))
    return np.minimum(dn, well)


def row_wander(dn, rng, k=1.0, **_):
    """Row offsets that wander from frame to frame: each sensor row's offset is 0.8 of its offset in the frame before plus a new draw (AR(1), 1 DN rms stationary), in the order the frames were taken at each ISO, in every kind of frame."""
    key = ("row_wander", id(rng), k)
    prev = _WALK.get(key)
    _, h, w = dn.shape
    r = rng.standard_normal(2 * h) if prev is None else 0.8 * prev + 0.6 * rng.standard_normal(2 * h)
    _WALK[key] = r
    return dn + _raw_to_packed(np.broadcast_to(r[:, None], (2 * h, 2 * w)))


def digital_iso(dn, rng, k=1.0, **_):
    """The top ISO is a digital gain: at K 3.0 DN/e- the camera converts at half the gain and doubles the codes, so every code of those frames is even (black-subtracted; the black level is even); the other ISOs untouched."""
    return 2.0 * np.rint(dn / 2.0) if k >= 3.0 else dn


def burst_columns(dn, rng, **_):
    """Column readout bursts: in every frame 1 % of the sensor columns (new ones each frame) read with 3 DN of extra white noise, pixel by pixel."""
    _, h, w = dn.shape
    hit = rng.random(2 * w) < 0.01
    return dn + _raw_to_packed(3.0 * hit[None, :] * rng.standard_normal((2 * h, 2 * w)))


def bimodal_read_noise(dn, rng, **_):
    """Two-level read noise (a trap in every source follower switching faster than a frame): each reading, new at every pixel and frame, 1.2 DN up or down with equal odds, on top of the model's read noise."""
    return dn + np.where(rng.random(dn.shape) < 0.5, 1.2, -1.2)


# the twelfth fresh batch (twenty-ninth session), written and committed before the loop ran on it
def row_pairs(dn, rng, **_):
    """A two-row readout: sensor rows 2j and 2j + 1 (one Bayer row pair) are converted together and share one row offset, 1.0 DN rms, new in every frame, in every kind of frame."""
    _, h, w = dn.shape
    r = np.repeat(rng.normal(0.0, 1.0, h), 2)
    return dn + _raw_to_packed(np.broadcast_to(r[:, None], (2 * h, 2 * w)))


def gain_scaled_fpn(dn, rng, k=1.0, **_):
    """Offsets before the amplifier (source-follower thresholds): each pixel's offset 0.6 e- rms (fixed), so K x 0.6 DN: 0.23 DN at ISO 400, 1.8 DN at ISO 3200, in every kind of frame."""
    return dn + k * 0.6 * _fixed(201, dn.shape)


def blue_prnu(dn, rng, kind="", **_):
    """A colour filter of uneven thickness: the blue pixels' response to light off by 2 % rms (fixed), the others' by 0.3 %, so flats show a blue pixel pattern in proportion to the signal and bias frames none."""
    gain = 1.0 + 0.003 * _fixed(211, dn.shape)
    gain[2] = 1.0 + 0.02 * _fixed(212, dn.shape[1:])  # packed B
    return dn * gain if kind == "flat" else dn


def periodic_rows(dn, rng, **_):
    """A row driver laid out in blocks of 8: a fixed row offset repeating every 8 sensor rows (8 values drawn once, 1.0 DN rms), the same in every frame."""
    _, h, w = dn.shape
    r = np.tile(np.random.default_rng(221).normal(0.0, 1.0, 8), -(-2 * h // 8))[: 2 * h]
    return dn + _raw_to_packed(np.broadcast_to(r[:, None], (2 * h, 2 * w)))


def gain_telegraph(dn, rng, kind="", **_):
    """Conversion-gain telegraph: 0.5 % of the pixels (fixed) have a floating-diffusion trap that switches their gain between +4 % and -4 % from frame to frame (a state per pixel and frame), so flats show pixels that jump in proportion to the signal and bias frames nothing."""
    where = np.random.default_rng(231).random(dn.shape) < 0.005
    state = np.where(rng.random(dn.shape) < 0.5, 1.04, 0.96)
    return np.where(where, dn * state, dn) if kind == "flat" else dn


def dark_row_noise(dn, rng, kind="", **_):
    """Row noise that grows in long exposures (a reference warmed by the integration): the 4 s darks carry 1.0 DN more row noise (a normal offset per sensor row and frame); bias frames and flats untouched."""
    if kind != "dark":
        return dn
    _, h, w = dn.shape
    r = rng.normal(0.0, 1.0, 2 * h)
    return dn + _raw_to_packed(np.broadcast_to(r[:, None], (2 * h, 2 * w)))


# the thirteenth fresh batch (thirtieth session), written and committed before the loop ran on it
def channel_digital_gain(dn, rng, **_):
    """White-balance pre-gain in the raw: the red and blue channels are converted at the greens' gain, rounded, then multiplied by 1.25 in the camera, so those channels miss one code in five and carry 25 % more signal and noise; the greens untouched."""
    out = dn.copy()
    out[[0, 2]] = 1.25 * np.rint(dn[[0, 2]])  # packed R, B
    return out


def masked_rows(dn, rng, kind="", k=1.0, **_):
    """Optically masked rows left in the raw: the top 8 sensor rows are covered, so in flats they read black with the noise of a bias frame at that ISO (normal, its rms); bias and dark frames as the other rows."""
    if kind == "bias":
        _WALK[("masked_rows", k)] = float(np.std(dn))
    if kind != "flat":
        return dn
    raw = np.zeros((2 * dn.shape[1], 2 * dn.shape[2]))
    raw[0::2, 0::2], raw[0::2, 1::2], raw[1::2, 1::2], raw[1::2, 0::2] = dn
    raw[:8] = rng.normal(0.0, _WALK[("masked_rows", k)], raw[:8].shape)
    return _raw_to_packed(raw)


def dual_gain_codes(dn, rng, **_):
    """Dual conversion gain: readings above 800 DN come from the low-gain path, converted at a quarter of the gain and scaled by 4 in the camera, so they carry codes in steps of 4 DN and 2 DN more read noise; lower readings untouched."""
    low = 4.0 * np.rint((dn + rng.normal(0.0, 2.0, dn.shape)) / 4.0)
    return np.where(dn > 800.0, low, dn)


def raw_smoothing(dn, rng, k=1.0, **_):
    """In-camera raw noise reduction at the top ISO: at K 3.0 DN/e- each pixel becomes 0.6 of itself plus 0.2 of each same-colour horizontal neighbour (edges reflected), in every kind of frame; the other ISOs untouched."""
    if k < 3.0:
        return dn
    p = np.pad(dn, ((0, 0), (0, 0), (1, 1)), mode="reflect")
    return 0.6 * dn + 0.2 * p[:, :, :-2] + 0.2 * p[:, :, 2:]


def split_row_noise(dn, rng, **_):
    """Row noise from two readout sides: the left and the right half of each sensor row take independent row offsets, 1.0 DN rms each, new in every frame, in every kind of frame."""
    _, h, w = dn.shape
    r = np.repeat(rng.normal(0.0, 1.0, (2 * h, 2)), w, axis=1)  # (2h, 2w): left half r[:, 0], right half r[:, 1]
    return dn + _raw_to_packed(r)


def column_pairs(dn, rng, **_):
    """Columns read in pairs: sensor columns 2j and 2j + 1 share a column amplifier whose offset is 1.0 DN rms, new in every frame, in every kind of frame."""
    _, h, w = dn.shape
    c = np.repeat(rng.normal(0.0, 1.0, w), 2)
    return dn + _raw_to_packed(np.broadcast_to(c, (2 * h, 2 * w)))


# the fourteenth fresh batch (thirtieth session), written and committed before the loop ran on it
def block_compression(dn, rng, **_):
    """Lossy raw compression in blocks (as Sony's): each run of 16 same-colour pixels along a packed row keeps its largest and smallest value, and the others as steps from the smallest in 7 bits, at the finest power-of-two step that spans the block (1 DN where its range is under 128 DN, coarser in bright, noisy flats)."""
    c, h, w = dn.shape
    n = w // 16 * 16
    v = np.rint(dn[:, :, :n]).reshape(c, h, n // 16, 16)
    lo, hi = v.min(axis=3, keepdims=True), v.max(axis=3, keepdims=True)
    step = 2.0 ** np.maximum(np.ceil(np.log2(np.maximum(hi - lo, 1.0) / 127.0)), 0.0)
    q = lo + step * np.floor((v - lo) / step)
    q = np.where((v == lo) | (v == hi), v, q)
    out = dn.copy()
    out[:, :, :n] = q.reshape(c, h, n)
    return out


def column_gain_flicker(dn, rng, kind="", **_):
    """Column amplifiers whose gain moves from frame to frame: every sensor column's gain on the signal is 1 + 0.5 % x a normal drawn per column and frame, so each flat shows new column stripes in proportion to its signal; bias and dark frames untouched."""
    if kind != "flat":
        return dn
    _, h, w = dn.shape
    g = 1.0 + 0.005 * rng.standard_normal(2 * w)
    return dn * _raw_to_packed(np.broadcast_to(g, (2 * h, 2 * w)))


def noisy_rows(dn, rng, **_):
    """Noisy row drivers: 0.5 % of the sensor rows (fixed) read with 4 DN of extra white noise, pixel by pixel, in every frame of every kind."""
    _, h, w = dn.shape
    bad = np.random.default_rng(241).random(2 * h) < 0.005
    return dn + _raw_to_packed(4.0 * bad[:, None] * rng.standard_normal((2 * h, 2 * w)))


def black_step(dn, rng, **_):
    """A clamp that re-triggers during readout: in every frame, from a sensor row drawn anew (uniform over the frame) to the bottom, the black level is 1.5 DN higher, in every kind of frame."""
    _, h, w = dn.shape
    start = rng.integers(0, 2 * h)
    step = np.where(np.arange(2 * h) >= start, 1.5, 0.0)
    return dn + _raw_to_packed(np.broadcast_to(step[:, None], (2 * h, 2 * w)))


def interleaved_row_gain(dn, rng, kind="", **_):
    """Line-interleaved dual gain (an HDR sensor): every other Bayer row pair (sensor rows 4j + 2 and 4j + 3) converts its photo signal with 1.5 times the gain, read noise unchanged, so flats show alternating bright and dim row pairs and bias frames nothing."""
    if kind != "flat":
        return dn
    _, h, w = dn.shape
    g = np.where(np.arange(h) % 2 == 1, 1.5, 1.0)  # packed row y holds sensor rows 2y, 2y + 1
    return dn * g[None, :, None]


def frame_row_noise(dn, rng, **_):
    """Interference in some frames: in about a quarter of the frames (each frame on its own) every sensor row takes 1.5 DN more row noise (a normal offset per row), in every kind of frame."""
    if rng.random() >= 0.25:
        return dn
    _, h, w = dn.shape
    r = rng.normal(0.0, 1.5, 2 * h)
    return dn + _raw_to_packed(np.broadcast_to(r[:, None], (2 * h, 2 * w)))


# the fifteenth fresh batch (thirty-first session), written and committed before the loop ran on it
def dark_hot_band(dn, rng, exposure=0.0, k=1.0, **_):
    """A warm readout under the bottom of the array: the bottom 48 sensor rows collect 3 e-/s more dark current, with its shot noise, in every kind of frame (long darks show a band)."""
    _, h, w = dn.shape
    rate = np.where(np.arange(2 * h) >= 2 * h - 48, 3.0, 0.0)[:, None] * np.ones((1, 2 * w))
    return dn + k * _raw_to_packed(rng.poisson(rate * exposure).astype(np.float64))


def adc_white_clip(dn, rng, **_):
    """An ADC whose range ends below the raw container's: every reading above 8000 DN (black-subtracted) is written as 8000 DN, while the file declares the 14-bit white level; the brightest flats clip."""
    return np.minimum(dn, 8000.0)


def flicker_bands(dn, rng, kind="", **_):
    """Flats under a flickering lamp with a rolling shutter: the light on each sensor row is 1 + 0.02 sin(2 pi Y / 150 + phase) of its mean, the phase drawn anew in every frame; bias and dark frames untouched."""
    if kind != "flat":
        return dn
    _, h, w = dn.shape
    y = np.arange(2 * h)[:, None] * np.ones((1, 2 * w))
    return dn * _raw_to_packed(1.0 + 0.02 * np.sin(2 * np.pi * y / 150.0 + rng.uniform(0.0, 2 * np.pi)))


def dust_shadow(dn, rng, kind="", **_):
    """Dust on the cover glass: two particles cast soft shadows on the flats, Gaussian blobs of 5 sensor pixels (sigma) at 40 % and 25 % depth, at fixed places; bias and dark frames untouched."""
    if kind != "flat":
        return dn
    _, h, w = dn.shape
    y, x = np.mgrid[0:2 * h, 0:2 * w].astype(np.float64)
    t = np.ones((2 * h, 2 * w))
    for cy, cx, depth in ((0.3, 0.6, 0.4), (0.7, 0.25, 0.25)):
        t *= 1.0 - depth * np.exp(-((y - cy * 2 * h) ** 2 + (x - cx * 2 * w) ** 2) / (2 * 5.0**2))
    return dn * _raw_to_packed(t)


def row_block_black(dn, rng, **_):
    """A black clamp refreshed every 64 sensor rows during readout: each block of 64 sensor rows takes its own black offset, normal of 0.7 DN, new in every frame, in every kind of frame."""
    _, h, w = dn.shape
    off = np.repeat(rng.normal(0.0, 0.7, (2 * h + 63) // 64), 64)[:2 * h]
    return dn + _raw_to_packed(np.broadcast_to(off[:, None], (2 * h, 2 * w)))


def clock_feedthrough(dn, rng, **_):
    """ADC clock feedthrough: a fixed offset pattern that repeats every 64 sensor columns (64 values drawn once, 0.6 DN rms), the same in every frame of every kind."""
    _, h, w = dn.shape
    period = np.random.default_rng(151).normal(0.0, 0.6, 64)
    return dn + _raw_to_packed(np.broadcast_to(np.resize(period, 2 * w)[None, :], (2 * h, 2 * w)))


# the sixteenth fresh batch (thirty-second session), written and committed before the loop ran on it
def vertical_read_corr(dn, rng, **_):
    """A column line that settles slowly: each pixel's read noise (1.5 DN) carries 0.6 of the read noise of the same-colour pixel two sensor rows above, new in every frame, in every kind of frame."""
    c, h, w = dn.shape
    n = rng.normal(0.0, 1.5, (c, h + 1, w))
    return dn + n[:, 1:] + 0.6 * n[:, :-1]


def column_group_gain(dn, rng, **_):
    """Column ADCs in groups of 8: the gain of each sensor column follows a fixed pattern that repeats every 8 columns (8 values drawn once, 1 % rms), on the signal and the read noise alike."""
    g = np.resize(1.0 + np.random.default_rng(161).normal(0.0, 0.01, 8), 2 * dn.shape[2])
    return dn * np.stack([g[0::2], g[1::2], g[1::2], g[0::2]])[:, None, :]  # R, G2 on even sensor columns


def row_gain_band(dn, rng, **_):
    """A weak row driver: sensor rows 100 to 139 convert at 3 % less gain, on the signal and the read noise alike, in every kind of frame."""
    g = np.where((np.arange(2 * dn.shape[1]) >= 100) & (np.arange(2 * dn.shape[1]) < 140), 0.97, 1.0)
    return dn * np.stack([g[0::2], g[0::2], g[1::2], g[1::2]])[:, :, None]  # R, G1 on even sensor rows


def shared_pair_fpn(dn, rng, **_):
    """Two pixels share a source follower: each vertical pair of sensor pixels (rows 2i and 2i + 1, one column) has one fixed offset, 1.0 DN rms (drawn once), in every frame of every kind."""
    _, h, w = dn.shape
    off = np.random.default_rng(163).normal(0.0, 1.0, (h, 2 * w))  # per tile row, per sensor column
    return dn + np.stack([off[:, 0::2], off[:, 1::2], off[:, 1::2], off[:, 0::2]])  # R + G2 share, G1 + B share


def read_noise_gradient(dn, rng, **_):
    """Read noise growing along the readout line: white noise whose sd rises from 0 at the left to 2.5 DN at the right sensor column, new in every frame, in every kind of frame."""
    _, h, w = dn.shape
    sd = 2.5 * np.arange(2 * w) / (2 * w - 1)
    sd = np.stack([sd[0::2], sd[1::2], sd[1::2], sd[0::2]])[:, None, :]
    return dn + sd * rng.standard_normal(dn.shape)


def dark_rate_jitter(dn, rng, kind="", exposure=0.0, k=1.0, **_):
    """A sensor whose temperature wanders between dark frames: each dark frame collects dark current at 1.5 e-/s times its own log-normal factor (30 % sd), with its shot noise; bias frames and flats untouched."""
    if kind != "dark":
        return dn
    rate = 1.5 * np.exp(rng.normal(-0.045, 0.3))
    return dn + k * rng.poisson(rate * exposure, dn.shape)


# the seventeenth fresh batch (thirty-second session), written and committed before the loop ran on it
def partial_hot_rows(dn, rng, exposure=0.0, k=1.0, **_):
    """A leaky row-driver segment: sensor rows 60, 61 and 250 collect 20 e-/s more dark current from sensor column 300 to the right edge, with its shot noise, in every kind of frame."""
    _, h, w = dn.shape
    rate = np.zeros((2 * h, 2 * w))
    rate[[60, 61, 250], 300:] = 20.0
    return dn + k * _raw_to_packed(rng.poisson(rate * exposure).astype(np.float64))


def dead_clusters(dn, rng, **_):
    """Dead clusters: 12 clusters of 3 x 3 sensor pixels (fixed places) read black (0 DN above it, without noise), in every kind of frame."""
    _, h, w = dn.shape
    places = np.random.default_rng(171)
    mask = np.zeros((2 * h, 2 * w), dtype=bool)
    for y, x in zip(places.integers(4, 2 * h - 4, 12), places.integers(4, 2 * w - 4, 12)):
        mask[y - 1 : y + 2, x - 1 : x + 2] = True
    return np.where(_raw_mask_to_packed(mask), 0.0, dn)


def dark_half_step(dn, rng, exposure=0.0, k=1.0, **_):
    """Two stitched halves: the right half of the sensor columns collects 2 e-/s more dark current than the left, with its shot noise, in every kind of frame (long darks step at the middle column)."""
    _, h, w = dn.shape
    rate = np.zeros((2 * h, 2 * w))
    rate[:, w:] = 2.0
    return dn + k * _raw_to_packed(rng.poisson(rate * exposure).astype(np.float64))


def gain_drift_sequence(dn, rng, kind="", k=1.0, **_):
    """Gain drifting down as the sensor warms through the flat series: the n-th flat of an ISO (n = 0, 1, ... in the order taken) converts at 1 - 0.002 n of the gain, signal and noise alike; bias and dark frames untouched."""
    if kind != "flat":
        return dn
    n = _WALK.get(("gain_drift_sequence", k), 0)
    _WALK[("gain_drift_sequence", k)] = n + 1
    return dn * (1.0 - 0.002 * n)


def half_column_noise(dn, rng, **_):
    """Column noise from one ADC bank: each sensor column of the left half takes an offset of 1.2 DN rms, new in every frame, in every kind of frame; the right half none."""
    _, h, w = dn.shape
    c = np.concatenate([rng.normal(0.0, 1.2, w), np.zeros(w)])
    return dn + _raw_to_packed(np.broadcast_to(c, (2 * h, 2 * w)))


def shared_pair_gain(dn, rng, **_):
    """Two pixels share a source follower: each vertical pair of sensor pixels (rows 2i and 2i + 1, one column) converts with one fixed gain, 1 % rms (drawn once), signal and noise alike, in every kind of frame."""
    _, h, w = dn.shape
    g = 1.0 + np.random.default_rng(173).normal(0.0, 0.01, (h, 2 * w))  # per tile row, per sensor column
    return dn * np.stack([g[:, 0::2], g[:, 1::2], g[:, 1::2], g[:, 0::2]])  # R + G2 share, G1 + B share


# the eighteenth fresh batch (thirty-third session), written and committed before the loop ran on it
def pixel_nonlinearity(dn, rng, kind="", **_):
    """Per-pixel response non-linearity: each pixel's signal bends by its own fixed coefficient, s -> s (1 + a s / 16000 DN) with a ~ N(0, 0.01) drawn once, so the flats' fixed pattern grows as the square of the level; bias and dark frames untouched."""
    if kind != "flat":
        return dn
    a = 0.01 * _fixed(181, dn.shape)
    return dn * (1.0 + a * np.maximum(dn, 0.0) / 16000.0)


def vertical_charge_leak(dn, rng, kind="", **_):
    """Charge leaking down the columns: in flats each pixel keeps 96 % of its charge and gets 4 % of the raw pixel above it's (a one-sided leak; the top row keeps its own), so flat noise is correlated between vertical neighbours; bias and dark frames untouched."""
    if kind != "flat":
        return dn
    _, h, w = dn.shape
    raw = _packed_to_raw(dn)
    above = np.concatenate([raw[:1], raw[:-1]], axis=0)
    return _raw_mask_to_packed(0.96 * raw + 0.04 * above)


def partial_dead_rows(dn, rng, **_):
    """Broken row lines: 3 sensor rows (fixed) read code 0 (512 DN below black) from the left edge to a fixed column, in every kind of frame."""
    _, h, w = dn.shape
    raw = np.zeros((2 * h, 2 * w), dtype=bool)
    where = np.random.default_rng(183)
    for _ in range(3):
        y, x = where.integers(0, 2 * h), where.integers(w // 2, 3 * w // 2)
        raw[y, :x] = True
    return np.where(_raw_to_packed(raw), -512.0, dn)


def readout_dark_gradient(dn, rng, exposure=0.0, k=1.0, **_):
    """A slow rolling readout: sensor row y is read 1 s x y / rows after the first, so it collects 3 e-/s of dark current for that much longer than the exposure (with its shot noise): bias frames ramp by 3 e- down the rows, darks too."""
    _, h, w = dn.shape
    t = exposure + np.arange(2 * h)[:, None] / (2 * h) * np.ones((1, 2 * w))
    return dn + k * _raw_to_packed(rng.poisson(3.0 * t).astype(np.float64))


def column_read_spread(dn, rng, **_):
    """Every column amplifier its own noise: each sensor column adds white noise of 1 DN x a lognormal factor (sigma 0.5 in log, drawn once), new at every pixel and frame, in every kind of frame."""
    _, h, w = dn.shape
    s = np.exp(0.5 * np.random.default_rng(185).standard_normal(2 * w))
    e = np.stack([s[0::2], s[1::2], s[1::2], s[0::2]])[:, None, :]  # R, G2 on even sensor columns
    return dn + e * rng.standard_normal(dn.shape)


def row_dark_current(dn, rng, exposure=0.0, k=1.0, **_):
    """Dark current per row driver: each sensor row's dark current is 2 e-/s x a lognormal factor (sigma 0.5 in log, drawn once), with its shot noise, in every kind of frame."""
    _, h, w = dn.shape
    rate = 2.0 * np.exp(0.5 * np.random.default_rng(187).standard_normal(2 * h))[:, None] * np.ones((1, 2 * w))
    return dn + k * _raw_to_packed(rng.poisson(rate * exposure).astype(np.float64))


# the nineteenth fresh batch (thirty-third session), written and committed before the loop ran on it
def warming_session_dark(dn, rng, kind="", exposure=0.0, k=1.0, **_):
    """A sensor warming through the calibration session, taken from the lowest ISO up: the dark current is 1 e-/s at K 0.375 and 1.5 times more at each doubling of K (with its shot noise), in every kind of frame."""
    rate = 1.0 * (k / 0.375) ** np.log2(1.5)
    return dn + k * rng.poisson(rate * exposure, dn.shape)


def edge_row_gain(dn, rng, **_):
    """Rows at the frame's top and bottom edges convert at a lower gain: the first and last 6 sensor rows read 0.95 of the signal and noise, in every kind of frame."""
    _, h, w = dn.shape
    g = np.ones(2 * h)
    g[:6], g[-6:] = 0.95, 0.95
    return dn * np.stack([g[0::2], g[0::2], g[1::2], g[1::2]])[:, :, None]  # R, G1 on even sensor rows


def coarse_codes_high_iso(dn, rng, k=1.0, **_):
    """A 12-bit readout mode at the highest ISO: at K 3 the camera writes codes in steps of 4 DN (the signal rounded to a multiple of 4 before the black level is added); the other ISOs write every code."""
    return 4.0 * np.round(dn / 4.0) if k > 2.5 else dn


def dead_column_pairs(dn, rng, **_):
    """Broken column-pair buses: 3 pairs of adjacent sensor columns (fixed places) read black (0 DN above it, without noise) over their whole length, in every kind of frame."""
    _, h, w = dn.shape
    mask = np.zeros((2 * h, 2 * w), dtype=bool)
    for x in np.random.default_rng(191).integers(2, 2 * w - 3, 3):
        mask[:, x : x + 2] = True
    return np.where(_raw_mask_to_packed(mask), 0.0, dn)


def hot_pixel_halo(dn, rng, exposure=0.0, k=1.0, **_):
    """Hot pixels whose charge diffuses: 30 sensor pixels (fixed places) collect 50 e-/s of dark current and each of their four raw neighbours 8 % of that, with its shot noise, in every kind of frame."""
    _, h, w = dn.shape
    rate = np.zeros((2 * h, 2 * w))
    places = np.random.default_rng(193)
    for y, x in zip(places.integers(1, 2 * h - 1, 30), places.integers(1, 2 * w - 1, 30)):
        rate[y, x] += 50.0
        for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            rate[y + dy, x + dx] += 4.0
    return dn + k * _raw_to_packed(rng.poisson(rate * exposure).astype(np.float64))


def serial_cti(dn, rng, kind="", **_):
    """Charge transfer inefficiency along the rows: in flats each raw pixel keeps 98 % of its charge and the next pixel along its row gets the 2 % it left (the first column keeps its own), so flat noise is correlated between horizontal neighbours; bias and dark frames untouched."""
    if kind != "flat":
        return dn
    _, h, w = dn.shape
    raw = _packed_to_raw(dn)
    left = np.concatenate([raw[:, :1], raw[:, :-1]], axis=1)
    return _raw_mask_to_packed(0.98 * raw + 0.02 * left)


# the twentieth fresh batch (thirty-fourth session), written and committed before the loop ran on it
def row_read_spread(dn, rng, **_):
    """Every row driver its own noise: each sensor row adds white noise of 1 DN x a lognormal factor (sigma 0.5 in log, drawn once), new at every pixel and frame, in every kind of frame."""
    _, h, w = dn.shape
    s = np.exp(0.5 * np.random.default_rng(197).standard_normal(2 * h))
    e = np.stack([s[0::2], s[0::2], s[1::2], s[1::2]])[:, :, None]  # R, G1 on even sensor rows
    return dn + e * rng.standard_normal(dn.shape)


def pixel_read_spread(dn, rng, **_):
    """Every pixel its own read noise: each pixel adds white noise of 1.5 DN x a lognormal factor (sigma 0.4 in log, drawn once per pixel), new in every frame, in every kind of frame."""
    s = 1.5 * np.exp(0.4 * _fixed(199, dn.shape))
    return dn + s * rng.standard_normal(dn.shape)


def dark_excess_noise(dn, rng, exposure=0.0, k=1.0, **_):
    """Dark current released in packets: dark electrons come 4 at a time, 2 e-/s on average, so the dark signal's shot noise is twice Poisson's (4 x its variance), in every kind of frame (it only shows in the 4 s darks)."""
    return dn + k * 4.0 * rng.poisson(0.5 * exposure, dn.shape)


def embedded_data_rows(dn, rng, **_):
    """Embedded metadata left in the raw: the last 2 sensor rows hold status words, codes fixed from frame to frame (uniform 0 to 1000 DN above black, drawn once) except the first 8 pixels of the last row, a frame counter, in every kind of frame."""
    _, h, w = dn.shape
    raw = _packed_to_raw(dn)
    raw[-2:] = np.random.default_rng(201).integers(0, 1000, (2, 2 * w)).astype(np.float64)
    n = _WALK.get("embedded_data_rows", 0)
    _WALK["embedded_data_rows"] = n + 1
    raw[-1, :8] = float(n % 256)
    return _raw_mask_to_packed(raw)


def diagonal_crosstalk(dn, rng, kind="", **_):
    """Optical crosstalk through the microlenses at an angle: in flats each raw pixel keeps 97 % of its charge and gets 3 % of its upper-left diagonal neighbour's (the first row and column keep their own), so flat noise is correlated at the diagonal lag; bias and dark frames untouched."""
    if kind != "flat":
        return dn
    raw = _packed_to_raw(dn)
    upper_left = raw.copy()
    upper_left[1:, 1:] = raw[:-1, :-1]
    return _raw_mask_to_packed(0.97 * raw + 0.03 * upper_left)


def column_gain_high_iso(dn, rng, k=1.0, **_):
    """Column amplifier gain mismatch at high analog gain only: at K >= 1.5 each sensor column's gain is off by 0.8 % rms (one fixed pattern), signal and noise alike; below, the columns match."""
    if k < 1.5:
        return dn
    _, h, w = dn.shape
    g = 1.0 + 0.008 * np.random.default_rng(203).standard_normal(2 * w)
    return dn * np.stack([g[0::2], g[1::2], g[1::2], g[0::2]])[:, None, :]  # R, G2 on even sensor columns


# the twenty-first fresh batch (thirty-fourth session), written and committed before the loop ran on it
def column_pattern_per_iso(dn, rng, k=1.0, **_):
    """Column offsets set anew at every gain: each ISO has a fixed pattern of sensor-column offsets of its own, 1.0 DN rms (drawn once per ISO), the same in every frame of that ISO, in every kind of frame."""
    _, h, w = dn.shape
    c = np.random.default_rng(205 + int(round(100 * k))).normal(0.0, 1.0, 2 * w)
    return dn + np.stack([c[0::2], c[1::2], c[1::2], c[0::2]])[:, None, :]  # R, G2 on even sensor columns


def first_frame_noise(dn, rng, kind="", exposure=0.0, k=1.0, **_):
    """A readout that settles after each change of setting: the first frame after a change (the first bias frame of an ISO, the first dark, the first flat of each level) reads with 2.5 DN more white noise."""
    key = ("first_noise", id(rng), kind, exposure, k)
    first = key not in _WALK
    _WALK[key] = True
    return dn + (2.5 * rng.standard_normal(dn.shape) if first else 0.0)


def bimodal_hot_pixels(dn, rng, exposure=0.0, k=1.0, **_):
    """Two kinds of hot pixels: 0.2 % of the pixels (fixed) collect 15 e-/s more and another 0.02 % 400 e-/s more, with its shot noise, so bias frames show none."""
    u = np.random.default_rng(207).random(dn.shape)
    rate = np.where(u < 0.002, 15.0, 0.0) + np.where((u >= 0.002) & (u < 0.0022), 400.0, 0.0)
    return dn + k * rng.poisson(rate * exposure)


def adc_inl(dn, rng, **_):
    """The ADC's integral non-linearity: every reading bent by 12 DN x sin(2 pi x DN / 16000) (an S-shaped transfer over the range), in every kind of frame."""
    return dn + 12.0 * np.sin(2.0 * np.pi * dn / 16000.0)


def ring_pattern(dn, rng, **_):
    """A fixed pattern of rings: the black level off by 0.7 DN x cos(2 pi r / 48) about the frame's centre (r in sensor pixels), the same in every frame of every kind (the mura of a clamp network)."""
    _, h, w = dn.shape
    y, x = np.mgrid[0 : 2 * h, 0 : 2 * w]
    r = np.hypot(y - h + 0.5, x - w + 0.5)
    return dn + _raw_mask_to_packed(0.7 * np.cos(2.0 * np.pi * r / 48.0))


def dark_column_telegraph(dn, rng, exposure=0.0, k=1.0, **_):
    """Leaky columns that switch: 0.5 % of the sensor columns (fixed) collect 3 e-/s more dark current in about half of the frames (high or low drawn per frame), with its shot noise, at every pixel of the column."""
    _, h, w = dn.shape
    leaky = np.random.default_rng(209).random(2 * w) < 0.005
    high = leaky & (rng.random(2 * w) < 0.5)
    rate = np.broadcast_to(np.where(high, 3.0, 0.0), (2 * h, 2 * w))
    return dn + k * _raw_to_packed(rng.poisson(rate * exposure).astype(np.float64))


CASES = {f.__name__: f for f in (coupled_readout, shared_pixel, tone, two_tones, black_drift, telegraph, channel_read,
                                 split_readout, parity_rows, fixed_rows, column_tone, dead_pixels, row_flicker, adc_dnl,
                                 column_gain, dark_hot_pixels, diagonal_tone, green_imbalance,
                                 leaky_columns, clamp_sag, gain_jitter, coarse_adc,
                                 impulses, column_flicker, reset_transient, noisy_frames,
                                 pdaf_pixels, row_gain, charge_sharing, lens_shading, companded_raw, channel_black,
                                 ramp_jitter, pixel_prnu, dark_current, dsnu, pixel_offsets, column_offsets, soft_knee,
                                 hot_pixels, black_clip, fixed_tone, locked_tone, noisy_pixels, thermal_gradient, leaky_rows,
                                 dark_telegraph, noisy_columns, adc_banks, row_telegraph, wide_codes, split_black,
                                 split_gain, top_bottom_black, clamp_ramp, channel_gain, weak_columns, warming_dark,
                                 amp_glow, random_missing_codes, defect_couplets, black_shading, gain_drift, column_noise,
                                 stuck_pixels, charge_transfer, dark_read_noise, read_noise_gradient, parity_row_gain,
                                 channel_dark, image_lag, black_by_iso, cosmic_rays, row_gain_noise, column_telegraph,
                                 low_light_toe, pixel_gain_noise, stuck_bit, alternating_black, blotchy_fpn, dim_pixels,
                                 laplace_rows, pixel_wander, dropouts, triple_adc_columns, column_flicker_1f,
                                 repeated_rows, quadrant_offsets, noisy_third_columns, hot_clusters, bit_flips, black_ramp,
                                 intermittent_tone, pixel_ringing, bank_gain, burst_rows, excess_shot_noise, black_col_ramp,
                                 partial_dead_columns, noisy_row_bank, wandering_tone, paired_columns, row_noise_ramp,
                                 noisy_edge_columns, hot_tiles, red_compression, ar_row_noise, skewed_read_noise,
                                 checker_tiles, partial_hot_columns, bimodal_black, column_dark_current, noisy_patch,
                                 row_spikes, first_frame_black, exposure_black_shift, column_wander, smooth_dsnu,
                                 column_bank_flicker, full_well, row_wander, digital_iso, burst_columns,
                                 bimodal_read_noise, row_pairs, gain_scaled_fpn, blue_prnu, periodic_rows, gain_telegraph,
                                 dark_row_noise, channel_digital_gain, masked_rows, dual_gain_codes, raw_smoothing,
                                 split_row_noise, column_pairs, block_compression, column_gain_flicker, noisy_rows,
                                 black_step, interleaved_row_gain, frame_row_noise, dark_hot_band, adc_white_clip,
                                 flicker_bands, dust_shadow, row_block_black, clock_feedthrough, vertical_read_corr,
                                 column_group_gain, row_gain_band, shared_pair_fpn, read_noise_gradient, dark_rate_jitter,
                                 partial_hot_rows, dead_clusters, dark_half_step, gain_drift_sequence, half_column_noise,
                                 shared_pair_gain, pixel_nonlinearity, vertical_charge_leak, partial_dead_rows,
                                 readout_dark_gradient, column_read_spread, row_dark_current, warming_session_dark,
                                 edge_row_gain, coarse_codes_high_iso, dead_column_pairs, hot_pixel_halo, serial_cti,
                                 row_read_spread, pixel_read_spread, dark_excess_noise, embedded_data_rows,
                                 diagonal_crosstalk, column_gain_high_iso, column_pattern_per_iso, first_frame_noise,
                                 bimodal_hot_pixels, adc_inl, ring_pattern, dark_column_telegraph)}
CASES["none"] = None
# cameras whose right answer is to add nothing: black_by_iso joined after its first run (twenty-first
# session): a per-ISO black offset is the ELD model's own colour bias, which the loop fitted as
# 0.30, 0.60, 1.20, 2.40 DN for the 0.8 K planted
NOTHING_TO_ADD = {"none", "lens_shading", "black_by_iso"}


# Session geometries: "small" is the default of write_manifest_camera; "issue" is the one issue 11's
# test cameras were reported with (512 x 384 mosaics, 4 ISOs, 8 bias frames, 4 darks of 4 s,
# flat pairs at five levels).
GEOMETRIES = {
    "small": {},
    "issue": {"size": (192, 256), "isos": ((400, 0.375), (800, 0.75), (1600, 1.5), (3200, 3.0)), "n_bias": 8,
              "flat_levels": (0.02, 0.05, 0.1, 0.2, 0.4)},
}


def run_case(name: str, seed: int, geometry: str = "small", keep: Path | None = None, base: str = BASE) -> dict:
    _WALK.clear()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) if keep is None else keep / name
        folder.mkdir(parents=True, exist_ok=True)
        manifest = write_manifest_camera(folder, NoiseProfile.load(base), post=CASES[name], seed=seed, **GEOMETRIES[geometry])
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            warnings.simplefilter("ignore")
            if cli(["loop", str(manifest), "--out", str(folder / "loop.yaml"), "--report", str(folder / "report"), "--n-synth", "8"]):
                raise RuntimeError(f"rawaug loop failed on camera {name!r}")
        data = json.loads((folder / "report" / "report.json").read_text())
    steps = [s for s in data["steps"] if s.get("accepted")]
    stacks: dict = {}
    for u in data.get("unexplained", []):
        stacks.setdefault(u["statistic"], set()).add(u["stack"])
    left = [f"{name} ({', '.join(sorted(where))})" if len(where) <= 2 else f"{name} ({len(where)} stacks)"
            for name, where in sorted(stacks.items())]
    fixed = bool(steps) and all(s["error_after"] <= 0.5 * s["error_before"] for s in steps) and not left
    return {"case": name, "added": [s["effect"] for s in steps],
            "errors": [f"{s['effect']} {s['error_before']:.2f} -> {s['error_after']:.2f}" for s in steps], "left": left,
            "fixed": (not steps and not left) if name in NOTHING_TO_ADD else fixed}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="*", help=f"cases (default: all): {', '.join(CASES)}")
    parser.add_argument("--seed", type=int, default=0, help="camera session (frames and patterns)")
    parser.add_argument("--geometry", choices=list(GEOMETRIES), default="small",
                        help="small: 64 x 64 packed, 2 ISOs, 6 bias, 2 flat levels; issue: 512 x 384 mosaics, 4 ISOs, "
                             "8 bias, 5 flat levels")
    parser.add_argument("--sessions", type=int, default=1,
                        help="run each camera in sessions SEED .. SEED + N - 1 and count how often it is fixed")
    parser.add_argument("--base", default=BASE, help=f"the ELD camera the test cameras start from (default {BASE})")
    parser.add_argument("--keep", type=Path, default=None,
                        help="keep each camera's frames, profile and loop report in KEEP/CASE (default: a temporary folder)")
    args = parser.parse_args(argv)
    unknown = [c for c in args.cases if c not in CASES]
    if unknown:
        parser.error(f"unknown cases {unknown}; known: {list(CASES)}")
    if args.sessions < 1:
        parser.error(f"--sessions must be >= 1, got {args.sessions}")
    if args.sessions > 1:
        return count_sessions(args.cases or list(CASES), args.seed, args.sessions, args.geometry, args.base)
    print("| camera (effect made outside rawaug) | added | evidence error | still significant | fixed |\n|---|---|---|---|---|")
    results = []
    for name in args.cases or CASES:
        r = run_case(name, args.seed, args.geometry, args.keep, args.base)
        results.append(r)
        print(f"| {name}: {(CASES[name].__doc__ or 'ELD model only').strip()} | {', '.join(r['added']) or '-'} | "
              f"{'; '.join(r['errors']) or '-'} | {', '.join(r['left']) or '-'} | {'yes' if r['fixed'] else 'no'} |", flush=True)
    print(f"\nfixed (or, for {', '.join(sorted(NOTHING_TO_ADD))}, nothing added): {sum(r['fixed'] for r in results)} of {len(results)}")
    return 0


def count_sessions(cases, first: int, n: int, geometry: str, base: str = BASE) -> int:
    """Each case in sessions first .. first + n - 1: how often it was fixed, and what was added where not."""
    print("| camera | sessions | fixed | where not: session (added; still significant) |\n|---|---|---|---|")
    for name in cases:
        runs = [(seed, run_case(name, seed, geometry, base=base)) for seed in range(first, first + n)]
        misses = "; ".join(f"{seed} ({', '.join(r['added']) or '-'}; {', '.join(r['left']) or '-'})" for seed, r in runs if not r["fixed"])
        print(f"| {name} | {first}-{first + n - 1} | {sum(r['fixed'] for _, r in runs)} of {n} | {misses or '-'} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
