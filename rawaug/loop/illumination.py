"""The light a flat was taken under: its smooth shape over the sensor.

A flat field is never perfectly uniform: lens vignetting (cos^4 falloff), a light source's
own falloff and the colour shading of a lens make its level vary smoothly over the frame,
by 10-30 % in the corners with a lens on. That is the scene, not noise, and EMVA 1288
separates it from the sensor's non-uniformity the same way: by its low spatial frequency.
The loop synthesizes each flat as it was taken, under the measured shape of its light, so
that the spatial statistics of flats (row and column means, low-frequency power, the
fixed-pattern spread) compare the sensor's noise, not the light.

The shape is a 2-D Legendre polynomial of degree ``DEGREE`` per channel, fitted by least
squares to the flat stack's mean less its bias stack's mean (the black level and the dark
fixed pattern taken out), normalized to mean 1, and shrunk towards 1 by the positive-part
James-Stein factor: with uniform light the fit holds only the noise of the mean frame in its
``p`` non-constant terms, ``p`` times its pixel variance in squared norm, and that part is
taken out, so a uniform flat gets a shape of (nearly) exactly 1.
"""
from __future__ import annotations

import functools

import numpy as np
from numpy.polynomial import legendre

from ..effects.tap_gain import shown_gains
from ..statistics import lit_pixels

DEGREE = 6  # total degree of the polynomial: a cos^4 vignetting and a light's falloff are smooth to this order
TERMS = (DEGREE + 1) * (DEGREE + 2) // 2  # 28
MIN_PIXELS = 10 * TERMS  # per channel: fewer cannot tell a shape from the noise


def _lit_edges(mean_dn) -> np.ndarray:
    """``mean_dn`` (4, h, w) with the lines without light at the frame's edges (optically black
    lines left in the raw, ``statistics.lit_pixels``) set to the nearest lit line's values: a
    shield is neither the light's shape nor a readout tap's step."""
    lit = lit_pixels(mean_dn)
    if lit.all():
        return mean_dn
    _, h, w = mean_dn.shape
    out = np.empty_like(mean_dn)
    for c in range(4):
        rows, cols = np.flatnonzero(lit[c].any(axis=1)), np.flatnonzero(lit[c].any(axis=0))
        if not rows.size or not cols.size:
            out[c] = mean_dn[c]
            continue
        out[c] = mean_dn[c][np.clip(np.arange(h), rows[0], rows[-1])][:, np.clip(np.arange(w), cols[0], cols[-1])]
    return out


@functools.lru_cache(maxsize=32)
def _basis(h: int, w: int) -> np.ndarray:
    """(h * w, p) orthonormal basis of the 2-D Legendre polynomials of total degree <= DEGREE
    on an h x w grid, the constant first."""
    y = legendre.legvander(np.linspace(-1.0, 1.0, h), DEGREE)  # (h, DEGREE + 1)
    x = legendre.legvander(np.linspace(-1.0, 1.0, w), DEGREE)
    cols = [np.outer(y[:, i], x[:, j]).ravel() for i in range(DEGREE + 1) for j in range(DEGREE + 1 - i)]
    q, _ = np.linalg.qr(np.stack(cols, axis=1))
    return q * np.sign(q[0, 0])  # the first column is the constant, of either sign: made positive


def illumination_shape(mean_dn, edges=None, excess=None) -> np.ndarray:
    """(4, h, w) relative shape of a flat's light (mean 1 per channel) from ``mean_dn`` (4, h, w):
    the flat stack's mean frame above its black (DN). A channel without signal gets 1. The
    steps of readout taps with gains of their own (``tap_gain.shown_gains``) are the
    sensor's, not the light's: they are divided out before the fit, at ``edges`` (the
    sensor's, over its flats) or, without, at those the flat shows (``excess``: its stack's
    ``stack_step_excess``, the coloured temporal noise its steps are tested against)."""
    mean_dn = np.asarray(mean_dn, dtype=np.float64)
    if mean_dn.ndim != 3 or mean_dn.shape[0] != 4:
        raise ValueError(f"mean_dn must be a packed mean frame (4, h, w), got shape {mean_dn.shape}")
    mean_dn = _lit_edges(mean_dn)  # read once: the taps' steps and the light without the dark edge lines
    mean_dn = mean_dn / shown_gains(mean_dn, edges, excess)
    _, h, w = mean_dn.shape
    out = np.ones_like(mean_dn)
    if h * w < MIN_PIXELS or min(h, w) <= DEGREE:
        return out  # too few pixels to tell a shape from the noise
    q = _basis(h, w)
    p = q.shape[1]
    for c in range(4):
        m = mean_dn[c].ravel()
        coef = q.T @ m
        fit = q @ coef
        level = float(fit.mean())
        if not level > 0:
            continue
        noise = float(np.sum((m - fit) ** 2) / max(m.size - p, 1))  # per-pixel variance about the smooth fit
        dev = q[:, 1:] @ coef[1:]  # the fit less its constant part
        power = float(np.sum(coef[1:] ** 2))
        shrink = max(0.0, 1.0 - (p - 1) * noise / power) if power > 0 else 0.0
        shape = 1.0 + shrink * (dev - dev.mean()) / level
        out[c] = (shape / shape.mean()).reshape(h, w)
    return out
