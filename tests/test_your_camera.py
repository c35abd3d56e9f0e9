"""scripts/your_camera.sh, the README's "Your camera, end to end", run whole on a small
session of DNG files (read through rawpy): calibrate, loop, train, denoise to DNG."""
import csv
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from rawaug import NoiseProfile, RawNoiseAugment, unpack
from rawaug.io import read_frame
from rawaug.io.dng import write_dng

REPO = Path(__file__).resolve().parent.parent
SCENES = REPO / "rawaug" / "data" / "scenes"
BASE = NoiseProfile.load("SonyA7S2")
COLUMN = {"seed": 3, "k": [1.0], "sigma_dn": [1.5], "fixed_dn": [2.0]}  # the effect nobody declared
CAMERA = BASE.with_effect("Col", COLUMN)


def _noisy_codes(clean, k, iso_index, seed, exposure_s=1e-4, ratio=1.0):
    """Raw codes (H, W) of the camera at gain ``k`` for a packed clean frame (normalized)."""
    fixed = {"k": k, "sigma_tl": BASE.tukey_scale.median(k), "lambda": 0.05, "sigma_r": BASE.row_scale.median(k),
             "exposure_s": exposure_s, "sensor": 0}  # one camera: its fixed column pattern in every frame
    aug = RawNoiseAugment(CAMERA, model="G*+P*+R", ratio=ratio, fixed=fixed, rank_seeding=False,
                          generator=torch.Generator().manual_seed(10_000 * iso_index + seed))
    dn = aug(torch.as_tensor(clean, dtype=torch.float32)[None]).numpy()[0] * BASE.span_dn
    packed = np.clip(np.rint(dn + BASE.black_level), 0, BASE.white_level)
    return unpack(packed, "RGGB").astype(np.uint16)


def _session(folder):
    """Bias, 4 s dark and flat-pair DNGs at ISO 800 and 3200, and their manifest (no levels
    or CFA columns: those come from the raw files)."""
    folder.mkdir()
    rows = [["path", "kind", "iso", "exposure_s"]]
    for i, (iso, k) in enumerate([(800, 0.75), (3200, 3.0)]):
        shots = ([("bias", 1e-4, 0.0)] * 6 + [("dark", 4.0, 0.0)] * 4 + [("flat", 0.01, 0.02)] * 2
                 + [("flat", 0.05, 0.1)] * 2)
        for j, (kind, exposure, level) in enumerate(shots):
            codes = _noisy_codes(np.full((4, 48, 48), level), k, i, j, exposure_s=exposure)
            name = f"{kind}_{iso}_{j}.dng"
            write_dng(folder / name, codes, cfa="RGGB", black_level=BASE.black_level, white_level=BASE.white_level,
                      iso=iso, exposure_s=exposure)
            rows.append([name, kind, iso, exposure])
    with open(folder / "frames.csv", "w", newline="") as f:
        csv.writer(f).writerows(rows)
    return folder / "frames.csv"


def _scene_crops(folder, split, scenes, size=96):
    """Clean DNGs: crops of bundled real scenes, mapped onto the camera's levels."""
    (folder / split).mkdir(parents=True)
    out = []
    for name in scenes:
        packed = read_frame(SCENES / name, cfa="GRBG", black_level=12.5, white_level=255).packed_normalized()
        packed = np.clip(packed[:, :size, :size], 0, 1)
        codes = unpack(np.rint(packed * BASE.span_dn + BASE.black_level), "GRBG").astype(np.uint16)
        write_dng(folder / split / f"{Path(name).stem}.dng", codes, cfa="GRBG", black_level=BASE.black_level,
                  white_level=BASE.white_level, iso=100)
        out.append(packed)
    return out


def test_your_camera_end_to_end(tmp_path):
    frames = _session(tmp_path / "session")
    _scene_crops(tmp_path / "clean", "train", ["Indoor1_1024x1024.npz", "Outdoor1_1024x1024.npz"])
    val = _scene_crops(tmp_path / "clean", "val", ["Outdoor4_1024x1024.npz"])
    (tmp_path / "shots").mkdir()
    shot = _noisy_codes(val[0] / 100, 3.0, 1, 99, exposure_s=0.01, ratio=1.0)  # 1/100 of the light at ISO 3200
    shot = np.ascontiguousarray(shot[::-1, ::-1]).astype(np.uint16)  # RGGB read backwards: BGGR
    write_dng(tmp_path / "shots" / "night.dng", shot, cfa="BGGR", black_level=BASE.black_level,
              white_level=BASE.white_level, iso=3200, exposure_s=0.01)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}

    out = tmp_path / "mycam"
    small = ["--model.base_channels", "4", "--model.crop_size", "32", "--model.eval_crop", "64",
             "--trainer.max_epochs", "1", "--trainer.check_val_every_n_epoch", "1",
             "--data.init_args.train.init_args.repeat", "2", "--data.init_args.num_workers", "0",
             "--trainer.accelerator", "cpu"]
    env = {**os.environ, "RATIO": "100", "LOOP_OPTIONS": "--n-synth 6"}
    done = subprocess.run(["bash", str(REPO / "scripts" / "your_camera.sh"), str(frames), str(tmp_path / "clean"),
                           str(tmp_path / "shots"), str(out), *small], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]

    # Calibration and loop: the profile carries the camera's name; the loop found its column noise.
    assert NoiseProfile.load(out / "profile.yaml").camera == "mycam"
    assert NoiseProfile.load(out / "profile.yaml").k_min == pytest.approx(0.75, rel=0.1)
    assert list(yaml.safe_load((out / "loop_profile.yaml").read_text())["effects"]) == ["Col"]
    assert "Explained physically: `Col`." in (out / "loop" / "report.md").read_text()
    # Training: the last epoch's checkpoint, validation labelled with the camera.
    assert list(out.glob("run/version_*/checkpoints/last.ckpt"))
    assert "mycam" in (out / "run" / "results" / "val_results.csv").read_text()
    # Denoised shot: a DNG with the input's CFA, levels and ISO, and the .npy beside it.
    import rawpy

    with rawpy.imread(str(out / "denoised" / "night.dng")) as raw:
        assert raw.raw_image.shape == shot.shape
        assert "".join(chr(raw.color_desc[c]) for c in raw.raw_pattern.ravel()) == "BGGR"
        assert [int(v) for v in raw.black_level_per_channel] == [BASE.black_level] * 4
        assert raw.white_level == BASE.white_level
    assert np.load(out / "denoised" / "night.npy").shape == (4, shot.shape[0] // 2, shot.shape[1] // 2)
    # Inputs untouched.
    assert {p: p.read_bytes() for p in before} == before
    shutil.rmtree(out)
