"""Throughput of RawNoiseAugment (G*+P*+R+U, the fused kernel) against two references.

* the per-image reference: how the published ELD/PMN code draws noise, one image at a time
  on the CPU, NumPy Poisson and ``scipy.stats.tukeylambda.rvs``;
* the torch-ops path: the same chain as separate torch operations (``torch.poisson``, the
  Tukey inverse CDF as elementwise ops, ``torch.randn`` rows, ``torch.rand``), which is what
  rawaug ran on every device before the fused kernel.

All synthesize the same model with the same per-sample parameters (those rawaug drew),
side by side in this process, timed alternately; ratios are printed, never asserted. Two
clean batches (8, 4, 512, 512):

* ``flat``: uniform [0, 0.2] at K = 1, ratio 200 (0 to 16 electrons), fixed parameters;
* ``scenes``: the bundled real scenes, parameters drawn from the SonyA7S2 profile
  (K over its whole range, ratio 100-300).

    python benchmarks/bench_augment.py [--repeats 5] [--threads 1] [--profile LOOP_PROFILE.yaml]
    python benchmarks/bench_augment.py --gpu-only [--profile LOOP_PROFILE.yaml]   # CUDA figures only

It first prints the host time of one call's parameter draws (what a GPU call does on the CPU
before its kernel), with the counters in numpy against the same counters as torch
operations. On a CUDA device it also prints, for the fused kernel (fixed and drawn parameters, and a
loop profile with its effects if given) and the torch-ops path: the fraction of the
memory-bandwidth bound (a device copy of the same bytes over the augmentation's time) at
(8, 4, 512, 512) and (32, 4, 512, 512), with the kernel alone beside each call; the share
of one SID U-Net training step (32 wide, Adam) at (1, 4, 512, 512) in fp32 and bf16
autocast and at (8, 4, 256, 256) and (8, 4, 512, 512); kernel launches per call (torch
profiler) and host synchronizations per call.
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch
from scipy import stats

from rawaug import RawNoiseAugment
from rawaug.bayer import pack
from rawaug.distributions import tukey_lambda_icdf
from rawaug.engine.backend import synthesize_op
from rawaug.engine.transfer import to_device
from rawaug.io import read_frame

FIXED = {"k": 1.0, "sigma_tl": 2.0, "lambda": 0.05, "sigma_r": 0.5, "ratio": 200.0}
SCENES = Path(__file__).resolve().parents[1] / "rawaug" / "data" / "scenes"


def reference_batch(clean: np.ndarray, span: float, p: dict, rng: np.random.Generator) -> np.ndarray:
    """Per-image NumPy/SciPy synthesis of G*+P*+R+U, as the published code does it."""
    out = np.empty_like(clean)
    for i, img in enumerate(clean):
        k, ratio = p["k"][i], p["ratio"][i]
        dn = img * span / ratio
        noisy = rng.poisson(np.maximum(dn / k, 0)).astype(np.float32) * k
        tl = stats.tukeylambda.rvs(p["lambda"][i], scale=p["sigma_tl"][i], size=dn.shape, random_state=rng)
        noisy += tl.astype(np.float32)
        rows = rng.standard_normal((2, dn.shape[1], 1)).astype(np.float32) * p["sigma_r"][i]
        noisy += rows[[0, 0, 1, 1]]
        step = p["step_dn"][i]
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


def torch_ops(clean: torch.Tensor, span: float, p: dict, generator: torch.Generator | None = None) -> torch.Tensor:
    """G*+P*+R+U as separate torch operations on clean's device (the pre-fused path)."""
    col = lambda name: p[name].to(clean.device, torch.float32).view(-1, 1, 1, 1)  # noqa: E731
    k, ratio = col("k"), col("ratio")
    dn = clean * (span / ratio)
    noisy = torch.poisson(torch.clamp(dn / k, min=0.0), generator=generator) * k
    u = torch.rand(clean.shape, device=clean.device, generator=generator)
    noisy += tukey_lambda_icdf(u, col("lambda")) * col("sigma_tl")
    rows = torch.randn((clean.shape[0], 2, clean.shape[2], 1), device=clean.device, generator=generator) * col("sigma_r")
    noisy += rows[:, (0, 0, 1, 1)]
    noisy += (torch.rand(clean.shape, device=clean.device, generator=generator) - 0.5) * col("step_dn")
    return noisy * (ratio / span)


