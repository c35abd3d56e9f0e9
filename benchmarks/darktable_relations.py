"""The parameter diagnosis on darktable's measured noise profiles: how well the chosen
structure (jumps, floor) fits sigma_G against K, over every camera with >= 8 ISOs.

    python benchmarks/darktable_relations.py /usr/share/darktable/noiseprofiles.json

darktable's file is GPL-3: this reads the user's own installed copy (Debian package
``darktable``) and ships nothing of it. Per camera, K and sigma_G per ISO come from
``rawaug.calibration.darktable.gains_and_read_noise`` (K from green, sigma_G the geometric
mean of the channels; ISOs with a resolved read noise, b > 0 in every channel); the error
is the rms residual of log(sigma_G) of the single ELD line and of the structure
``relation_loop`` keeps. Prints the medians over cameras and the structures kept.

Then the absolute scale: for the cameras both in darktable's file and among rawaug's
built-in ELD profiles, darktable's K and sigma_G against ELD's K and Gaussian read noise at
ISO 400-6400 (span 16383), raw and after either rescaling rule anchored at ISO 1600.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter

import numpy as np

from rawaug import NoiseProfile
from rawaug.calibration.darktable import DEBIAN_PATH, find_camera, gains_and_read_noise
from rawaug.loop.parameters import BIC_DROP, F_TEST_P, fit_structure, relation_loop


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("noiseprofiles", nargs="?", default=DEBIAN_PATH, help="darktable's noiseprofiles.json (yours)")
    ap.add_argument("--min-isos", type=int, default=8)
    args = ap.parse_args(argv)
    data = json.loads(open(args.noiseprofiles).read())
    start = time.perf_counter()
    rows = []
    for maker in data.get("noiseprofiles", []):
        for model in maker.get("models", []):
            gains, read = gains_and_read_noise(model.get("profiles", []), 1.0)  # the span cancels in log residuals
            isos = sorted(set(gains) & set(read))
            if len(isos) < args.min_isos:
                continue
            k, sigma = np.array([gains[i] for i in isos]), np.array([read[i] for i in isos])
            fit, _ = relation_loop(k, sigma, "sigma_g")
            rows.append((f"{maker.get('maker')} {model.get('model')}", len(isos), fit_structure(k, sigma).rms, fit.rms, fit.name))
    line, kept = np.array([r[2] for r in rows]), np.array([r[3] for r in rows])
    print(f"{len(rows)} cameras with >= {args.min_isos} ISOs of resolved read noise in {args.noiseprofiles}")
    print(f"median rms(log sigma_G): single line {np.median(line):.4f} -> kept structure {np.median(kept):.4f} "
          f"(BIC drop > {BIC_DROP:g}, F-test p < {F_TEST_P:g}); {time.perf_counter() - start:.0f} s")
    print("structures kept: " + ", ".join(f"{name} {count}" for name, count in Counter(r[4] for r in rows).most_common()))
    print_scale(data)
    return 0


ELD_IN_DARKTABLE = {"NikonD850": "Nikon D850", "CanonEOS70D": "Canon EOS 70D", "CanonEOS700D": "Canon EOS 700D",
                    "CanonEOS5D4": "Canon EOS 5D Mark IV"}


def print_scale(data: dict, isos=(400, 800, 1600, 3200, 6400), anchor=1600) -> None:
    """darktable / ELD ratios of K and sigma_G per ISO: as imported, after scaling both by the K
    ratio at ``anchor`` (darktable = raw x constant), and sigma_G by its square root (darktable
    = raw averaged over about that many pixels)."""
    print(f"darktable / ELD at ISO {', '.join(map(str, isos))} (span 16383; rescaled at ISO {anchor}):")
    for eld_name, dt_name in ELD_IN_DARKTABLE.items():
        try:
            profiles = find_camera(data, dt_name)[2]
        except ValueError:
            continue
        gains, read = gains_and_read_noise(profiles, 16383.0)
        eld = NoiseProfile.load(eld_name)
        here = [i for i in isos if i in gains and i in read]
        if anchor not in here:
            continue
        k_ratio = np.array([gains[i] / eld.k_at_iso(i) for i in here])
        s_ratio = np.array([read[i] / eld.gaussian_scale.median(eld.k_at_iso(i)) for i in here])
        n = 1.0 / k_ratio[here.index(anchor)]
        fmt = lambda v: "/".join(f"{x:.2f}" for x in v)  # noqa: E731
        print(f"  {eld_name:13s} K {fmt(k_ratio)} -> x{n:.1f}: {fmt(k_ratio * n)};  sigma_G {fmt(s_ratio)} -> x{n:.1f}: "
              f"{fmt(s_ratio * n)}, x sqrt: {fmt(s_ratio * np.sqrt(n))}")


if __name__ == "__main__":
    sys.exit(main())
