"""The ELD ablation (Table 1) on TestCam, a camera whose true noise rawaug was never told about.

One command runs it all:

    python benchmarks/ablation/run.py --out runs/ablation --scale cpu     # CPU, <= 60 min
    python benchmarks/ablation/run.py --out runs/ablation --scale gpu     # full U-Net and crops
    python benchmarks/ablation/run.py --out runs/ablation --scale smoke   # seconds, for tests
    python benchmarks/ablation/run.py --out runs/ablation --scale gpu-short --jobs 8 --time-limit 560
                                      # rows as 8 processes sharing one GPU, BM3D on the CPU beside
                                      # them; exit status 3 when cut: run it again to resume

Steps: (1) TestCam's bias and flat frames -> ``rawaug calibrate`` (the ELD model) and
``rawaug loop`` (the closed loop's profile); (2) TestCam's noisy/clean pairs of the bundled
real scenes in the SID Sony layout; (3) the U-Net trained with each noise model from the
same clean scenes, and on TestCam's own pairs (paired real), each with several seeds;
(4) BM3D and Anscombe-BM3D; (5) PSNR/SSIM per ratio (the paper's protocol: one least-squares
scale per image, packed raw) as ``results.md``, ``results.csv`` and ``results.png``.

Every result is written the moment it exists (a training's test table, each BM3D pair) and a
later invocation on the same ``--out`` skips it; a training stopped by ``--time-limit`` resumes
from its last checkpoint (``ckpt_every`` steps).
"""
from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import math
import os
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import scenes  # noqa: E402
import testcam  # noqa: E402
from children import UNFINISHED, run_children  # noqa: E402

from rawaug import NoiseProfile  # noqa: E402
from rawaug.io import read_frame  # noqa: E402
from rawaug.atomic import write_text_atomic  # noqa: E402
from rawaug.train.metrics import evaluate  # noqa: E402

# the paper's rows, then the ELD model with its calibrated colour bias (TestCam's channel means
# sit 0.2-5.9 DN above black, jumping between ISOs: ELD's published SonyA7S2 biases plus the
# dark shading)
MODELS = ["G", "G+P", "G+P*", "G*+P*", "G*+P*+R", "G*+P*+R+U", "G*+P*+R+U+C"]
RATIOS = (100, 200, 250, 300)
TRAIN_PIECE = 256  # packed pixels: training scenes are cut into pieces of about this size
TEST_ISOS = (800, 1600, 3200)  # as in the ELD dataset

SCALES = {
    # steps: optimizer steps per run; base: U-Net width; crop: packed training crop; tile: packed test tile
    # residual/lr: the CPU recipe of configs/quickstart.yaml (a residual U-Net at lr 1e-3 converges in
    # minutes; its gradient norm clipped at 1: without, a spike at lr 1e-3 can leave a run at the
    # identity, the noisy input); the gpu scale is the paper's (direct U-Net, lr 1e-4).
    "smoke": dict(seeds=[0], steps=2, base=4, crop=32, batch=2, tile=32, test_tiles=2, frame=64, n_bias=2, bm3d=False, residual=True, lr=1e-3, n_synth=6,
                  ckpt_every=10),
    "cpu": dict(seeds=[0, 1], steps=1500, base=16, crop=64, batch=8, tile=128, test_tiles=9, frame=256, n_bias=8, bm3d=True, residual=True, lr=1e-3,
                clip=1.0, ckpt_every=250),
    # tile 128 at the GPU scales too: HalideN900, the third held-out scene, has one tile of 128 and none of 256
    "gpu": dict(seeds=[0, 1], steps=20000, base=32, crop=256, batch=4, tile=128, test_tiles=24, frame=512, n_bias=8, bm3d=True, residual=False, lr=1e-4,
                ckpt_every=1000),
    # the scale of the GPU table in issue 12 (H100: 3000 steps, lr 3e-4, 16 test tiles then of one scene)
    "gpu-short": dict(seeds=[0, 1], steps=3000, base=32, crop=256, batch=4, tile=128, test_tiles=24, frame=512, n_bias=8, bm3d=True, residual=False,
                      lr=3e-4, ckpt_every=500),
}


