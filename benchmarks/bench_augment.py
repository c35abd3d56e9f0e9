"""Throughput of RawNoiseAugment (G*+P*+R+U) against the reference way of synthesizing.

The reference is how the published ELD/PMN code draws noise: one image at a time on the
CPU, NumPy Poisson and ``scipy.stats.tukeylambda.rvs``. Both run side by side in this
process on the same (B, 4, H, W) batch; the ratio is printed, never asserted.

    python benchmarks/bench_augment.py [--batch 8 --size 512 --repeats 3]

On a CUDA device it also prints the fraction of the memory-bandwidth bound reached
(reading clean + writing noisy, against a measured device-to-device copy of the same
bytes) and the cost relative to one U-Net training step.
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch
from scipy import stats

from rawaug import RawNoiseAugment

FIXED = {"k": 1.0, "sigma_tl": 2.0, "lambda": 0.05, "sigma_r": 0.5, "ratio": 200.0}


def reference_batch(clean: np.ndarray, span: float, rng: np.random.Generator) -> np.ndarray:
    """Per-image NumPy/SciPy synthesis of G*+P*+R+U, as the published code does it."""
    out = np.empty_like(clean)
    k, ratio = FIXED["k"], FIXED["ratio"]
    for i, img in enumerate(clean):
        dn = img * span / ratio
        noisy = rng.poisson(np.maximum(dn / k, 0)).astype(np.float32) * k
        noisy += stats.tukeylambda.rvs(FIXED["lambda"], scale=FIXED["sigma_tl"], size=dn.shape, random_state=rng).astype(np.float32)
        rows = rng.standard_normal((2, dn.shape[1], 1)).astype(np.float32) * FIXED["sigma_r"]
        noisy += rows[[0, 0, 1, 1]]
        noisy += rng.uniform(-0.5, 0.5, dn.shape).astype(np.float32)
        out[i] = noisy * ratio / span
    return out


def timed(fn, repeats, sync=lambda: None):
    fn()
    sync()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def cpu_comparison(batch, size, repeats, threads):
    torch.set_num_threads(threads)
    aug = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", fixed=FIXED, check_finite=False)
    clean = torch.rand(batch, 4, size, size) * 0.2
    megapixels = clean.numel() / 1e6
    t_rawaug = timed(lambda: aug(clean), repeats)
    rng = np.random.default_rng(0)
    clean_np = clean.numpy()
    t_ref = timed(lambda: reference_batch(clean_np, aug.profile.span_dn, rng), max(1, repeats // 2))
    print(f"CPU, {threads} thread(s), batch {tuple(clean.shape)} = {megapixels:.1f} MP")
    print(f"  reference (per image, NumPy Poisson + scipy tukeylambda.rvs): {megapixels / t_ref:8.2f} MP/s")
    print(f"  rawaug RawNoiseAugment G*+P*+R+U:                           {megapixels / t_rawaug:8.2f} MP/s")
    print(f"  ratio rawaug / reference: {t_ref / t_rawaug:.1f}x (target >= 5x)")
    return t_ref / t_rawaug


def gpu_report(batch, size, repeats):
    device = torch.device("cuda")
    sync = torch.cuda.synchronize
    aug = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", fixed=FIXED, check_finite=False)
    clean = torch.rand(batch, 4, size, size, device=device) * 0.2
    megapixels = clean.numel() / 1e6
    t_aug = timed(lambda: aug(clean), repeats * 5, sync)
    dst = torch.empty_like(clean)
    t_copy = timed(lambda: dst.copy_(clean), repeats * 5, sync)  # reads and writes the same bytes
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

    t_step = timed(step, repeats * 3, sync)
    print(f"  U-Net training step: {t_step * 1e3:.1f} ms -> augmentation is {t_aug / t_step:.1%} of it (target < 5%)")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    for threads in sorted({1, torch.get_num_threads()}):
        cpu_comparison(args.batch, args.size, args.repeats, threads)
    if torch.cuda.is_available():
        gpu_report(args.batch, args.size, args.repeats)
    else:
        print("GPU: no CUDA device here, GPU figures not measured")


if __name__ == "__main__":
    main()
