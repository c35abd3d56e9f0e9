"""Poisson-Gaussian tables: `rawaug import-darktable` on a stand-in noiseprofiles.json
(made here, in darktable's layout), and G+P profiles without Tukey-lambda or row fits."""
import json
import math

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.cli import main

SPAN = 16383.0 - 512.0
ISOS = [100, 200, 400, 800, 1600, 3200, 6400]


def true_k(iso):
    return 0.0009563 * iso


def true_sigma(iso):
    return 1.2 * true_k(iso) ** 0.8 + 0.0 * iso


def write_noiseprofiles(path, negative_b_at=(100,)):
    profiles = []
    for iso in ISOS:
        a = true_k(iso) / SPAN
        b = (true_sigma(iso) / SPAN) ** 2
        # as darktable measures: after white balance (red x2.1, blue x1.6, green x1), so red and
        # blue ``a`` carry the multipliers; the read noise differs by channel around the true one
        # (geometric mean 1); an unresolved ISO has b <= 0 in one channel; one ISO listed twice
        bs = [b * 0.8, b / (0.8 * 1.25), b * 1.25 if iso not in negative_b_at else -1e-8]
        profiles.append({"name": f"Test Cam iso {iso}", "iso": iso, "a": [a * 2.1, a, a * 1.6], "b": bs})
    profiles.append(dict(profiles[3]))
    data = {"version": 0, "noiseprofiles": [
        {"maker": "Acme", "models": [{"model": "Test Cam", "profiles": profiles},
                                      {"model": "Test Cam II", "profiles": profiles[:1]}]}]}
    path.write_text(json.dumps(data))
    return path


def test_import_recovers_gain_and_read_noise(tmp_path):
    src = write_noiseprofiles(tmp_path / "noiseprofiles.json")
    out = tmp_path / "acme.yaml"
    with pytest.warns(UserWarning, match="ISO 100"):
        assert main(["import-darktable", str(src), "acme test cam", "--out", str(out),
                     "--black-level", "512", "--white-level", "16383"]) == 0
    profile = NoiseProfile.load(out)
    assert profile.camera == "Acme Test Cam" and profile.tukey_scale is None and profile.row_scale is None
    assert profile.richest_model == "G+P*+U"
    for iso in ISOS:  # K = a(green) * span at every ISO, the one without a read noise included
        assert math.isclose(profile.k_at_iso(iso), true_k(iso), rel_tol=1e-9)
    rel = profile.gaussian_scale
    assert math.isclose(rel.slope, 0.8, rel_tol=1e-9) and math.isclose(math.exp(rel.intercept), 1.2, rel_tol=1e-9)
    aug = RawNoiseAugment(profile, ratio=1.0, fixed={"k": 1.0, "sigma_g": 2.0})
    noise = (aug(torch.zeros(4, 4, 64, 64)) * profile.span_dn).numpy()
    assert abs(noise.std() / math.sqrt(2.0**2 + 1 / 12) - 1) < 5 * math.sqrt(1 / (2 * noise.size))
    # the training module's default model is the profile's (G*+P*+R+U would need fits it lacks)
    from rawaug.train import DenoiseModule

    assert DenoiseModule(base_channels=2, crop_size=16, profile=str(out)).noise.model == "G+P*+U"


def test_import_errors_name_the_problem(tmp_path, capsys):
    src = write_noiseprofiles(tmp_path / "noiseprofiles.json")
    args = ["--out", str(tmp_path / "x.yaml"), "--black-level", "512", "--white-level", "16383"]
    assert main(["import-darktable", str(src), "Acme Cam", *args]) == 2
    assert "similar: ['Acme Test Cam', 'Acme Test Cam II']" in capsys.readouterr().err
    assert main(["import-darktable", str(src), "Acme Test Cam II", *args]) == 2
    assert "at 0 ISO(s)" in capsys.readouterr().err
    assert main(["import-darktable", str(tmp_path / "missing.json"), "Acme Test Cam", *args]) == 2
    assert "do not exist" in capsys.readouterr().err
    assert not (tmp_path / "x.yaml").exists()


def test_models_needing_missing_fits_are_refused_with_the_alternative(tmp_path):
    src = write_noiseprofiles(tmp_path / "noiseprofiles.json", negative_b_at=())
    main(["import-darktable", str(src), "Acme Test Cam", "--out", str(tmp_path / "p.yaml"), "--black-level", "512",
          "--white-level", "16383"])
    profile = NoiseProfile.load(tmp_path / "p.yaml")
    with pytest.raises(ValueError, match="no Tukey-lambda read-noise fit.*'G\\+P\\*\\+U'"):
        RawNoiseAugment(profile, model="G*+P*")
    with pytest.raises(ValueError, match="no row-noise fit"):
        RawNoiseAugment(profile, model="G+P*+R")
    assert RawNoiseAugment(profile, model="G+P*+R", fixed={"sigma_r": 0.5}).model == "G+P*+R"


def test_a_poisson_gaussian_csv_table_calibrates(tmp_path):
    table = tmp_path / "pg.csv"
    table.write_text("iso,K,sigma_G\n" + "".join(f"{iso},{true_k(iso)},{true_sigma(iso)}\n" for iso in ISOS))
    out = tmp_path / "pg.yaml"
    assert main(["calibrate", str(table), "--out", str(out), "--cfa", "RGGB", "--black-level", "512",
                 "--white-level", "16383", "--report", str(tmp_path / "report")]) == 0
    assert "| sigma_TL | not measured" in (tmp_path / "report" / "report.md").read_text()
    profile = NoiseProfile.load(out)
    assert profile.tukey_scale is None and profile.row_scale is None
    assert np.isclose(profile.gaussian_scale.slope, 0.8)
