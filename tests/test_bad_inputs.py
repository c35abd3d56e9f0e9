"""The bad-input matrix: every case gets a clear error (exit code 2 and a message naming the
value), inputs stay byte-identical and no old output is destroyed."""
import hashlib
import os
import stat

import pytest

from rawaug import NoiseProfile
from rawaug.cli import main

TABLE = "iso,K,sigma_TL,lambda,sigma_r\n800,0.77,1.9,0.05,0.3\n1600,1.53,2.7,0.02,0.45\n3200,3.06,4.4,0.0,0.7\n"
TWO_CAMERAS = ("camera,iso,K,sigma_TL,lambda,sigma_r\n"
               "CamA,800,0.77,1.9,0.05,0.3\nCamA,1600,1.53,2.7,0.02,0.45\nCamA,3200,3.06,4.4,0.0,0.7\n"
               "CamB,800,0.5,1.9,0.05,0.3\nCamB,1600,1.0,2.7,0.02,0.45\nCamB,3200,2.0,4.4,0.0,0.7\n")
LEVELS = ["--cfa", "RGGB", "--black-level", "512", "--white-level", "16383"]


def digest(folder):
    """{relative path: sha256} of every file below ``folder``."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def workspace(tmp_path):
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "table.csv").write_text(TABLE)
    (tmp_path / "old").mkdir()
    assert main(["calibrate", str(tmp_path / "in" / "table.csv"), "--out", str(tmp_path / "old" / "p.yaml"),
                 "--report", str(tmp_path / "old" / "report"), *LEVELS]) == 0
    return tmp_path


CASES = {
    "out is the input": (["calibrate", "{in}/table.csv", "--out", "{in}/table.csv", *LEVELS], "would overwrite the input"),
    "report inside the input folder": (["calibrate", "{in}", "--out", "{tmp}/p.yaml", "--report", "{in}/rep", *LEVELS],
                                       "would mix report files with the input"),
    "report is the input file": (["calibrate", "{in}/table.csv", "--out", "{tmp}/p.yaml", "--report", "{in}/table.csv", *LEVELS],
                                 "is a file"),
    "out is a folder": (["calibrate", "{in}/table.csv", "--out", "{tmp}/old", *LEVELS], "is a folder"),
    "out below a file": (["calibrate", "{in}/table.csv", "--out", "{in}/table.csv/p.yaml", *LEVELS], "is a file, not a folder"),
    "black above white": (["calibrate", "{in}/table.csv", "--out", "{old}/p.yaml", "--report", "{old}/report", "--cfa", "RGGB",
                           "--black-level", "20000", "--white-level", "16383"], "white_level must exceed black_level"),
    "bit depth 99": (["calibrate", "{in}/table.csv", "--out", "{old}/p.yaml", "--report", "{old}/report", *LEVELS,
                      "--bit-depth", "99"], "--bit-depth must be in [1, 32], got 99"),
    "negative quantization step": (["calibrate", "{in}/table.csv", "--out", "{old}/p.yaml", "--report", "{old}/report", *LEVELS,
                                    "--quantization-step", "-1"], "--quantization-step must be > 0 DN, got -1"),
    "max samples -5": (["calibrate", "{in}/table.csv", "--out", "{old}/p.yaml", *LEVELS, "--max-samples", "-5"],
                       "--max-samples must be 0 (all) or >= 1000"),
    "absurd noise scale": (["calibrate", "{in}/absurd.csv", "--out", "{old}/p.yaml", "--report", "{old}/report", *LEVELS],
                           "more than the whole range"),
    "missing input": (["calibrate", "{in}/nope.csv", "--out", "{tmp}/p.yaml", *LEVELS], "does not exist"),
    "loop frame size 0": (["loop", "{in}/table.csv", "--report", "{tmp}/r", "--frame-size", "0", "0", *LEVELS],
                          "--frame-size ROWS COLS must be at least 2 2"),
    "loop n-synth 1": (["loop", "{in}/table.csv", "--report", "{tmp}/r", "--n-synth", "1", *LEVELS], "--n-synth must be >= 3"),
    "report holds other files": (["calibrate", "{in}/table.csv", "--out", "{tmp}/p.yaml", "--report", "{tmp}/mine", *LEVELS],
                                 "holds files that are not a rawaug report"),
    "several cameras, none chosen": (["calibrate", "{in}/two.csv", "--out", "{old}/p.yaml", *LEVELS],
                                     "holds 2 cameras (CamA, CamB); choose one with --camera"),
    "several cameras, unknown one": (["loop", "{in}/two.csv", "--report", "{tmp}/r", "--camera", "CamC", *LEVELS],
                                     "no camera 'CamC' in the table; it holds CamA, CamB"),
    "darktable out is its input": (["import-darktable", "{in}/table.csv", "Acme", "--out", "{in}/table.csv",
                                    "--black-level", "0", "--white-level", "1023"], "would overwrite the input"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_gets_a_clear_error_and_loses_nothing(workspace, case, capsys):
    argv, message = CASES[case]
    (workspace / "in" / "absurd.csv").write_text(TABLE.replace("1.9,", "1900000.0,").replace("2.7,", "2700000.0,")
                                                 .replace("4.4,", "4400000.0,"))
    (workspace / "in" / "two.csv").write_text(TWO_CAMERAS)
    (workspace / "mine").mkdir()
    (workspace / "mine" / "notes.txt").write_text("my own file")
    before = digest(workspace)
    paths = {"in": workspace / "in", "old": workspace / "old", "tmp": workspace}
    code = main([a.format(**paths) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1  # one line, no traceback
    assert digest(workspace) == before  # inputs and old outputs untouched, nothing new left behind


def test_bad_cfa_is_refused_by_the_parser(workspace, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", str(workspace / "in" / "table.csv"), "--out", str(workspace / "p.yaml"), "--cfa", "XYZ"])
    assert exc.value.code == 2 and "invalid choice: 'XYZ'" in capsys.readouterr().err


def test_a_rerun_replaces_the_report_whole_and_keeps_permissions(workspace):
    old = workspace / "old"
    (old / "report" / "stale_figure.png").write_bytes(b"old")
    os.chmod(old / "p.yaml", 0o644)
    assert main(["calibrate", str(workspace / "in" / "table.csv"), "--out", str(old / "p.yaml"),
                 "--report", str(old / "report"), *LEVELS]) == 0
    assert not (old / "report" / "stale_figure.png").exists()
    assert stat.S_IMODE((old / "p.yaml").stat().st_mode) == 0o644
    NoiseProfile.load(old / "p.yaml")
    previous = os.umask(0o027)
    try:
        assert main(["calibrate", str(workspace / "in" / "table.csv"), "--out", str(workspace / "new.yaml"), *LEVELS]) == 0
    finally:
        os.umask(previous)
    assert stat.S_IMODE((workspace / "new.yaml").stat().st_mode) == 0o640  # the umask's, not 0600


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt, OSError])
def test_an_interrupted_run_leaves_the_old_profile_and_report(workspace, monkeypatch, interrupt):
    from rawaug.calibration import report

    def broken(folder, *args, **kwargs):
        (folder / "report.json").write_text("half")
        raise interrupt("stopped while writing the report")

    monkeypatch.setattr(report, "write_report", broken)
    before = digest(workspace)
    argv = ["calibrate", str(workspace / "in" / "table.csv"), "--out", str(workspace / "old" / "p.yaml"),
            "--report", str(workspace / "old" / "report"), *LEVELS]
    if interrupt is KeyboardInterrupt:
        with pytest.raises(KeyboardInterrupt):
            main(argv)
    else:
        assert main(argv) == 2  # an OS error is one line naming it
    assert digest(workspace) == before
    assert sorted(p.name for p in (workspace / "old").iterdir()) == ["p.yaml", "report"]  # no temporary left


def _frames_manifest(folder, blacks, sep=",", bom=False):
    """2 ISOs x (1 bias + 2 flats) of 96x96 .npy frames; ``blacks``: the black level of each row."""
    import numpy as np

    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for n, (iso, kind, level) in enumerate([(800, "bias", 0), (800, "flat", 3000), (800, "flat", 3000),
                                            (1600, "bias", 0), (1600, "flat", 3000), (1600, "flat", 3000)]):
        frame = np.random.default_rng(n).normal(blacks[n] + level, 20, (96, 96)).clip(0, 16383).astype(np.uint16)
        np.save(folder / f"f{n}.npy", frame)
        rows.append(sep.join(map(str, [f"f{n}.npy", kind, iso, 0.01, "RGGB", blacks[n], 16383])))
    header = sep.join(["path", "kind", "iso", "exposure_s", "cfa", "black_level", "white_level"])
    (folder / "frames.csv").write_text(("\ufeff" if bom else "") + "\n".join([header] + rows) + "\n", encoding="utf-8")
    return folder / "frames.csv"


def test_frames_of_different_black_levels_are_refused(tmp_path, capsys):
    manifest = _frames_manifest(tmp_path / "in", [512, 600, 512, 512, 512, 512])
    assert main(["calibrate", str(manifest), "--out", str(tmp_path / "p.yaml"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "frames differ in black level" in err and "600.0" in err and not (tmp_path / "p.yaml").exists()


def test_a_semicolon_manifest_is_named_and_a_bom_is_read(tmp_path, capsys):
    from rawaug.calibration.command import _is_manifest_csv
    from rawaug.io import read_manifest

    semi = _frames_manifest(tmp_path / "semi", [512] * 6, sep=";")
    assert main(["calibrate", str(semi), "--out", str(tmp_path / "p.yaml"), "--no-progress"]) == 2
    assert "separated by ';'" in capsys.readouterr().err
    bom = _frames_manifest(tmp_path / "bom", [512] * 6, bom=True)
    assert _is_manifest_csv(bom)
    assert [e.kind for e in read_manifest(bom)][:2] == ["bias", "flat"]
