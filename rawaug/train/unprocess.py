"""Unprocessing (Brooks et al., *Unprocessing Images for Learned Raw Denoising*, CVPR 2019):
ordinary sRGB photos -> clean packed raw, by inverting a camera pipeline step by step.

Each step undoes one stage of the forward pipeline (raw -> white balance -> demosaic ->
colour correction -> gamma -> tone curve), in reverse order. Values are linear and
normalized (0 = black, 1 = white) once the gamma is undone. Written from the paper; no code
of the authors' is used.
"""
from __future__ import annotations

import numpy as np

# XYZ (D65) -> linear sRGB's inverse: linear sRGB -> XYZ (IEC 61966-2-1).
SRGB_TO_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                        [0.2126729, 0.7151522, 0.0721750],
                        [0.0193339, 0.1191920, 0.9503041]])
# XYZ -> camera of the Sony ILCE-7S / 7S II (the SonyA7S2 built-in profile's camera), as
# LibRaw/dcraw list it (the matrix rawpy reports as ``rgb_xyz_matrix`` for that camera).
XYZ_TO_SONY_A7S2 = np.array([[5838, -1430, -246], [-3497, 11477, 2297], [-748, 1885, 5778]]) / 10000.0


def inverse_tone(srgb: np.ndarray) -> np.ndarray:
    """Undo the global tone curve, a smoothstep ``3x^2 - 2x^3``: ``x = 1/2 - sin(asin(1 - 2y) / 3)``."""
    y = np.clip(srgb, 0.0, 1.0)
    return 0.5 - np.sin(np.arcsin(1.0 - 2.0 * y) / 3.0)


def inverse_gamma(x: np.ndarray, gamma: float = 2.2) -> np.ndarray:
    """Undo the display gamma: linear = x^2.2 (the paper's approximation of sRGB)."""
    return np.maximum(x, 1e-8) ** gamma


def rgb_to_camera(xyz_to_cam: np.ndarray) -> np.ndarray:
    """Linear sRGB -> camera RGB, rows normalized so white stays white (the forward colour
    correction maps camera white to sRGB white)."""
    m = np.asarray(xyz_to_cam, dtype=np.float64) @ SRGB_TO_XYZ
    return m / m.sum(axis=1, keepdims=True)


def inverse_white_balance(rgb: np.ndarray, red_gain: float, blue_gain: float, digital_gain: float) -> np.ndarray:
    """Divide out the white-balance and digital gains, keeping highlights: near white the
    inverse gain fades to 1, so saturated pixels are not pushed below white (as the paper does)."""
    gains = np.array([red_gain, 1.0, blue_gain]) * digital_gain
    gray = rgb.mean(axis=-1, keepdims=True)
    inflection = 0.9
    mask = (np.maximum(gray - inflection, 0.0) / (1.0 - inflection)) ** 2
    safe = np.maximum(mask + (1.0 - mask) / gains, 1.0 / gains)  # per-pixel inverse gains
    return rgb * safe


def mosaic_packed(cam: np.ndarray) -> np.ndarray:
    """(H, W, 3) camera RGB -> packed (4, H/2, W/2) in rawaug's order (R, G1, B, G2)."""
    h, w = (cam.shape[0] // 2) * 2, (cam.shape[1] // 2) * 2
    c = cam[:h, :w]
    return np.stack([c[0::2, 0::2, 0], c[0::2, 1::2, 1], c[1::2, 1::2, 2], c[1::2, 0::2, 1]])


def random_gains(rng: np.random.Generator) -> tuple[float, float, float]:
    """(red, blue, digital) gains as the paper draws them: red U(1.9, 2.4), blue U(1.5, 1.9),
    digital 1 / N(0.8, 0.1)."""
    return float(rng.uniform(1.9, 2.4)), float(rng.uniform(1.5, 1.9)), float(1.0 / np.clip(rng.normal(0.8, 0.1), 0.5, 1.1))


def unprocess(srgb: np.ndarray, rng: np.random.Generator, xyz_to_cam=XYZ_TO_SONY_A7S2) -> np.ndarray:
    """An sRGB image (H, W, 3), values in [0, 1] -> clean packed raw (4, H/2, W/2), float32, normalized."""
    srgb = np.asarray(srgb, dtype=np.float64)
    if srgb.ndim != 3 or srgb.shape[2] != 3 or min(srgb.shape[:2]) < 2:
        raise ValueError(f"an sRGB image must be (H, W, 3) with H, W >= 2, got shape {srgb.shape}")
    linear = inverse_gamma(inverse_tone(srgb))
    cam = linear @ rgb_to_camera(xyz_to_cam).T
    cam = inverse_white_balance(np.clip(cam, 0.0, 1.0), *random_gains(rng))
    return np.clip(mosaic_packed(cam), 0.0, 1.0).astype(np.float32)
