"""TestCam: a simulated camera whose true noise holds effects the ELD model lacks.

Its base noise is the SonyA7S2 built-in profile (ELD's published calibration), taken at the
median of each joint relation at every ISO (a real camera's noise parameters are fixed at a
given ISO). On top of that, two effects that nobody declares to rawaug:

* **column noise** (``Col``): a fixed column pattern plus a per-frame column offset, both
  growing with the analog gain, comparable in size to the row noise;
* **dark shading / fixed-pattern noise** (``FPN``): a per-pixel offset map, the same in every
  frame, with a smooth shading gradient across the sensor.

Raw codes are rounded to integers (true quantization) and clipped to [0, white]. Frames are
written as self-describing ``.npz`` mosaics (levels, CFA, ISO, exposure inside), which
``rawaug.io.read_frame`` reads like any raw file.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import torch

from rawaug import NoiseProfile, RawNoiseAugment, unpack

TRUE_MODEL = "G*+P*+R+C"  # plus the profile's effects Col and FPN; quantization is real rounding
K_POINTS = [0.0939, 0.75, 6.01]  # DN/e-: ISO 100, 800, 6400
UNDECLARED = {
    "Col": {"seed": 7, "k": K_POINTS, "sigma_dn": [0.3, 0.8, 2.5], "fixed_dn": [0.4, 1.0, 3.0]},
    "FPN": {
        "seed": 11,
        "k": K_POINTS,
        "sigma_dn": [0.3, 0.7, 2.0],
        "shading_dn": [[[0.0, 0.4], [0.8, 1.2]], [[0.0, 1.0], [2.0, 3.0]], [[0.0, 3.0], [6.0, 9.0]]],
    },
}


def true_profile() -> NoiseProfile:
    profile = NoiseProfile.load("SonyA7S2")
    for token, params in UNDECLARED.items():
        profile = profile.with_effect(token, params)
    return profile


def iso_parameters(profile: NoiseProfile, iso: float) -> dict:
    """The camera's fixed noise parameters at one ISO."""
    k = profile.k_at_iso(iso)
    lam = profile.tukey_shape.nearest(k)
    bias = profile.color_bias.nearest(k)
    return {"k": k, "sigma_tl": profile.tukey_scale.median(k), "sigma_r": profile.row_scale.median(k),
            "lambda": lam, "color_bias_dn": list(bias)}


def capture(profile: NoiseProfile, clean: np.ndarray, iso: float, ratio: float, seed: int) -> np.ndarray:
    """Short-exposure raw codes (N, 4, h, w) of clean normalized packed frames (N, 4, h, w)."""
    aug = RawNoiseAugment(profile, model=TRUE_MODEL, ratio=ratio, fixed={**iso_parameters(profile, iso), "sensor": 0},
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    noisy = aug(torch.from_numpy(np.ascontiguousarray(clean, dtype=np.float32))).numpy()
    short_dn = noisy * profile.span_dn / ratio
    return np.clip(np.rint(short_dn + profile.black_level), 0, profile.white_level)


def save_frame(path: Path, packed_codes: np.ndarray, profile: NoiseProfile, iso: float, exposure_s: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    mosaic = unpack(packed_codes.astype(np.float32), profile.cfa)
    np.savez(path, mosaic=mosaic.astype(np.uint16) if np.allclose(mosaic, np.rint(mosaic)) else mosaic,
             black_level=profile.black_level, white_level=profile.white_level, cfa=profile.cfa, iso=iso, exposure_s=exposure_s)


def write_calibration_frames(out: Path, isos=(100, 400, 800, 1600, 3200, 6400), size=256, n_bias=8,
                             flat_levels=(0.01, 0.04, 0.15), seed=0) -> Path:
    """Bias frames and flat-field pairs of TestCam, and the CSV manifest describing them."""
    profile = true_profile()
    rows = []
    for i, iso in enumerate(isos):
        zeros = np.zeros((n_bias, 4, size, size), np.float32)
        for j, codes in enumerate(capture(profile, zeros, iso, 1.0, seed + 100 * i)):
            name = f"bias_iso{iso}_{j:02d}.npz"
            save_frame(out / name, codes, profile, iso, 1 / 8000)
            rows.append([name, "bias", iso, 1 / 8000])
        for m, level in enumerate(flat_levels):
            flats = np.full((2, 4, size, size), level, np.float32)
            exposure = level  # exposure time proportional to the flat level
            for j, codes in enumerate(capture(profile, flats, iso, 1.0, seed + 100 * i + 10 + m)):
                name = f"flat_iso{iso}_{m}{'ab'[j]}.npz"
                save_frame(out / name, codes, profile, iso, exposure)
                rows.append([name, "flat", iso, exposure])
    manifest = out / "manifest.csv"
    with open(manifest, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["path", "kind", "iso", "exposure_s"])
        writer.writerows(rows)
    return manifest


SHORT_EXPOSURE = {100: 0.1, 200: 0.05, 250: 0.04, 300: 1 / 30}


def write_sid_layout(out: Path, train_clean: list[np.ndarray], test_clean: list[np.ndarray], test_isos=(800, 1600, 3200),
                     ratios=(100, 200, 250, 300), train_pairs=4, seed=1) -> Path:
    """TestCam pairs in the SID Sony layout: ``Sony/long`` clean (10 s), ``Sony/short`` noisy, and
    ``Sony_train_list.txt`` (paired-real training) / ``Sony_test_list.txt`` (evaluation)."""
    profile = true_profile()
    rng = np.random.default_rng(seed)
    lines = {"train": [], "test": []}
    scenes = [("train", c) for c in train_clean] + [("test", c) for c in test_clean]
    for n, (split, clean) in enumerate(scenes, start=1):
        long_name = f"Sony/long/{n:05d}_00_10s.npz"
        save_frame(out / long_name, np.clip(clean, 0, 1) * profile.span_dn + profile.black_level, profile, 100, 10.0)
        settings = ([(int(rng.choice(test_isos)), int(rng.choice(ratios))) for _ in range(train_pairs)] if split == "train"
                    else [(test_isos[i % len(test_isos)], r) for i, r in enumerate(ratios)])
        for j, (iso, ratio) in enumerate(settings):
            exposure = SHORT_EXPOSURE[ratio]
            short_name = f"Sony/short/{n:05d}_{j:02d}_{exposure:g}s.npz"
            codes = capture(profile, clean[None], iso, ratio, seed * 1000 + n * 10 + j)[0]
            save_frame(out / short_name, codes, profile, iso, exposure)
            lines[split].append(f"./{short_name} ./{long_name} ISO{iso} F8")
    for split, entries in lines.items():
        (out / f"Sony_{split}_list.txt").write_text("\n".join(entries) + "\n")
    return out
