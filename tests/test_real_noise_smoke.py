"""benchmarks/real_noise/run.py at its smoke scale, on the real dark frame's bundled crop:
the three training-noise rows run end to end and the test pairs carry the held-out real noise."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from rawaug import NoiseProfile

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "real_noise"))
import run as real_noise  # noqa: E402


@pytest.mark.slow  # 25 s: a loop and three trainings
def test_real_noise_benchmark_smoke(tmp_path):
    assert real_noise.main(["--out", str(tmp_path), "--smoke", "--dark", str(tmp_path / "absent.raw")]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    loop = NoiseProfile.load(tmp_path / "loop_profile.yaml")
    rows = [r for r in real_noise.ROWS if r != "loop without CodeMap" or "CodeMap" in loop.effects]
    assert [r["row"] for r in results] == rows  # the row without CodeMap only where the loop added it
    noisy = [results[0]["noisy_psnr"][str(q)] for q in real_noise.RATIOS]
    assert noisy[0] > noisy[1] > noisy[2]  # fewer photons at a higher ratio: noisier input
    assert "| sampled real | 1 |" in (tmp_path / "results.md").read_text()
    # the loop saw the crop's training rows: its profile holds effects the ELD model lacks
    assert loop.effects
    assert not NoiseProfile.load(tmp_path / "eld_profile.yaml").effects


def test_pairs_hold_the_held_out_dark_frame():
    dark = real_noise.read_dark(real_noise.DARK_CROP)
    held = dark[:, 100:]
    pairs = real_noise.test_pairs(held, dict(real_noise.SCALES["smoke"], test_tiles=2))
    assert len(pairs) == 2 * len(real_noise.RATIOS)
    for ratio, noisy, clean, (i, j) in pairs:
        h, w = clean.shape[1:]
        shot = noisy.astype(np.float64) * real_noise.WHITE / ratio - held[:, i : i + h, j : j + w]  # DN
        assert np.allclose(shot, np.rint(shot), atol=1e-3) and shot.min() > -1e-3  # counts x K = 1 DN/e-
        expected = clean.astype(np.float64) * real_noise.WHITE / ratio / real_noise.K  # Poisson means (e-)
        # the total count of Poisson draws: mean and variance both sum(expected); 6 sigma
        assert abs(shot.sum() - expected.sum()) < 6 * np.sqrt(expected.sum())


@pytest.mark.slow
def test_trainings_as_processes_are_cut_and_resumed(tmp_path):
    common = ["--out", str(tmp_path), "--smoke", "--dark", str(tmp_path / "absent.raw"), "--rows", "ELD", "sampled real",
              "--seeds", "0", "1", "--jobs", "2"]
    # cut before any training can finish (a child needs seconds to start): exit 3, nothing written
    assert real_noise.main(common + ["--time-limit", "0.5"]) == real_noise.UNFINISHED
    assert not list((tmp_path / "runs").glob("*.json"))
    assert real_noise.main(common + ["--time-limit", "600"]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    assert sorted((r["row"], r["seed"]) for r in results) == [("ELD", 0), ("ELD", 1), ("sampled real", 0), ("sampled real", 1)]
    # the same run in this process: the same scores (to 0.01 dB: thread counts may order sums differently)
    serial = tmp_path / "serial"
    assert real_noise.main(["--out", str(serial), "--smoke", "--dark", str(tmp_path / "absent.raw"), "--rows", "ELD",
                            "--seeds", "1"]) == 0
    one = json.loads((serial / "results.json").read_text())[0]
    child = next(r for r in results if r["row"] == "ELD" and r["seed"] == 1)
    assert one["psnr"] == pytest.approx(child["psnr"], abs=0.01)