def cpu_comparison(name, clean, aug, threads, repeats):
    torch.set_num_threads(threads)
    aug(clean)
    params = dict(aug._params)
    named = {key: value.cpu() for key, value in aug.sample_parameters(params).items()}
    megapixels = clean.numel() / 1e6
    rng = np.random.default_rng(0)
    clean_np = clean.numpy()
    span = aug.profile.span_dn
    t = alternate({
        "reference": lambda: reference_batch(clean_np, span, {key: v.numpy() for key, v in named.items()}, rng),
        "fused": lambda: aug(clean, params=params),
        "torch": lambda: torch_ops(clean, span, named),
    }, repeats)
    print(f"CPU, {threads} thread(s), {name} batch {tuple(clean.shape)} = {megapixels:.1f} MP")
    print(f"  reference (per image, NumPy Poisson + scipy tukeylambda.rvs): {megapixels / t['reference']:8.2f} MP/s")
    print(f"  torch-ops path (torch.poisson, elementwise Tukey, randn, rand): {megapixels / t['torch']:8.2f} MP/s"
          f"  ratio {t['reference'] / t['torch']:.1f}x")
    print(f"  rawaug fused kernel G*+P*+R+U:                                 {megapixels / t['fused']:8.2f} MP/s"
          f"  ratio {t['reference'] / t['fused']:.1f}x (target >= 10x per thread)")
    return t["reference"] / t["fused"]


def cpu_profile_cost(clean, profile_path, threads, repeats):
    """The fused kernel on the CPU with a profile's effects against the base model's, the same
    clean batch and fixed base parameters, timed alternately."""
    torch.set_num_threads(threads)
    base = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", fixed=FIXED)
    loop = RawNoiseAugment(profile_path, model="G*+P*+R+U", fixed=FIXED)
    t = alternate({"base": lambda: base(clean), "loop": lambda: loop(clean)}, repeats)
    megapixels = clean.numel() / 1e6
    print(f"CPU, {threads} thread(s), flat batch {tuple(clean.shape)}: G*+P*+R+U {megapixels / t['base']:.2f} MP/s, "
          f"with {sorted(loop.profile.effects)} {megapixels / t['loop']:.2f} MP/s: {t['loop'] / t['base']:.2f}x the time")


def draw_comparison(repeats):
    """Host time of one call's parameter draws (the part of a GPU call before its kernel):
    counters in numpy (rawaug) against the same counters as torch operations (its previous
    draws), the same values, timed alternately."""
    import contextlib

    import rawaug.augment as A
    import rawaug.effects.base as E
    from rawaug.rng import torch_normal, torch_unit

    @contextlib.contextmanager
    def torch_counters():
        saved = E.host_unit, E.host_normal, A.host_unit
        E.host_unit = A.host_unit = lambda key, n: torch_unit(key, torch.arange(n))
        E.host_normal = lambda key, n: torch_normal(key, torch.arange(n))
        try:
            yield
        finally:
            E.host_unit, E.host_normal, A.host_unit = saved

    def per_call(aug, batch, n=200):
        start = time.perf_counter()
        for _ in range(n):
            aug.draw_parameters(batch, "cpu", shape=(512, 512))
        return (time.perf_counter() - start) / n

    for name, aug in (("G*+P*+R+U", RawNoiseAugment("SonyA7S2", model="G*+P*+R+U")),):
        for batch in (1, 8, 32):
            fast, slow = [], []
            for _ in range(repeats):
                fast.append(per_call(aug, batch))
                with torch_counters():
                    slow.append(per_call(aug, batch))
            f, s = statistics.median(fast), statistics.median(slow)
            print(f"parameter draws, {name}, batch {batch}: numpy counters {f * 1e6:.0f} us, torch counters {s * 1e6:.0f} us "
                  f"per call (ratio {s / f:.1f}x)")


def _cuda_timed(fn, n):
    fn()
    torch.cuda.synchronize()
    start = time.perf_counter()
    for _ in range(n):
        fn()
    torch.cuda.synchronize()
    return (time.perf_counter() - start) / n


def _launches(fn) -> int:
    from torch.profiler import ProfilerActivity, profile

    fn()
    torch.cuda.synchronize()
    with profile(activities=[ProfilerActivity.CUDA]) as prof:
        fn()
        torch.cuda.synchronize()
    return sum(1 for e in prof.events() if e.device_type == torch.autograd.DeviceType.CUDA)


def _syncs(fn) -> int:
    import warnings

    torch.cuda.set_sync_debug_mode("warn")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            fn()
    finally:
        torch.cuda.set_sync_debug_mode(0)
    return sum("synchroniz" in str(w.message) for w in caught)


