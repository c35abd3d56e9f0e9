"""The loop's denoising gain on real noise: test pairs whose read-side noise is a real dark frame.

    python benchmarks/real_noise/run.py --out runs/real_noise            # CPU, about 17 minutes
    python benchmarks/real_noise/run.py --out runs/real_noise --smoke    # seconds, for tests
    python benchmarks/real_noise/run.py --out runs/real_noise_gpu --scale gpu-short --jobs 9 --time-limit 540
        # the ablation's GPU recipe (32-wide direct U-Net, 3000 steps of 4 crops of 256, lr 3e-4):
        # trainings as 9 processes sharing the GPU, exit status 3 when cut: run it again to resume

The real dark frame (InfiniteISP BlackImage, 1920x1080, 12 bit, BGGR, Apache-2.0; whole in
../shared beside the checkout, else its 512x512 crop bundled with the tests) has effects
rawaug was never told about: clipping at code 0, a code comb, a dead row, a hot column,
banding. Its rows are split: the top 2/3 (training part) is all any noise model sees; the
bottom 1/3 (held-out part) makes the test pairs (a split by rows keeps column effects, such
as the hot last column, in both parts, as they are on one sensor):

    noisy DN = Poisson(clean * span / ratio / K) * K + a crop of the held-out part (DN)

at K = 1 DN/e- (the frame has no flats, so K is chosen), ratios x50 / x100 / x200, on tiles
of three held-out real scenes (benchmarks/scenes.py). The same U-Net is trained on the other
three bundled real scenes and the four bundled photos, unprocessed, with (a) the ELD model
calibrated on the training part (stage 1: Tukey-lambda read noise, row noise, colour bias)
as the paper trains it (G*+P*+R+U: without the colour bias),
(a') the same with its colour bias (G*+P*+R+U+C), (b) the closed loop's profile of the
training part with everything it calibrated (its effects and its fitted colour bias), (c)
noise sampled directly from the training part (random crops added to shot noise, the way
sampling-based methods make pairs: an upper bound for a model of this frame) and (c') values
drawn independently from the training part's pixels (its distribution without its spatial
structure). A further row, (b') the loop's profile without its measured code map, is run
only when the loop added ``CodeMap``: shot noise is added on top of the dark frame's codes,
so in these pairs the comb and the clip at code 0 act on the read-side noise only, while
the loop's ``CodeMap`` and ``Clip`` act at the ADC, after the shot noise, as a sensor does.
Every row has the same steps, seeds and recipe (the quickstart's, with the gradient norm
clipped at 1).
Each run's result is written when it exists and reused by the next invocation.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from rawaug import NoiseProfile
from rawaug.atomic import write_text_atomic
from rawaug.calibration.stage1 import estimate_color_bias, estimate_read_noise, estimate_row_noise, read_residual
from rawaug.io import read_frame
from rawaug.loop import FrameStack, run_frame_loop
from rawaug.train.metrics import evaluate

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import scenes  # noqa: E402
from children import UNFINISHED, run_children  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
DARK = ROOT.parent / "shared/data/frames/InfiniteISP/BlackImage_1920x1080_12bits_BGGR.raw"
DARK_CROP = ROOT / "tests/data/InfiniteISP_BlackImage_crop512_y0_x1408_12bits_BGGR.raw"
K = 1.0  # DN/e-
RATIOS = (50, 100, 200)
WHITE = 4095
ROWS = ("ELD", "ELD with colour bias", "loop", "loop without CodeMap", "sampled real", "sampled real, shuffled")
# noise model per row; the sampled rows use none
MODELS = {"ELD": "G*+P*+R+U", "ELD with colour bias": "G*+P*+R+U+C", "loop": "G*+P*+R+U+C", "loop without CodeMap": "G*+P*+R+U+C"}
GRADIENT_CLIP = 1.0  # max gradient norm
SCALES = {"cpu": dict(steps=1024, seeds=(0, 1, 2), base=16, crop=64, batch=8, tile=128, test_tiles=12, n_synth=8),
          "smoke": dict(steps=2, seeds=(0,), base=4, crop=32, batch=2, tile=32, test_tiles=2, n_synth=8),
          # the ablation's gpu-short recipe; crops of 256 need the whole frame's training part (360 packed rows)
          "gpu-short": dict(steps=3000, seeds=(0, 1, 2), base=32, crop=256, batch=4, tile=128, test_tiles=24, n_synth=8,
                            lr=3e-4, residual=False, accelerator="auto")}


def read_dark(path: Path) -> np.ndarray:
    """Packed (4, h, w) DN of the dark frame (black level 0: its codes are what it holds)."""
    width, height = (512, 512) if "crop512" in path.name else (1920, 1080)
    frame = read_frame(path, width=width, height=height, dtype="<u2", cfa="BGGR", black_level=0, white_level=WHITE)
    return frame.packed_dn().astype(np.float32)


def eld_profile(train: np.ndarray) -> NoiseProfile:
    """The ELD model of the training part at K: stage-1 read (Tukey lambda) and row noise,
    the channel offsets as colour bias; slope-0 relations (one gain)."""
    row = estimate_row_noise(train.astype(np.float64))
    read = estimate_read_noise(read_residual(train.astype(np.float64), row.row_means))
    data = NoiseProfile.load("SonyA7S2").to_dict()
    flat = lambda sigma: {"slope": 0.0, "intercept": float(np.log(sigma)), "residual_std": 0.0}  # noqa: E731
    data.update(camera="InfiniteISP dark frame (training part)",
                source="benchmarks/real_noise/run.py: stage 1 on the training part of the real dark frame, K chosen")
    data["sensor"].update(black_level=0.0, white_level=float(WHITE), bit_depth=12, cfa="BGGR")
    data["system_gain"] = {"k_min": K, "k_max": K, "iso": [100.0], "k": [K]}
    data["read_noise"] = {"tukey_scale": flat(read.sigma_tl), "gaussian_scale": flat(read.sigma_g),
                          "tukey_shape": {"k": [K], "lambda": [float(read.lam)]}}
    data["row_noise"] = {"scale": flat(max(row.sigma_r, 1e-3))}
    data["color_bias"] = {"k": [K], "dn": [estimate_color_bias(train).tolist()]}
    data["effects"] = {}
    return NoiseProfile.from_dict(data), {"sigma_tl": read.sigma_tl, "lambda": read.lam, "sigma_g": read.sigma_g,
                                          "sigma_r": row.sigma_r}


def write_train_scenes(folder: Path, crop: int) -> None:
    """The training scenes (benchmarks/scenes.py) as normalized mosaics ``folder/<name>.npz``
    (RGGB, black 0, white 1) for ``CleanFolder``."""
    from rawaug.bayer import unpack

    for name, packed in scenes.train_scenes(min_size=crop, piece=max(crop, 256)):
        path = folder / f"{name}.npz"
        if not path.exists():
            folder.mkdir(parents=True, exist_ok=True)
            tmp = folder.parent / f".{folder.name}-{name}.tmp.npz"  # outside the folder CleanFolder reads
            np.savez(tmp, mosaic=unpack(packed, "RGGB").astype(np.float32), black_level=0.0, white_level=1.0, cfa="RGGB")
            tmp.replace(path)


def test_pairs(held_out: np.ndarray, scale: dict):
    """[(ratio, noisy normalized x ratio, clean, (row, col) of the dark crop)] of scene tiles
    with real held-out noise."""
    tiles = [t for _, t in scenes.test_tiles(scale["tile"], scale["test_tiles"])]
    rng = np.random.default_rng(12345)
    pairs = []
    for ratio in RATIOS:
        for clean in tiles:
            _, h, w = clean.shape
            i, j = rng.integers(0, held_out.shape[1] - h + 1), rng.integers(0, held_out.shape[2] - w + 1)
            shot = rng.poisson(clean * WHITE / ratio / K) * K
            noisy = (shot + held_out[:, i : i + h, j : j + w]) / WHITE * ratio
            pairs.append((ratio, noisy.astype(np.float32), clean.astype(np.float32), (int(i), int(j))))
    return pairs


class SampledRealNoise(torch.nn.Module):
    """Shot noise at K plus a random crop of real dark frames (DN): a sampling-based noise
    source with RawNoiseAugment's call (clean normalized in, noisy x ratio out)."""

    def __init__(self, dark_dn: np.ndarray, k: float, ratio: tuple, white: float):
        super().__init__()
        self.register_buffer("dark", torch.as_tensor(dark_dn, dtype=torch.float32))
        self.k, self.ratio, self.white = float(k), tuple(float(r) for r in ratio), float(white)

    def forward(self, clean):
        b, _, h, w = clean.shape
        lo, hi = np.log(self.ratio[0]), np.log(self.ratio[1])
        ratio = torch.exp(lo + (hi - lo) * torch.rand(b, 1, 1, 1, device=clean.device))
        shot = torch.poisson(clean * self.white / ratio / self.k) * self.k
        i = torch.randint(0, self.dark.shape[1] - h + 1, (b,)).tolist()
        j = torch.randint(0, self.dark.shape[2] - w + 1, (b,)).tolist()
        crops = torch.stack([self.dark[:, y : y + h, x : x + w] for y, x in zip(i, j)])
        return (shot + crops) / self.white * ratio


