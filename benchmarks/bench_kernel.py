"""Where the fused Triton kernel's time goes on CUDA, beside a device copy of the same bytes
(the bandwidth bound), in one process. Outputs as in ``benchmarks/results_h100/``:

* ``stages``: each stage alone, and exact Poisson against the number of electrons, at
  (8, 4, 512, 512) (``stages.txt``, measured at 1024 elements per program, the default then);
* ``blocks``: the whole model against the block size and warp count at (32, 4, 512, 512),
  and whether the noise stays the same (it must: the counters are per element) (``blocks.txt``).

    python benchmarks/bench_kernel.py [stages|blocks] [--profile LOOP_PROFILE.yaml]
"""
import argparse
import sys

import torch

from bench_augment import FIXED, _cuda_timed
from rawaug import RawNoiseAugment
from rawaug.engine import backend as B
from rawaug.engine import layout as L
from rawaug.engine.backend import synthesize_op
from rawaug.engine.transfer import to_device

CONFIGS = ((1024, 4), (1024, 8), (512, 4), (512, 8), (256, 4), (256, 8), (128, 4), (256, 2))


def on_device(aug, batch, dev):
    """The parameters of one call (sample 0's for every sample), keys and tables on ``dev``."""
    values = aug._params["values"][:1].expand(batch, -1).contiguous()
    values, keys = to_device((values, aug._stream_keys(int(aug._params["seed"]))), dev)
    return values, keys, aug._tables_on(dev)


def stages(dev):
    clean = torch.rand(8, 4, 512, 512, device=dev) * 0.2
    t_copy = _cuda_timed(lambda: torch.empty_like(clean).copy_(clean), 30)
    print(f"copy {t_copy * 1e3:.3f} ms", flush=True)
    aug = RawNoiseAugment("SonyA7S2", model="G*+P*+R+U", fixed=FIXED)
    aug(clean[:1])
    values, keys, tables = on_device(aug, 8, dev)
    span = float(aug.profile.span_dn)
    for name, flags in [("none", 0), ("P*", L.SHOT_POISSON), ("P", L.SHOT_GAUSS), ("G*", L.READ_TUKEY), ("G", L.READ_GAUSS),
                        ("R", L.ROW), ("U", L.QUANT), ("C", L.BIAS), ("G*+P*+R+U", aug._flags)]:
        t = _cuda_timed(lambda: synthesize_op(clean, values, keys, span, flags, *tables), 30)
        print(f"{name:12s} {t * 1e3:.3f} ms  {t_copy / t:.1%} of the bound", flush=True)
    for level in (0.002, 0.02, 0.2, 1.0):
        c = torch.rand(8, 4, 512, 512, device=dev) * level
        t = _cuda_timed(lambda: synthesize_op(c, values, keys, span, L.SHOT_POISSON, *tables), 30)
        print(f"P* at clean U(0, {level}) (0-{level * span / 200:.0f} e-): {t * 1e3:.3f} ms", flush=True)


def blocks(dev, profile):
    from rawaug.gpu import fused

    clean = torch.rand(32, 4, 512, 512, device=dev) * 0.2
    t_copy = _cuda_timed(lambda: torch.empty_like(clean).copy_(clean), 20)
    print(f"copy (32,4,512,512) {t_copy * 1e3:.3f} ms", flush=True)
    fine, coarse = B.poisson_tables(str(dev))
    normal = B.normal_table_on(str(dev))
    for name, prof in [("G*+P*+R+U", "SonyA7S2")] + ([("loop", profile)] if profile else []):
        aug = RawNoiseAugment(prof, model="G*+P*+R+U", fixed=FIXED)
        aug(clean[:1])
        values, keys, (grids, code_lut, read_lut) = on_device(aug, 32, dev)
        ref = None
        for block, warps in CONFIGS:
            out = torch.empty_like(clean)
            t = _cuda_timed(lambda: fused.launch(clean, out, values, keys, float(aug.profile.span_dn), aug._flags, fine, coarse, grids,
                                                 normal, code_lut, read_lut, block=block, num_warps=warps), 20)
            same = "ref" if ref is None else ("same noise" if torch.equal(out, ref) else "DIFFERENT")
            ref = out.clone() if ref is None else ref
            print(f"{name:10s} BLOCK {block:5d} warps {warps}: {t * 1e3:.3f} ms = {t_copy / t:.1%} of the bound; {same}", flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("part", nargs="?", choices=["stages", "blocks"], default=None, help="one part (default: both)")
    parser.add_argument("--profile", default=None, help="blocks: also a loop profile, with its effects")
    args = parser.parse_args(argv)
    if not torch.cuda.is_available():
        sys.exit("bench_kernel.py needs a CUDA device; none is available here")
    dev = torch.device("cuda")
    if args.part in (None, "stages"):
        stages(dev)
    if args.part in (None, "blocks"):
        blocks(dev, args.profile)


if __name__ == "__main__":
    main()
