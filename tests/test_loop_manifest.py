"""`rawaug loop MANIFEST`: calibrate the base model from frames, then find what it lacks."""
import csv
import json

import numpy as np
import pytest
import torch
import yaml

from rawaug import NoiseProfile, RawNoiseAugment, unpack
from rawaug.cli import main

BASE = NoiseProfile.load("SonyA7S2")
COLUMN = {"seed": 3, "k": [1.0], "sigma_dn": [1.5], "fixed_dn": [2.0]}


def write_frames(folder, with_columns: bool):
    profile = BASE.with_effect("Col", COLUMN) if with_columns else BASE
    rows = []
    for i, (iso, k) in enumerate([(800, 0.75), (3200, 3.0)]):
        fixed = {"k": k, "sigma_tl": BASE.tukey_scale.median(k), "lambda": 0.05, "sigma_r": BASE.row_scale.median(k)}
        aug = RawNoiseAugment(profile, model="G*+P*+R", ratio=1.0, fixed=fixed, generator=torch.Generator().manual_seed(i), rank_seeding=False)
        frames = [("bias", 1e-4, 0.0, j) for j in range(6)] + [("flat", level, level, j) for level in (0.02, 0.1) for j in range(2)]
        clean = torch.tensor([f[2] for f in frames], dtype=torch.float32)[:, None, None, None].expand(len(frames), 4, 64, 64)
        codes = np.clip(np.rint(aug(clean.contiguous()).numpy() * BASE.span_dn + BASE.black_level), 0, BASE.white_level)
        for (kind, exposure, _, j), packed in zip(frames, codes):
            name = f"{kind}_{iso}_{exposure:g}_{j}.npy"
            np.save(folder / name, unpack(packed, "RGGB").astype(np.uint16))
            rows.append([name, kind, iso, exposure, "RGGB", 512, 16383])
    manifest = folder / "manifest.csv"
    with open(manifest, "w", newline="") as f:
        csv.writer(f).writerows([["path", "kind", "iso", "exposure_s", "cfa", "black_level", "white_level"]] + rows)
    return manifest


@pytest.mark.parametrize("with_columns", [True, False])
def test_loop_on_a_manifest_names_the_undeclared_effect(tmp_path, with_columns):
    manifest = write_frames(tmp_path, with_columns)
    out, report = tmp_path / "loop.yaml", tmp_path / "report"
    assert main(["loop", str(manifest), "--out", str(out), "--report", str(report), "--n-synth", "8"]) == 0
    assert (report / "calibration" / "base_profile.yaml").is_file()  # the base model was calibrated first
    steps = json.loads((report / "report.json").read_text())["steps"]
    accepted = [s for s in steps if s.get("accepted")]
    effects = yaml.safe_load(out.read_text())["effects"]
    if with_columns:
        assert "Col" in effects, steps
        col = next(s for s in accepted if s["effect"] == "Col")
        assert col["error_after"] <= 0.5 * col["error_before"], col
    else:
        assert accepted == [] and effects == {}, steps