def make_data(out: Path, scale: dict) -> dict:
    frames = out / "frames"
    if not (frames / "manifest.csv").exists():
        testcam.write_calibration_frames(frames, size=scale["frame"] // 2, n_bias=scale["n_bias"])
    sid = out / "TestCam_SID"
    if not (sid / "Sony_test_list.txt").exists():
        # training: the bundled real scenes not held out and the bundled photos, unprocessed (those
        # a training crop fits in), in pieces of about 256 so each entry weighs alike; test: tiles
        # of three held-out real scenes (benchmarks/scenes.py)
        train = scenes.train_scenes(min_size=scale["crop"], piece=max(scale["crop"], TRAIN_PIECE))
        test = scenes.test_tiles(scale["tile"], scale["test_tiles"])
        testcam.write_sid_layout(sid, [s for _, s in train], [t for _, t in test], test_isos=TEST_ISOS, ratios=RATIOS)
        write_text_atomic(sid / "scenes.json", json.dumps({"train": [n for n, _ in train], "test_tiles": [n for n, _ in test]}))
    return {"manifest": frames / "manifest.csv", "sid": sid}


def run_cli(args: list[str], log: Path) -> None:
    with open(log, "w") as f:
        proc = subprocess.run([sys.executable, "-m", "rawaug.cli", *args], stdout=f, stderr=subprocess.STDOUT)
    if proc.returncode:
        raise RuntimeError(f"rawaug {' '.join(args)} failed (exit {proc.returncode}); see {log}")


def calibrate(out: Path, data: dict, with_loop: bool = True, n_synth: int = 12) -> dict:
    profiles = {"eld": out / "testcam_eld.yaml", "loop": out / "testcam_loop.yaml"}
    if not profiles["eld"].exists():
        run_cli(["calibrate", str(data["manifest"]), "--out", str(profiles["eld"]), "--report", str(out / "calibration_report")], out / "calibrate.log")
    if with_loop and not profiles["loop"].exists():
        run_cli(["loop", str(data["manifest"]), "--out", str(profiles["loop"]), "--report", str(out / "loop_report"),
                 "--n-synth", str(n_synth)], out / "loop.log")
    return profiles


def run_dir_of(out: Path, row: str, seed: int) -> Path:
    return out / "runs" / f"{row.replace('*', 's').replace('+', '_').replace(' ', '_')}_seed{seed}"


def step_checkpoint(path: Path, every: int):
    """A Lightning callback saving the whole training state to ``path`` every ``every`` steps,
    atomically (write, then rename), so a stopped training resumes from it."""
    import lightning as L

    class StepCheckpoint(L.Callback):
        def on_train_batch_end(self, trainer, *args) -> None:
            if trainer.global_step % every == 0 and trainer.global_step < trainer.max_steps:
                tmp = path.with_name(path.name + ".tmp")
                trainer.save_checkpoint(tmp)
                os.replace(tmp, path)

    return StepCheckpoint()


def train_and_test(row: str, seed: int, out: Path, data: dict, profiles: dict, scale: dict) -> Path:
    """Fit one U-Net with the real LightningCLI and test it on TestCam's pairs; returns the results CSV."""
    from lightning.pytorch.cli import LightningCLI

    from rawaug.train import DenoiseModule, RawDenoiseData

    run_dir = run_dir_of(out, row, seed)
    result = run_dir / "test_results.csv"
    if result.exists():
        return result
    paired = row == "paired real"
    profile = str(profiles["loop"] if row == "loop" else profiles["eld"])
    model = "G*+P*+R+U" if row in ("loop", "paired real") else row  # the loop row: the best ELD row's base + the loop's effects
    sid = str(data["sid"])
    calibrated = NoiseProfile.load(profiles["eld"])
    isos = scale.get("train_isos", TEST_ISOS)  # training gains: K over these ISOs' range, x1.25 each side
    k_train = [calibrated.k_at_iso(min(isos)) / 1.25, calibrated.k_at_iso(max(isos)) * 1.25]  # DN/e-
    config = {
        "seed_everything": seed,
        "trainer": {"accelerator": "auto", "devices": 1, "max_steps": scale["steps"], "logger": False, "enable_checkpointing": False,
                    "enable_progress_bar": False, "limit_val_batches": 0, "default_root_dir": str(run_dir), "enable_model_summary": False,
                    "gradient_clip_val": scale.get("clip")},
        "model": {"base_channels": scale["base"], "depth": 5, "residual": scale["residual"], "profile": profile, "noise_model": model,
                  "include_profile_effects": row == "loop", "ratio": [100, 300], "k": k_train, "crop_size": scale["crop"], "lr": scale["lr"],
                  "lr_milestones": [0.5, 0.9], "lr_factors": [0.5, 0.1], "seed": seed, "results_dir": str(run_dir), "image_log_size": 0},
        "data": {"class_path": "rawaug.train.RawDenoiseData", "init_args": {
            "batch_size": scale["batch"],
            "train": {"class_path": "rawaug.train.SIDSony", "init_args": {"root": sid, "list_file": "Sony_train_list.txt",
                                                                           "mode": "paired" if paired else "clean", "camera": "TestCam", "repeat": 64,
                                                                           "window": scale["crop"]}},
            "test": {"class_path": "rawaug.train.SIDSony", "init_args": {"root": sid, "list_file": "Sony_test_list.txt", "mode": "paired", "camera": "TestCam"}},
        }},
    }
    run_dir.mkdir(parents=True, exist_ok=True)
    cli = LightningCLI(DenoiseModule, RawDenoiseData, subclass_mode_data=True, args=config, run=False, save_config_callback=None)
    last = run_dir / "last.ckpt"
    if scale.get("ckpt_every"):
        cli.trainer.callbacks.append(step_checkpoint(last, scale["ckpt_every"]))
    resume = last if last.exists() else None
    if resume is not None:
        step = torch.load(resume, map_location="cpu", weights_only=False)["global_step"]
        print(f"{row} seed {seed}: resuming from {resume} (step {step})", flush=True)
    cli.trainer.fit(cli.model, datamodule=cli.datamodule, ckpt_path=str(resume) if resume else None)
    cli.trainer.test(cli.model, datamodule=cli.datamodule)
    if not result.exists():
        raise RuntimeError(f"the test step wrote no {result}")
    last.unlink(missing_ok=True)
    return result


# ----------------------------------------------------------------- non-deep baselines
def _test_pairs(sid: Path):
    from rawaug.train import SIDSony
    from rawaug.train.cache import FrameCache

    source = SIDSony(str(sid), "Sony_test_list.txt", mode="paired", camera="TestCam")
    source.bind(FrameCache()) if hasattr(source, "bind") else None
    entries = source.list_entries()
    for entry in entries:
        noisy = read_frame(testcam_path(entry["short"])).packed_normalized() * np.float32(entry["ratio"])
        clean = read_frame(testcam_path(entry["long"])).packed_normalized()
        yield entry, np.clip(noisy, 0, None), clean


def testcam_path(path: Path) -> Path:
    return path if path.exists() else path.with_suffix(".npz")


def gat(z, sigma):
    """Generalized Anscombe transform for unit-gain Poisson-Gaussian data (Makitalo & Foi)."""
    return 2.0 * np.sqrt(np.maximum(z + 3.0 / 8.0 + sigma**2, 0.0))


def gat_inverse(d, sigma):
    """Closed-form approximation of the exact unbiased inverse (Makitalo & Foi, 2013)."""
    d = np.maximum(d, 0.8)
    s = math.sqrt(1.5)
    return np.maximum(0.25 * d**2 + 0.25 * s / d - 11.0 / 8.0 / d**2 + 0.625 * s / d**3 - 0.125 - sigma**2, 0.0)


def bm3d_rows(out: Path, data: dict, profiles: dict) -> list[dict]:
    import bm3d

    cache = out / "bm3d_results.json"
    if cache.exists():
        return json.loads(cache.read_text())
    partial_path = out / "bm3d_pairs.json"  # {short frame: {method: [psnr, ssim]}}, written pair by pair
    partial = json.loads(partial_path.read_text()) if partial_path.exists() else {}
    profile = NoiseProfile.load(profiles["eld"])
    span = profile.span_dn
    results = defaultdict(list)
    for entry, noisy, clean in _test_pairs(data["sid"]):
        ratio, iso = entry["ratio"], entry["iso"]
        key = Path(entry["short"]).name
        if key in partial:
            for name, score in partial[key].items():
                results[(name, round(ratio))].append(tuple(score))
            continue
        k = profile.k_at_iso(iso)
        sigma_read = profile.gaussian_scale.median(k)  # DN, calibrated Gaussian read noise
        short_dn = noisy * span / ratio
        level = max(float(short_dn.mean()), 0.0)
        sigma = math.sqrt(k * level + sigma_read**2) * ratio / span  # normalized, at the mean level
        plain = np.stack([bm3d.bm3d(c.astype(np.float64), sigma_psd=sigma) for c in noisy])
        electrons = short_dn / k
        sig_e = sigma_read / k
        ans = np.stack([gat_inverse(bm3d.bm3d(gat(c, sig_e), sigma_psd=1.0), sig_e) for c in electrons]) * k * ratio / span
        partial[key] = {}
        for name, out_img in (("BM3D", plain), ("A-BM3D", ans)):
            m = evaluate(torch.from_numpy(out_img.astype(np.float32))[None], torch.from_numpy(clean)[None])
            results[(name, round(ratio))].append((float(m["psnr"]), float(m["ssim"])))
            partial[key][name] = [float(m["psnr"]), float(m["ssim"])]
        write_text_atomic(partial_path, json.dumps(partial))
    rows = [{"row": name, "seed": 0, "ratio": ratio, "psnr_db": float(np.mean([v[0] for v in vals])), "ssim": float(np.mean([v[1] for v in vals]))}
            for (name, ratio), vals in sorted(results.items())]
    write_text_atomic(cache, json.dumps(rows))
    partial_path.unlink(missing_ok=True)
    return rows


# ----------------------------------------------------------------- tables
def read_results(path: Path, row: str, seed: int) -> list[dict]:
    with open(path) as f:
        return [{"row": row, "seed": seed, "ratio": int(round(float(r["ratio"]))), "psnr_db": float(r["psnr_db"]), "ssim": float(r["ssim"]),
                 "psnr_noisy_db": float(r["psnr_noisy_db"])} for r in csv.DictReader(f)]


def summarize(rows: list[dict], order: list[str]) -> tuple[str, str]:
    cells = defaultdict(list)
    for r in rows:
        cells[(r["row"], r["ratio"])].append(r)
    ratios = sorted({r["ratio"] for r in rows})
    md = ["| model | seeds | " + " | ".join(f"x{q} PSNR / SSIM" for q in ratios) + " |", "|---|---|" + "---|" * len(ratios)]
    csv_lines = ["model,ratio,seeds,psnr_db_mean,psnr_db_spread,ssim_mean,ssim_spread"]
    for name in order:
        entries = []
        seeds = 0
        for q in ratios:
            vals = cells.get((name, q), [])
            if not vals:
                entries.append("-")
                continue
            seeds = len(vals)
            p = np.array([v["psnr_db"] for v in vals])
            s = np.array([v["ssim"] for v in vals])
            spread_p = float(p.max() - p.min())
            spread_s = float(s.max() - s.min())
            entries.append(f"{p.mean():.2f} ±{spread_p / 2:.2f} / {s.mean():.3f} ±{spread_s / 2:.3f}")
            csv_lines.append(f"{name},{q},{len(vals)},{p.mean():.4f},{spread_p:.4f},{s.mean():.4f},{spread_s:.4f}")
        md.append(f"| {name} | {seeds} | " + " | ".join(entries) + " |")
    noisy = defaultdict(list)
    for r in rows:
        if "psnr_noisy_db" in r:
            noisy[r["ratio"]].append(r["psnr_noisy_db"])
    if noisy:
        md.append("| noisy input | - | " + " | ".join(f"{np.mean(noisy[q]):.2f} / -" if q in noisy else "-" for q in ratios) + " |")
    md.append("")
    md.append("± is half the seed-to-seed range (max - min over seeds); BM3D rows are deterministic.")
    return "\n".join(md) + "\n", "\n".join(csv_lines) + "\n"


def plot(rows: list[dict], order: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ratios = sorted({r["ratio"] for r in rows})
    fig, ax = plt.subplots(figsize=(8, 4))
    for i, q in enumerate(ratios):
        means = [np.mean([r["psnr_db"] for r in rows if r["row"] == name and r["ratio"] == q] or [np.nan]) for name in order]
        ax.plot(range(len(order)), means, marker="o", label=f"x{q}")
        for name_i, name in enumerate(order):
            vals = [r["psnr_db"] for r in rows if r["row"] == name and r["ratio"] == q]
            ax.scatter([name_i] * len(vals), vals, s=8, color=f"C{i}", alpha=0.5)
    ax.set_xticks(range(len(order)), order, rotation=30, ha="right")
    ax.set_ylabel("PSNR (dB)")
    ax.set_title("TestCam ablation (dots: individual seeds)")
    ax.legend()
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(path)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="runs/ablation", help="output folder (reused: finished steps are skipped)")
    parser.add_argument("--scale", choices=sorted(SCALES), default="cpu")
    parser.add_argument("--rows", nargs="*", default=None, help="subset of rows to run")
    parser.add_argument("--collect", action="store_true", help="only tabulate the runs already finished in --out (no training)")
    parser.add_argument("--jobs", type=int, default=1, help="trainings at once, as child processes sharing the device "
                        "(with BM3D in one more on the CPU); 1 without --time-limit: all in this process, one after another")
    parser.add_argument("--time-limit", type=float, default=None, metavar="SECONDS",
                        help=f"stop this invocation after SECONDS: trainings keep their last checkpoint, the tables show what finished, "
                             f"the exit status is {UNFINISHED}; run again to resume")
    parser.add_argument("--steps", type=int, default=None, help="training steps instead of the scale's")
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="training seeds instead of the scale's")
    parser.add_argument("--train-isos", type=float, nargs="+", default=None, metavar="ISO",
                        help=f"train over the gains of these ISOs (K from the lowest's / 1.25 to the highest's x 1.25) instead of "
                             f"the test ISOs {TEST_ISOS}: e.g. 800 for a denoiser of one gain")
    parser.add_argument("--no-bm3d", action="store_true", help="leave out the BM3D and A-BM3D rows (they need `pip install bm3d`)")
    parser.add_argument("--train-one", nargs=2, metavar=("ROW", "SEED"), help=argparse.SUPPRESS)  # a child process
    parser.add_argument("--bm3d-only", action="store_true", help=argparse.SUPPRESS)  # a child process
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be >= 1, got {args.jobs}")
    if args.time_limit is not None and not args.time_limit > 0:
        parser.error(f"--time-limit must be > 0 seconds, got {args.time_limit}")
    scale = dict(SCALES[args.scale])
    scale_args = ["--scale", args.scale]
    if args.steps is not None:
        if args.steps < 1:
            parser.error(f"--steps must be >= 1, got {args.steps}")
        scale["steps"] = args.steps
        scale_args += ["--steps", str(args.steps)]
    if args.seeds is not None:
        scale["seeds"] = list(args.seeds)
        scale_args += ["--seeds", *map(str, args.seeds)]
    if args.train_isos is not None:
        if min(args.train_isos) <= 0:
            parser.error(f"--train-isos must be positive ISOs, got {args.train_isos}")
        scale["train_isos"] = list(args.train_isos)
        scale_args += ["--train-isos", *map(str, args.train_isos)]
    if args.no_bm3d:
        scale["bm3d"] = False
        scale_args += ["--no-bm3d"]
    if scale["bm3d"] and importlib.util.find_spec("bm3d") is None:  # said before hours of training, not after
        parser.error(f"the {args.scale} scale's BM3D rows need the bm3d package: pip install bm3d, or pass --no-bm3d")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.time()
    deadline = start + args.time_limit if args.time_limit else None
    torch.set_num_threads(max(1, torch.get_num_threads()))
    data = make_data(out, scale)
    print(f"[{time.time() - start:6.0f} s] TestCam frames and pairs in {out}")
    order = MODELS + ["loop", "paired real"]
    for row in args.rows or []:
        if row not in order:
            raise ValueError(f"unknown row {row!r}; rows: {order}")
    needed = [args.train_one[0]] if args.train_one else [] if args.bm3d_only else args.rows or order
    profiles = calibrate(out, data, with_loop="loop" in needed, n_synth=scale.get("n_synth", 12))
    if args.train_one:
        train_and_test(args.train_one[0], int(args.train_one[1]), out, data, profiles, scale)
        return 0
    if args.bm3d_only:
        bm3d_rows(out, data, profiles)
        return 0
    print(f"[{time.time() - start:6.0f} s] profiles: {profiles['eld']} (calibrate), {profiles['loop']} (loop)")
    finished = True
    if not args.collect and (args.jobs > 1 or deadline is not None):
        jobs = [(f"{row} seed {seed}", ["--train-one", row, str(seed)], run_dir_of(out, row, seed) / "train.log")
                for row in args.rows or order for seed in scale["seeds"] if not (run_dir_of(out, row, seed) / "test_results.csv").exists()]
        side = [("BM3D", ["--bm3d-only"], out / "bm3d.log")] if scale["bm3d"] and not (out / "bm3d_results.json").exists() else []
        cmd = [sys.executable, str(Path(__file__).resolve()), "--out", str(out), *scale_args]
        finished = run_children(cmd, jobs, args.jobs, deadline, start, side)
    rows = []
    for row in args.rows or order:
        for seed in scale["seeds"]:
            done = run_dir_of(out, row, seed) / "test_results.csv"
            if (args.collect or not finished) and not done.exists():
                continue
            rows += read_results(train_and_test(row, seed, out, data, profiles, scale), row, seed)
            print(f"[{time.time() - start:6.0f} s] {row} seed {seed}: " + ", ".join(f"x{r['ratio']} {r['psnr_db']:.2f} dB" for r in rows[-4:] if r["row"] == row and r["seed"] == seed))
    full_order = (["BM3D", "A-BM3D"] if scale["bm3d"] else []) + order
    if scale["bm3d"] and ((not args.collect and finished) or (out / "bm3d_results.json").exists()):
        rows += bm3d_rows(out, data, profiles)
        print(f"[{time.time() - start:6.0f} s] BM3D and A-BM3D done")
    md, table = summarize(rows, [r for r in full_order if any(x["row"] == r for x in rows)])
    split = json.loads((data["sid"] / "scenes.json").read_text())
    by_scene = ", ".join(f"{n} {split['test_tiles'].count(n)}" for n in dict.fromkeys(split["test_tiles"]))
    header = (f"# TestCam ablation ({args.scale} scale)\n\nTrue noise: SonyA7S2 ELD model (with its colour bias) + undeclared column noise and dark shading "
              f"(benchmarks/ablation/testcam.py). Scale: {json.dumps(scale)}. Wall time {time.time() - start:.0f} s.\n\n"
              f"Training scenes: {', '.join(split['train'])}. Test tiles ({len(split['test_tiles'])}, by held-out scene): {by_scene}.\n\n")
    write_text_atomic(out / "results.md", header + md)
    write_text_atomic(out / "results.csv", table)
    write_text_atomic(out / "results.json", json.dumps(rows, indent=1))
    plot(rows, [r for r in full_order if any(x["row"] == r for x in rows)], out / "results.png")
    print(header + md)
    return 0 if finished else UNFINISHED


if __name__ == "__main__":
    sys.exit(main())
