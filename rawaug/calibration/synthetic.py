"""Calibration frame sets synthesized by rawaug itself, at known parameters (for tests,
the benchmark and demos). Frames come out as a real ADC would write them: integer raw
codes with the black level added (uint16), rounded and clipped to [0, white]."""
from __future__ import annotations

import numpy as np
import torch

from ..augment import RawNoiseAugment
from ..bayer import unpack
from ..profile import NoiseProfile


def synthesize_packed(profile: NoiseProfile, clean_normalized: float, *, k: float, sigma_tl: float, lam: float,
                      sigma_r: float, shape: tuple[int, int], seed: int, model: str = "G*+P*+R") -> np.ndarray:
    """One packed frame (4, h, w) of raw codes (uint16, black included) at gain ``k`` (DN/e-).

    ``clean_normalized`` is the uniform clean level (0 for a bias frame). Noise is drawn by
    ``RawNoiseAugment`` with ratio 1 and the given fixed parameters (sigmas in DN); the ADC
    rounding to integer codes is the quantization.
    """
    aug = RawNoiseAugment(profile, model=model, ratio=1.0, k=k, include_profile_effects=False,
                          fixed={"k": k, "sigma_tl": sigma_tl, "lambda": lam, "sigma_r": sigma_r, "sensor": 0},
                          generator=torch.Generator().manual_seed(int(seed)), rank_seeding=False)
    x = torch.full((1, 4) + tuple(shape), float(clean_normalized), dtype=torch.float32)
    with torch.no_grad():
        y = aug(x)[0].numpy()
    codes = np.rint(y.astype(np.float64) * profile.span_dn + profile.black_level)
    return np.clip(codes, 0, profile.white_level).astype(np.uint16)


def synthesize_iso_set(profile: NoiseProfile, *, k: float, sigma_tl: float, lam: float, sigma_r: float,
                       shape=(128, 128), n_bias: int = 2, flat_levels=(0.05, 0.15, 0.35), seed: int = 0,
                       model: str = "G*+P*+R"):
    """Bias frames and flat pairs (packed raw codes) of one ISO.

    Returns ``(bias_frames, flat_pairs)``; ``flat_levels`` are clean levels, normalized."""
    common = dict(k=k, sigma_tl=sigma_tl, lam=lam, sigma_r=sigma_r, shape=shape, model=model)
    bias = [synthesize_packed(profile, 0.0, seed=seed * 1000 + i, **common) for i in range(n_bias)]
    pairs = []
    for j, level in enumerate(flat_levels):
        base = seed * 1000 + 100 + 2 * j
        pairs.append((synthesize_packed(profile, level, seed=base, **common),
                      synthesize_packed(profile, level, seed=base + 1, **common)))
    return bias, pairs


def to_mosaic(packed: np.ndarray, cfa: str) -> np.ndarray:
    """Packed (4, h, w) -> Bayer mosaic (2h, 2w)."""
    return unpack(packed, cfa)
