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


def write_manifest_camera(folder, profile: NoiseProfile, *, post=None, seed: int = 0, isos=((800, 0.75), (3200, 3.0)),
                          n_bias: int = 6, n_dark: int = 4, dark_exposures=(4.0,), flat_levels=(0.02, 0.1), lights: bool = False,
                          size: int | tuple[int, int] = 64, cfa: str = "RGGB", n_flat: int = 2):
    """A virtual camera's calibration frames as a manifest (``folder/manifest.csv``) of 16-bit
    mosaics: at each (ISO, K DN/e-) of ``isos``, ``n_bias`` bias frames, ``n_dark`` dark frames
    per exposure of ``dark_exposures`` (s) and ``n_flat`` flats (a pair by default) at ``flat_levels`` (fraction of
    white; exposure in seconds = level, or with ``lights`` all at 0.5 s under a relative light
    = level, listed in the manifest's ``light`` column), ``size`` x ``size`` per packed channel (or
    ``size = (height, width)``).
    The noise is ``profile``'s (``G*+P*+R`` at its median sigmas, lambda 0.05, and every effect
    it holds, one sensor instance), then ``post(dn, rng, kind=, exposure=, k=)``: a change to
    the black-subtracted DN that no rawaug stage makes (an undeclared effect of your own).
    Returns the manifest's path."""
    import csv
    from pathlib import Path

    folder = Path(folder)
    height, width = (size, size) if np.isscalar(size) else size
    rng = np.random.default_rng(5 + seed)
    rows = []
    for i, (iso, k) in enumerate(isos):
        frames = ([("bias", 1e-4, 0.0, j) for j in range(n_bias)]
                  + [("dark", t, 0.0, j) for t in dark_exposures for j in range(n_dark)]
                  + [("flat", 0.5 if lights else level, level, j) for level in flat_levels for j in range(n_flat)])
        for kind, exposure, level, j in frames:
            fixed = {"k": k, "sigma_tl": profile.tukey_scale.median(k), "lambda": 0.05, "sigma_r": profile.row_scale.median(k),
                     "exposure_s": exposure, "sensor": 0}  # one camera: one sensor in every frame
            aug = RawNoiseAugment(profile, model="G*+P*+R", ratio=1.0, fixed=fixed, rank_seeding=False,
                                  generator=torch.Generator().manual_seed(1000 * i + 10 * j + len(rows) + 100_003 * seed))
            dn = aug(torch.full((1, 4, height, width), level)).numpy()[0] * profile.span_dn
            dn = post(dn, rng, kind=kind, exposure=exposure, k=k) if post else dn
            packed = np.clip(np.rint(dn + profile.black_level), 0, profile.white_level)
            name = f"{kind}_{iso}_{exposure:g}_{level:g}_{j}.npy"
            np.save(folder / name, unpack(packed, cfa).astype(np.uint16))
            rows.append([name, kind, iso, exposure, cfa, f"{profile.black_level:g}", f"{profile.white_level:g}"]
                        + ([level if kind == "flat" else ""] if lights else []))
    manifest = folder / "manifest.csv"
    with open(manifest, "w", newline="") as f:
        header = ["path", "kind", "iso", "exposure_s", "cfa", "black_level", "white_level"] + (["light"] if lights else [])
        csv.writer(f).writerows([header] + rows)
    return manifest
