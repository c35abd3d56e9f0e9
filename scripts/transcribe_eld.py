"""Write rawaug's built-in profiles from the ELD authors' released parameters.

Source: Vandermode/ELD camera_params/release/*_params.npy, as transcribed to JSON in
shared/data/published/ELD/ELD_camera_params.json (MIT licence, rawaug/profiles/LICENSE-ELD).

Choices made here, because the release does not record them:
* ``G_shape`` and ``color_bias`` rows are ordered from low to high ISO in pairs of frames.
  Each pair is given the K of its ISO step, spaced geometrically from Kmin (ISO 100) to
  Kmax (ISO 6400) -- ISO steps are geometric and K is linear in ISO.
* ``Profile-1`` is used (the authors' code samples it); NikonD850 also has a ``Profile-2``
  whose coefficients are noted in the source field.
* Black/white levels are not in the release. SonyA7S2 uses black 512, white 16383. For the
  other cameras the nominal 14-bit levels below are placeholders: the augmentation only
  uses white - black to convert normalized values to DN, so set them from your raw files.
"""
import json
import math
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT.parent / "shared/data/published/ELD/ELD_camera_params.json"
LEVELS = {  # black, white, bit depth
    "SonyA7S2": (512, 16383, 14, "from the data README (SonyA7S2 ARW)"),
    "NikonD850": (0, 16383, 14, "nominal 14-bit placeholder: set from your raw files"),
    "CanonEOS70D": (2048, 15000, 14, "nominal placeholder: set from your raw files"),
    "CanonEOS700D": (2048, 15000, 14, "nominal placeholder: set from your raw files"),
    "CanonEOS5D4": (2048, 15000, 14, "nominal placeholder: set from your raw files"),
}


def relation(d):
    return {"slope": d["slope"], "intercept": d["bias"], "residual_std": d["sigma"]}


def pair_k(n, kmin, kmax):
    steps = (n + 1) // 2
    ks = [kmin * (kmax / kmin) ** (i / max(steps - 1, 1)) for i in range(steps)]
    return [ks[i // 2] for i in range(n)]


def main(source=SOURCE, out_dir=ROOT / "rawaug/profiles"):
    data = json.loads(Path(source).read_text())
    for camera, p in data.items():
        prof = p["Profile-1"]
        black, white, bits, level_note = LEVELS[camera]
        kmin, kmax = p["Kmin"], p["Kmax"]
        note = (
            f"ELD (Wei et al., CVPR 2020) released parameters for {camera}, Profile-1; "
            f"Vandermode/ELD camera_params/release, MIT licence (LICENSE-ELD). "
            f"Record K values assigned by ISO step (see scripts/transcribe_eld.py). Levels: {level_note}."
        )
        if "Profile-2" in p:
            note += " Release also holds Profile-2: " + json.dumps(p["Profile-2"])
        doc = {
            "format": "rawaug.noise-profile",
            "version": 1,
            "camera": camera,
            "source": note,
            "sensor": {"black_level": black, "white_level": white, "bit_depth": bits, "cfa": "RGGB"},
            "system_gain": {"k_min": kmin, "k_max": kmax, "iso": [100, 6400], "k": [kmin, kmax]},
            "read_noise": {
                "tukey_scale": relation(prof["G_scale"]),
                "gaussian_scale": relation(prof["g_scale"]),
                "tukey_shape": {"k": pair_k(len(p["G_shape"]), kmin, kmax), "lambda": p["G_shape"]},
            },
            "row_noise": {"scale": relation(prof["R_scale"])},
            "quantization": {"step_dn": 1.0},
            "color_bias": {"k": pair_k(len(p["color_bias"]), kmin, kmax), "dn": p["color_bias"]},
            "effects": {},
        }
        (Path(out_dir) / f"{camera}.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
        assert math.isclose(kmax / kmin, 64, rel_tol=1e-6), camera


if __name__ == "__main__":
    main(*sys.argv[1:])