def gpu_report(repeats, profile_path=None):
    device = torch.device("cuda")
    augs = {"G*+P*+R+U, fixed": RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", fixed=FIXED),
            "G*+P*+R+U, drawn": RawNoiseAugment("SonyA7S2", model="G*+P*+R+U")}
    if profile_path is not None:  # a loop profile: its effects in the same pass
        augs[f"{Path(profile_path).stem} (+ its effects), drawn"] = RawNoiseAugment(profile_path, model="G*+P*+R+U")
    print(f"GPU {torch.cuda.get_device_name()}, torch {torch.__version__}")
    for batch in (8, 32):
        clean = torch.rand(batch, 4, 512, 512, device=device) * 0.2
        dst = torch.empty_like(clean)
        t_copy = _cuda_timed(lambda: dst.copy_(clean), repeats * 10)
        print(f"  batch {tuple(clean.shape)}: device copy of the same bytes {t_copy * 1e3:.3f} ms")
        for name, aug in augs.items():
            aug(clean)
            t = _cuda_timed(lambda: aug(clean), repeats * 10)
            print(f"    {name}: {t * 1e3:.3f} ms = {t_copy / t:.1%} of the bandwidth bound (target >= 30% at batch 32)")
            values, keys = to_device((aug._params["values"], aug._stream_keys(int(aug._params["seed"]))), device)
            tables = aug._tables_on(device)
            t_kernel = _cuda_timed(lambda: synthesize_op(clean, values, keys, float(aug.profile.span_dn), aug._flags, *tables), repeats * 10)
            print(f"      the kernel alone (parameters on the device): {t_kernel * 1e3:.3f} ms = {t_copy / t_kernel:.1%}; "
                  f"the call's host work (draws, keys, copy) {max(t - t_kernel, 0) * 1e3:.3f} ms")
        aug = augs["G*+P*+R+U, fixed"]
        named = aug.sample_parameters(dict(aug._params))
        t_ops = _cuda_timed(lambda: torch_ops(clean, aug.profile.span_dn, named), repeats * 10)
        print(f"    torch-ops path, fixed: {t_ops * 1e3:.3f} ms = {t_copy / t_ops:.1%}")
    clean = torch.rand(8, 4, 512, 512, device=device) * 0.2
    for name, aug in augs.items():
        print(f"  {name}: kernel launches per call {_launches(lambda: aug(clean))} (target <= 3), "
              f"host synchronizations per call {_syncs(lambda: aug(clean))} (target 0)")
    try:
        from rawaug.train.unet import UNet
    except ImportError:
        print("  U-Net step: rawaug.train not installed, skipped")
        return
    net = UNet().to(device)
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    aug = augs["G*+P*+R+U, drawn"]
    for shape, dtype in (((1, 4, 512, 512), None), ((1, 4, 512, 512), torch.bfloat16), ((8, 4, 256, 256), None),
                         ((8, 4, 512, 512), None)):
        clean = torch.rand(shape, device=device) * 0.2
        noisy = aug(clean)

        def step():
            opt.zero_grad(set_to_none=True)
            with torch.autocast("cuda", dtype=dtype or torch.float32, enabled=dtype is not None):
                loss = (net(noisy) - clean).abs().mean()
            loss.backward()
            opt.step()

        t_step = _cuda_timed(step, repeats * 3)
        t_aug = _cuda_timed(lambda: aug(clean), repeats * 10)
        print(f"  U-Net step {shape} {'bf16' if dtype else 'fp32'}: {t_step * 1e3:.2f} ms; augmentation (drawn) "
              f"{t_aug * 1e3:.3f} ms = {t_aug / t_step:.1%} of it (target < 5%)")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None, help="one thread count (default: 1, 2 and all)")
    parser.add_argument("--gpu-only", action="store_true", help="skip the CPU comparisons")
    parser.add_argument("--profile", default=None,
                        help="also time this profile with its effects (a loop profile): on the GPU, and on the CPU against the base model")
    args = parser.parse_args(argv)
    if args.gpu_only:
        if not torch.cuda.is_available():
            parser.error("--gpu-only needs a CUDA device; none is available here")
        gpu_report(args.repeats, args.profile)
        return
    flat = torch.rand(args.batch, 4, args.size, args.size, generator=torch.Generator().manual_seed(0)) * 0.2
    workloads = {
        "flat": (flat, RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", fixed=FIXED)),
        "scenes": (scene_batch(args.batch, args.size),
                   RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", generator=torch.Generator().manual_seed(0))),
    }
    draw_comparison(args.repeats)
    for threads in sorted({1, 2, torch.get_num_threads()} if args.threads is None else {args.threads}):
        for name, (clean, aug) in workloads.items():
            cpu_comparison(name, clean, aug, threads, args.repeats)
        if args.profile:
            cpu_profile_cost(flat, args.profile, threads, args.repeats)
    if torch.cuda.is_available():
        gpu_report(args.repeats, args.profile)
    else:
        print("GPU: no CUDA device here, GPU figures not measured")


if __name__ == "__main__":
    main()