class SampledRealDistribution(SampledRealNoise):
    """Shot noise at K plus values drawn independently, per channel, from the pixels of real
    dark frames: their distribution without their spatial structure (rows, columns, defects,
    shading). Set beside ``SampledRealNoise``, it tells how much of the real noise is its
    distribution."""

    def forward(self, clean):
        b, _, h, w = clean.shape
        lo, hi = np.log(self.ratio[0]), np.log(self.ratio[1])
        ratio = torch.exp(lo + (hi - lo) * torch.rand(b, 1, 1, 1, device=clean.device))
        shot = torch.poisson(clean * self.white / ratio / self.k) * self.k
        flat = self.dark.reshape(4, -1)
        idx = torch.randint(0, flat.shape[1], (b, 4, h * w), device=clean.device)
        values = torch.gather(flat[None].expand(b, -1, -1), 2, idx).reshape(b, 4, h, w)
        return (shot + values) / self.white * ratio


def run_name(row: str, seed: int) -> str:
    return f"{row.replace(',', '').replace(' ', '_')}_seed{seed}"


def train_and_test(row: str, seed: int, out: Path, profiles: dict, train_dark: np.ndarray, pairs, scale) -> dict:
    result = out / "runs" / f"{run_name(row, seed)}.json"
    if result.exists():
        return json.loads(result.read_text())
    import lightning as L

    from rawaug.train import CleanFolder, DenoiseModule, RawDenoiseData

    torch.manual_seed(seed)
    module = DenoiseModule(base_channels=scale["base"], depth=5, residual=scale.get("residual", True), profile=str(profiles[row if row in profiles else "ELD"]),
                           noise_model=MODELS.get(row, "G*+P*+R+U"), include_profile_effects=row.startswith("loop"), ratio=[RATIOS[0], RATIOS[-1]], k=K,
                           crop_size=scale["crop"], lr=scale.get("lr", 1e-3), seed=seed, image_log_size=0, eval_iso=None, eval_k=K)
    if row.startswith("sampled real"):
        source = SampledRealDistribution if row == "sampled real, shuffled" else SampledRealNoise
        module.noise = source(train_dark, K, (RATIOS[0], RATIOS[-1]), WHITE)
    data = RawDenoiseData(train=CleanFolder(str(out / "train_scenes"), camera="bundled-scenes", repeat=64, window=scale["crop"]), batch_size=scale["batch"], seed=seed)
    # gradient clipping: without it a loss spike early at lr 1e-3 (the loop row, seed 0: L1 0.03 -> 0.57
    # near step 100) left a run 7 dB below its other seed
    trainer = L.Trainer(max_steps=scale["steps"], accelerator=scale.get("accelerator", "cpu"), devices=1, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0, default_root_dir=str(out / "runs"),
                        gradient_clip_val=GRADIENT_CLIP)
    start = time.time()
    trainer.fit(module, datamodule=data)
    module = module.cpu().eval()  # tested on the CPU, as the pairs are
    scores = {q: [] for q in RATIOS}
    noisy_scores = {q: [] for q in RATIOS}
    with torch.no_grad():
        for ratio, noisy, clean, _ in pairs:
            x = torch.from_numpy(noisy)[None].clamp(0, 1)
            y = torch.from_numpy(clean)[None]
            m = evaluate(module(x), y)
            scores[ratio].append((float(m["psnr"]), float(m["ssim"])))
            n = evaluate(x, y)
            noisy_scores[ratio].append((float(n["psnr"]), float(n["ssim"])))
    res = {"row": row, "seed": seed, "train_s": round(time.time() - start, 1),
           "psnr": {q: float(np.mean([s[0] for s in v])) for q, v in scores.items()},
           "ssim": {q: float(np.mean([s[1] for s in v])) for q, v in scores.items()},
           "noisy_psnr": {q: float(np.mean([s[0] for s in v])) for q, v in noisy_scores.items()}}
    result.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(result, json.dumps(res))
    return res


