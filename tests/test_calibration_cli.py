"""`rawaug calibrate` end to end: real DNG files through rawpy (directory mode, kinds guessed),
a manifest of headerless files, a stage-2 table, and clean errors."""
import json

import numpy as np
import pytest

from rawaug.calibration.synthetic import synthesize_iso_set, to_mosaic
from rawaug.cli import main
from rawaug.io.dng import write_dng
from rawaug.profile import NoiseProfile

PROFILE = NoiseProfile.load("SonyA7S2")
SETS = [(400, 0.4, 1.5, 0.0, 0.3), (1600, 1.6, 4.0, -0.05, 0.8)]  # iso, K, sigma_TL, lambda, sigma_r


def _write_set(folder, fmt):
    rows = ["path,kind,iso,exposure_s,width,height,dtype,cfa,black_level,white_level"]
    for i, (iso, k, stl, lam, sr) in enumerate(SETS):
        bias, pairs = synthesize_iso_set(PROFILE, k=k, sigma_tl=stl, lam=lam, sigma_r=sr, shape=(96, 96), n_bias=2,
                                         flat_levels=(0.04, 0.12), seed=i + 7)
        frames = [("bias", b, 1 / 8000) for b in bias]
        frames += [("flat", f, 0.01 * (j + 1)) for j, pair in enumerate(pairs) for f in pair]
        for n, (kind, packed, exposure) in enumerate(frames):
            mosaic = to_mosaic(packed, "RGGB")
            if fmt == "dng":
                write_dng(folder / f"iso{iso}_{n:02d}.dng", mosaic, cfa="RGGB", black_level=512, white_level=16383,
                          iso=iso, exposure_s=exposure)
            else:
                name = f"iso{iso}_{n:02d}.raw"
                mosaic.astype("<u2").tofile(folder / name)
                rows.append(f"{name},{kind},{iso},{exposure},192,192,uint16,RGGB,512,16383")
    if fmt == "raw":
        (folder / "frames.csv").write_text("\n".join(rows) + "\n")


def test_directory_of_dng_files_to_profile_and_report(tmp_path, capsys):
    (tmp_path / "frames").mkdir()
    _write_set(tmp_path / "frames", "dng")
    out, report = tmp_path / "out" / "profile.yaml", tmp_path / "report"
    assert main(["calibrate", str(tmp_path / "frames"), "--out", str(out), "--report", str(report), "--no-progress"]) == 0
    assert "wrote" in capsys.readouterr().out
    prof = NoiseProfile.load(out)
    assert prof.iso_table[0] == (400.0, 1600.0)
    assert prof.k_at_iso(400) == pytest.approx(0.4, rel=0.05) and prof.k_at_iso(1600) == pytest.approx(1.6, rel=0.05)
    data = json.loads((report / "report.json").read_text())
    assert len(data["per_iso"]) == 2 and "r2_tukey" in data["per_iso"][0]["extra"]
    for fig in ("ppcc.png", "probplot_iso400.png", "bias_fft.png", "joint_fits.png", "photon_transfer.png"):
        assert (report / fig).stat().st_size > 1000
        assert fig in (report / "report.md").read_text()
    assert not list(out.parent.glob(".*"))  # atomic write left no temp file


def test_manifest_of_headerless_frames(tmp_path):
    _write_set(tmp_path, "raw")
    out = tmp_path / "p.yaml"
    assert main(["calibrate", str(tmp_path / "frames.csv"), "--out", str(out), "--no-progress"]) == 0
    assert NoiseProfile.load(out).k_max == pytest.approx(1.6, rel=0.05)


