"""The ablation driver end to end at smoke scale: TestCam data, calibrate, loop, the real
LightningCLI fit and test for three rows, and the results tables."""
import csv
import subprocess
import sys
from pathlib import Path

RUN = Path(__file__).resolve().parents[1] / "benchmarks" / "ablation" / "run.py"


def test_ablation_smoke(tmp_path):
    out = tmp_path / "ablation"
    proc = subprocess.run([sys.executable, str(RUN), "--out", str(out), "--scale", "smoke", "--rows", "G", "loop", "paired real"],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert {r["model"] for r in rows} == {"G", "loop", "paired real"}
    assert {int(r["ratio"]) for r in rows} == {100, 200, 250, 300}
    for r in rows:
        assert 0 < float(r["psnr_db_mean"]) < 100 and 0 <= float(r["ssim_mean"]) <= 1
    assert (out / "results.md").read_text().count("| paired real |") == 1
    assert (out / "results.png").stat().st_size > 1000
    assert (out / "testcam_loop.yaml").is_file() and (out / "loop_report" / "report.md").is_file()