def table(results: list[dict]) -> str:
    md = ["| training noise | seeds | " + " | ".join(f"x{q} PSNR (dB) / SSIM" for q in RATIOS) + " |", "|---|---|" + "---|" * len(RATIOS)]
    for row in ROWS:
        rs = [r for r in results if r["row"] == row]
        if not rs:
            continue
        cells = []
        for q in RATIOS:
            p = np.array([r["psnr"][str(q)] if str(q) in r["psnr"] else r["psnr"][q] for r in rs])
            s = np.array([r["ssim"][str(q)] if str(q) in r["ssim"] else r["ssim"][q] for r in rs])
            cells.append(f"{p.mean():.2f} ±{(p.max() - p.min()) / 2:.2f} / {s.mean():.3f}")
        md.append(f"| {row} | {len(rs)} | " + " | ".join(cells) + " |")
    r0 = results[0]
    md.append("| noisy input | - | " + " | ".join(f"{r0['noisy_psnr'][str(q)] if str(q) in r0['noisy_psnr'] else r0['noisy_psnr'][q]:.2f} / -"
                                                 for q in RATIOS) + " |")
    md += ["", "± is half the seed-to-seed range."]
    return "\n".join(md) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/real_noise", help="output folder (reused: finished runs are skipped)")
    ap.add_argument("--dark", default=str(DARK), help="the whole dark frame (default: beside the checkout)")
    ap.add_argument("--scale", choices=sorted(SCALES), default="cpu")
    ap.add_argument("--smoke", action="store_true", help="tiny scale, seconds (for tests): --scale smoke")
    ap.add_argument("--rows", nargs="*", default=list(ROWS), choices=ROWS)
    ap.add_argument("--seeds", type=int, nargs="*", default=None, help="training seeds (default: the scale's)")
    ap.add_argument("--jobs", type=int, default=1, help="trainings at once, as child processes sharing the device")
    ap.add_argument("--time-limit", type=float, default=None, metavar="SECONDS",
                    help=f"stop this invocation after SECONDS (finished runs are kept; exit status {UNFINISHED}); run again to resume")
    ap.add_argument("--train-one", nargs=2, metavar=("ROW", "SEED"), help=argparse.SUPPRESS)  # a child process
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs must be >= 1, got {args.jobs}")
    if args.time_limit is not None and not args.time_limit > 0:
        ap.error(f"--time-limit must be > 0 seconds, got {args.time_limit}")
    scale_name = "smoke" if args.smoke else args.scale
    scale = dict(SCALES[scale_name])
    if args.seeds:
        scale["seeds"] = tuple(args.seeds)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.time()
    path = Path(args.dark) if Path(args.dark).is_file() else DARK_CROP
    dark = read_dark(path)
    cut = dark.shape[1] * 2 // 3
    train_dark, held_out = dark[:, :cut], dark[:, cut:]
    print(f"dark frame {path.name}: packed {dark.shape}; training part {train_dark.shape}, held-out part {held_out.shape}")
    if min(train_dark.shape[1:]) < scale["crop"] or min(held_out.shape[1:]) < scale["tile"]:
        ap.error(f"the {scale_name} scale's crops of {scale['crop']} and tiles of {scale['tile']} need a larger dark frame than "
                 f"{path} (training part {train_dark.shape[1:]}, held-out part {held_out.shape[1:]}): pass the whole frame with --dark")
    eld, base = eld_profile(train_dark)
    profiles = {"ELD": out / "eld_profile.yaml", "loop": out / "loop_profile.yaml"}
    if not profiles["ELD"].exists():
        eld.save(profiles["ELD"])
    if any(r.startswith("loop") for r in args.rows) and not profiles["loop"].exists():
        stack = FrameStack(train_dark[None].astype(np.float64), K, label="training part", base=base)
        loop = run_frame_loop([stack], eld, n_synth=scale["n_synth"], seed=0, log=print)
        loop.profile.save(profiles["loop"])
        write_text_atomic(out / "loop_steps.json", json.dumps([s.to_dict() for s in loop.steps], default=str))
        print(f"[{time.time() - start:5.0f} s] loop added {loop.added}")
    profiles["loop without CodeMap"] = out / "loop_profile_without_codemap.yaml"
    if profiles["loop"].exists() and not profiles["loop without CodeMap"].exists():
        data = NoiseProfile.load(profiles["loop"]).to_dict()
        data["effects"].pop("CodeMap", None)
        NoiseProfile.from_dict(data).save(profiles["loop without CodeMap"])
    rows = [r for r in args.rows if r != "loop without CodeMap" or "CodeMap" in NoiseProfile.load(profiles["loop"]).effects]
    pairs = test_pairs(held_out, scale)
    write_train_scenes(out / "train_scenes", scale["crop"])
    if args.train_one:
        train_and_test(args.train_one[0], int(args.train_one[1]), out, profiles, train_dark, pairs, scale)
        return 0
    finished = True
    if args.jobs > 1 or args.time_limit:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--out", str(out), "--dark", str(path), "--scale", scale_name,
               "--seeds", *map(str, scale["seeds"])]
        jobs = [(f"{row} seed {seed}", ["--train-one", row, str(seed)], out / "runs" / f"{run_name(row, seed)}.log")
                for row in rows for seed in scale["seeds"] if not (out / "runs" / f"{run_name(row, seed)}.json").exists()]
        finished = run_children(cmd, jobs, args.jobs, start + args.time_limit if args.time_limit else None, start)
    header = (f"# Real-noise test pairs ({path.name}, held-out bottom third; K = {K:g} DN/e-)\n\n"
              f"{len(pairs) // len(RATIOS)} test tiles per ratio of {', '.join(scenes.TEST_RAW)}; training scenes "
              f"{', '.join(p.stem for p in sorted((out / 'train_scenes').glob('*.npz')))}; scale {json.dumps({k: v for k, v in scale.items() if k != 'seeds'})}; "
              "every finished seed in the folder counts.\n\n")
    md = header + "No run of these rows and seeds has finished.\n"
    for row in rows:
        for seed in scale["seeds"]:
            if not finished and not (out / "runs" / f"{run_name(row, seed)}.json").exists():
                continue
            res = train_and_test(row, seed, out, profiles, train_dark, pairs, scale)
            print(f"[{time.time() - start:5.0f} s] {row} seed {seed}: "
                  + ", ".join(f"x{q} {v:.2f} dB" for q, v in res["psnr"].items()))
            # every finished run in the folder, this invocation's and earlier ones'
            results = sorted((json.loads(p.read_text()) for p in (out / "runs").glob("*_seed*.json")),
                             key=lambda r: (ROWS.index(r["row"]), r["seed"]))
            md = header + table(results)
            write_text_atomic(out / "results.md", md)
            write_text_atomic(out / "results.json", json.dumps(results, indent=1))
    print(md)
    print(f"(elapsed {time.time() - start:.0f} s)")
    return 0 if finished else UNFINISHED


if __name__ == "__main__":
    sys.exit(main())