def test_stage2_table_and_clean_errors(tmp_path, capsys):
    from pathlib import Path

    pmn = Path(__file__).parents[1] / "rawaug" / "data" / "measured" / "PMN" / "PMN_noise_params_extracted.json"
    out = tmp_path / "sony.yaml"
    assert main(["calibrate", str(pmn), "--out", str(out), "--cfa", "RGGB", "--camera", "SonyA7S2"]) == 0
    prof = NoiseProfile.load(out)
    assert (prof.black_level, prof.white_level, prof.bit_depth) == (512, 16383, 14)
    assert main(["calibrate", str(pmn), "--out", str(out)]) == 2
    assert "--cfa" in capsys.readouterr().err
    (tmp_path / "m.csv").write_text("path,kind,iso,exposure_s\nf.npy,flat,100,0.01\nb.npy,bias,100,\n")
    np.save(tmp_path / "f.npy", np.zeros((8, 8), np.uint16))
    np.save(tmp_path / "b.npy", np.zeros((8, 8), np.uint16))
    assert main(["calibrate", str(tmp_path / "m.csv"), "--out", str(out), "--no-progress"]) == 2
    assert "single flat" in capsys.readouterr().err


def _counting_reads(monkeypatch):
    """Every frame read of a calibration, counted by path (the real reader is called)."""
    import rawaug.calibration.command as command
    from collections import Counter

    reads, real = Counter(), command.read_frame

    def read_frame(path, **hints):
        reads[str(path)] += 1
        return real(path, **hints)

    monkeypatch.setattr(command, "read_frame", read_frame)
    return reads


@pytest.mark.parametrize("base", ["calibrated", "--profile"])
def test_loop_reads_each_frame_once(tmp_path, monkeypatch, base):
    """``rawaug loop`` keeps its view of each frame as calibration reads it: every frame of
    the manifest, the flat calibration cannot pair included, is read exactly once."""
    _write_set(tmp_path, "raw")
    mosaic = np.fromfile(tmp_path / "iso400_02.raw", dtype="<u2").reshape(192, 192)
    np.roll(mosaic, 2, axis=1).tofile(tmp_path / "odd.raw")  # a third flat at the first level: no pair for it
    with open(tmp_path / "frames.csv", "a") as f:
        f.write("odd.raw,flat,400,0.01,192,192,uint16,RGGB,512,16383\n")
    reads = _counting_reads(monkeypatch)
    extra = ["--profile", "SonyA7S2"] if base == "--profile" else []
    assert main(["loop", str(tmp_path / "frames.csv"), "--out", str(tmp_path / "p.yaml"), "--report",
                 str(tmp_path / "report"), "--n-synth", "3", "--no-progress", *extra]) == 0
    listed = [line.split(",")[0] for line in (tmp_path / "frames.csv").read_text().splitlines()[1:]]
    assert sorted(reads) == sorted(str(tmp_path / name) for name in listed) and set(reads.values()) == {1}, reads
    stacks = json.loads((tmp_path / "report" / "report.json").read_text())["stacks"]
    assert [s["kind"] for s in stacks.values()].count("bias") == 2 and "flat" in [s["kind"] for s in stacks.values()]
    assert (tmp_path / "report" / "calibration").is_dir() == (base == "calibrated")


def test_loop_on_a_folder_without_manifest(tmp_path):
    """``rawaug loop`` takes what ``rawaug calibrate`` takes: a folder of raw files (DNG,
    through rawpy) without a manifest, kinds guessed from the frame means."""
    (tmp_path / "frames").mkdir()
    _write_set(tmp_path / "frames", "dng")
    report = tmp_path / "report"
    assert main(["loop", str(tmp_path / "frames"), "--out", str(tmp_path / "p.yaml"), "--report", str(report),
                 "--n-synth", "3", "--no-progress"]) == 0
    data = json.loads((report / "report.json").read_text())
    kinds = sorted(s["kind"] for s in data["stacks"].values())
    assert kinds.count("bias") == 2 and kinds.count("flat") >= 2, data["stacks"]
    assert NoiseProfile.load(tmp_path / "p.yaml").k_at_iso(1600) == pytest.approx(1.6, rel=0.05)
