"""Throughput of RawNoiseAugment (G*+P*+R+U) against the reference way of synthesizing.

The reference is how the published ELD/PMN code draws noise: one image at a time on the
CPU, NumPy Poisson and ``scipy.stats.tukeylambda.rvs``. Both synthesize the same model with
the same per-sample parameters (those rawaug drew), side by side in this process, timed
alternately; the ratio is printed, never asserted. Two clean batches (8, 4, 512, 512):

* ``flat``: uniform [0, 0.2] at K = 1, ratio 200 (0 to 16 electrons), fixed parameters;
* ``scenes``: the bundled real scenes, parameters drawn from the SonyA7S2 profile
  (K over its whole range, ratio 100-300).

``rawaug (torch samplers)`` is the same module with ``RAWAUG_CPU_KERNELS=0``: the path
every non-CPU device takes, here on the CPU.

    python benchmarks/bench_augment.py [--repeats 5]

On a CUDA device it also prints the fraction of the memory-bandwidth bound reached
(reading clean + writing noisy, against a measured device-to-device copy of the same
bytes) and the cost relative to one U-Net training step.
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch
from scipy import stats

from rawaug import RawNoiseAugment, cpu
from rawaug.bayer import pack
from rawaug.io import read_frame

FIXED = {"k": 1.0, "sigma_tl": 2.0, "lambda": 0.05, "sigma_r": 0.5, "ratio": 200.0}
SCENES = Path(__file__).resolve().parents[1] / "rawaug" / "data" / "scenes"


def reference_batch(clean: np.ndarray, span: float, params: dict, rng: np.random.Generator) -> np.ndarray:
    """Per-image NumPy/SciPy synthesis of G*+P*+R+U, as the published code does it."""
    p = {key: value.numpy() for key, value in params.items() if key != "seed"}
    out = np.empty_like(clean)
    for i, img in enumerate(clean):
        k, ratio = p["k"][i], p["ratio"][i]
        dn = img * span / ratio
        noisy = rng.poisson(np.maximum(dn / k, 0)).astype(np.float32) * k
        tl = stats.tukeylambda.rvs(p["read_noise.lambda"][i], scale=p["read_noise.sigma_tl"][i], size=dn.shape, random_state=rng)
        noisy += tl.astype(np.float32)
        rows = rng.standard_normal((2, dn.shape[1], 1)).astype(np.float32) * p["row_noise.sigma_r"][i]
        noisy += rows[[0, 0, 1, 1]]
        step = p["quantization.step_dn"][i]
        noisy += rng.uniform(-0.5 * step, 0.5 * step, dn.shape).astype(np.float32)
        out[i] = noisy * ratio / span
    return out


def scene_batch(batch: int, size: int) -> torch.Tensor:
    """(batch, 4, size, size) packed crops of the bundled 1024x1024 real scenes (and their
    mirror images, to fill the batch), normalized."""
    crops = []
    for path in sorted(SCENES.glob("*_1024x1024.npz")):
        frame = read_frame(path)
        packed = pack(frame.mosaic.astype(np.float32), frame.cfa)[:, :size, :size]
        crops.append((packed - frame.black_level) / (frame.white_level - frame.black_level))
    crops += [c[:, :, ::-1] for c in crops]
    return torch.from_numpy(np.ascontiguousarray(np.stack(crops[:batch]))).clamp_(0, 1)


def alternate(fns: dict, repeats: int) -> dict:
    """Median seconds of each function, run in turn so slow drifts hit all alike."""
    for fn in fns.values():
        fn()
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


def torch_samplers(fn):
    def run():
        previous = cpu.use_cpu_kernels(False)
        try:
            return fn()
        finally:
            cpu.use_cpu_kernels(previous)
    return run


def cpu_comparison(name, clean, aug, threads, repeats):
    torch.set_num_threads(threads)
    aug(clean)
    params = dict(aug._params)
    megapixels = clean.numel() / 1e6
    rng = np.random.default_rng(0)
    clean_np = clean.numpy()
    t = alternate({
        "reference": lambda: reference_batch(clean_np, aug.profile.span_dn, params, rng),
        "kernels": lambda: aug(clean, params=params),
        "torch": torch_samplers(lambda: aug(clean, params=params)),
    }, repeats)
    print(f"CPU, {threads} thread(s), {name} batch {tuple(clean.shape)} = {megapixels:.1f} MP")
    print(f"  reference (per image, NumPy Poisson + scipy tukeylambda.rvs): {megapixels / t['reference']:8.2f} MP/s")
    print(f"  rawaug (torch samplers):                                     {megapixels / t['torch']:8.2f} MP/s"
          f"  ratio {t['reference'] / t['torch']:.1f}x")
    print(f"  rawaug RawNoiseAugment G*+P*+R+U:                            {megapixels / t['kernels']:8.2f} MP/s"
          f"  ratio {t['reference'] / t['kernels']:.1f}x (target >= 5x)")
    return t["reference"] / t["kernels"]


def gpu_report(batch, size, repeats):
    device = torch.device("cuda")
    sync = torch.cuda.synchronize
    aug = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", fixed=FIXED, check_finite=False)
    clean = torch.rand(batch, 4, size, size, device=device) * 0.2
    megapixels = clean.numel() / 1e6

    def timed(fn, n):
        fn()
        sync()
        start = time.perf_counter()
        for _ in range(n):
            fn()
        sync()
        return (time.perf_counter() - start) / n

    t_aug = timed(lambda: aug(clean), repeats * 5)
    dst = torch.empty_like(clean)
    t_copy = timed(lambda: dst.copy_(clean), repeats * 5)  # reads and writes the same bytes
    print(f"GPU {torch.cuda.get_device_name()}, batch {tuple(clean.shape)}")
    print(f"  rawaug: {megapixels / t_aug:10.1f} MP/s ({t_aug * 1e3:.2f} ms)")
    print(f"  copy of the same bytes: {t_copy * 1e3:.3f} ms -> fraction of bandwidth bound: {t_copy / t_aug:.1%} (target >= 30%)")
    try:
        from rawaug.train.unet import UNet
    except ImportError:
        print("  U-Net step: rawaug.train not installed, skipped")
        return
    net = UNet().to(device)
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    noisy = aug(clean)

    def step():
        opt.zero_grad(set_to_none=True)
        loss = (net(noisy) - clean).abs().mean()
        loss.backward()
        opt.step()

    t_step = timed(step, repeats * 3)
    print(f"  U-Net training step: {t_step * 1e3:.1f} ms -> augmentation is {t_aug / t_step:.1%} of it (target < 5%)")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    flat = torch.rand(args.batch, 4, args.size, args.size, generator=torch.Generator().manual_seed(0)) * 0.2
    workloads = {
        "flat": (flat, RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", fixed=FIXED, check_finite=False)),
        "scenes": (scene_batch(args.batch, args.size),
                   RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", check_finite=False, generator=torch.Generator().manual_seed(0))),
    }
    for threads in sorted({1, torch.get_num_threads()}):
        for name, (clean, aug) in workloads.items():
            cpu_comparison(name, clean, aug, threads, args.repeats)
    if torch.cuda.is_available():
        gpu_report(args.batch, args.size, args.repeats)
    else:
        print("GPU: no CUDA device here, GPU figures not measured")


if __name__ == "__main__":
    main()
