"""``rawaug import-darktable NOISEPROFILES_JSON "MAKER MODEL"``: a darktable noise profile
as a Poisson-Gaussian NoiseProfile.

darktable (GPL-3) ships measured noise profiles of several hundred cameras in
``noiseprofiles.json`` (Debian: ``/usr/share/darktable/noiseprofiles.json``). This reads the
user's own installed copy; rawaug ships none of it. Each profile holds, per ISO and per
colour channel, ``var(x) = a * x + b`` for the black-subtracted raw value normalized to
``x = DN / (white - black)``. In DN, with ``span = white - black``:
``var(D) = (a * span) * D + b * span^2``, so the system gain is ``K = a * span`` (DN per
electron) and the Gaussian read noise ``sigma_G = sqrt(b) * span`` (DN). The result is a
``G+P`` profile: darktable measures no Tukey-lambda shape, row noise or colour bias.

darktable measures on its own processed image, so this K is on darktable's scale: for the
cameras also in the ELD authors' calibration it is 5-12 times below the raw K (README).
"""
from __future__ import annotations

import json
import math
import re
import warnings
from pathlib import Path

from .joint import IsoParameters, fit_joint

DEBIAN_PATH = "/usr/share/darktable/noiseprofiles.json"


def _norm(name: str) -> str:
    return re.sub(r"\s+", " ", str(name)).strip().lower()


def find_camera(data: dict, camera: str) -> tuple[str, str, list]:
    """(maker, model, profiles) of ``camera`` ("MAKER MODEL" or "MODEL", case-insensitive)."""
    want = _norm(camera)
    names = []
    for maker in data.get("noiseprofiles", []):
        for model in maker.get("models", []):
            m, mo = str(maker.get("maker", "")), str(model.get("model", ""))
            names.append(f"{m} {mo}")
            if want in (_norm(f"{m} {mo}"), _norm(mo)):
                return m, mo, list(model.get("profiles", []))
    close = [n for n in names if all(part in _norm(n) for part in want.split())][:10]
    hint = f"; similar: {close}" if close else f"; {len(names)} cameras in the file"
    raise ValueError(f"camera {camera!r} is not in the darktable noise profiles{hint}")


def _median(values):
    values = sorted(float(v) for v in values)
    n = len(values)
    return values[n // 2] if n % 2 else 0.5 * (values[n // 2 - 1] + values[n // 2])


def gains_and_read_noise(profiles: list, span: float) -> tuple[dict, dict]:
    """``({iso: K}, {iso: sigma_G})`` in DN/e- and DN (darktable's scale: see README).

    K comes from the green channel: darktable measures after white balance, whose multiplier
    is 1 on green, so ``a`` of red and blue carries their multipliers (their ratio to green
    is the same at every ISO). sigma_G is the geometric mean over the three channels (mean of
    log ``sqrt(b)``): three estimates of one read noise. Its intercept ``b`` is often <= 0 (read
    noise below what the fit resolves); an ISO has a read noise only where ``b > 0`` in every
    channel. Repeated entries of one ISO: medians."""
    a_by_iso, s_by_iso = {}, {}
    for p in profiles:
        iso = float(p["iso"])
        a, b = [float(v) for v in p["a"]], [float(v) for v in p["b"]]
        if len(a) != 3 or len(b) != 3:
            raise ValueError(f"darktable profile {p.get('name', iso)!r}: a and b need 3 channels, got {len(a)} and {len(b)}")
        a_by_iso.setdefault(iso, []).append(a[1])
        resolved = all(math.isfinite(v) and v > 0 for v in b)
        s_by_iso.setdefault(iso, []).append(math.exp(sum(0.5 * math.log(v) for v in b) / 3) if resolved else math.nan)
    gains, read = {}, {}
    for iso in sorted(a_by_iso):
        a, s = _median(a_by_iso[iso]), s_by_iso[iso]
        if math.isfinite(a) and a > 0:
            gains[iso] = a * span
            if all(math.isfinite(v) for v in s):
                read[iso] = _median(s) * span
    return gains, read


def import_profile(path, camera: str, *, black_level: float, white_level: float, cfa: str = "RGGB"):
    """The NoiseProfile of ``camera`` from a darktable ``noiseprofiles.json``: the K range and
    ISO table from every ISO with a gain, the sigma_G relation fitted (log-linear in K) on the
    ISOs where darktable resolved a read noise and extrapolated to the others."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"darktable noise profiles {str(path)!r} do not exist (Debian installs them at {DEBIAN_PATH})")
    if not white_level > black_level >= 0:
        raise ValueError(f"need white level > black level >= 0 (raw codes), got black {black_level}, white {white_level}")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a darktable noiseprofiles.json: {exc}") from None
    maker, model, profiles = find_camera(data, camera)
    gains, read = gains_and_read_noise(profiles, white_level - black_level)
    name = f"{maker} {model}".strip()
    params = [IsoParameters(iso=iso, k=gains[iso], sigma_tl=None, sigma_r=None, lam=None, sigma_g=sigma)
              for iso, sigma in read.items()]
    if len({p.k for p in params}) < 2:
        raise ValueError(f"{name}: darktable resolves a read noise (b > 0) at {len(params)} ISO(s); a profile needs >= 2")
    left = sorted(set(gains) - set(read))
    if left:
        warnings.warn(f"{name}: darktable's read-noise intercept b <= 0 at ISO {', '.join(f'{i:g}' for i in left)}: "
                      "sigma_G there comes from the fitted relation", stacklevel=2)
    profile = fit_joint(params, camera=name, black_level=black_level, white_level=white_level,
                        bit_depth=max(1, math.ceil(math.log2(white_level + 1))), cfa=cfa,
                        source=f"darktable noise profile ({path.name}, GPL-3, read from the user's copy; darktable's scale, not raw)")
    isos = sorted(gains)
    profile.k_min, profile.k_max = min(gains.values()), max(gains.values())
    profile.iso_table = (tuple(isos), tuple(gains[i] for i in isos))
    return type(profile).from_dict(profile.to_dict())  # validated as a file would be


def add_arguments(parser) -> None:
    parser.add_argument("noiseprofiles", help=f"darktable's noiseprofiles.json (Debian: {DEBIAN_PATH})")
    parser.add_argument("camera", help='"MAKER MODEL" as darktable names it, e.g. "Canon EOS 5D Mark II"')
    parser.add_argument("--out", required=True, help="output profile (YAML)")
    parser.add_argument("--black-level", type=float, required=True, help="black level, raw code")
    parser.add_argument("--white-level", type=float, required=True, help="white level, raw code")
    parser.add_argument("--cfa", default="RGGB", choices=["RGGB", "BGGR", "GRBG", "GBRG"])


def run(args) -> int:
    from ..outputs import check_outputs, write_set

    check_outputs(args.out, None, [args.noiseprofiles])
    profile = import_profile(args.noiseprofiles, args.camera, black_level=args.black_level,
                             white_level=args.white_level, cfa=args.cfa)
    write_set(profile, args.out)
    print(f"{profile.camera}: K {profile.k_min:.4g} .. {profile.k_max:.4g} DN/e-, model {profile.richest_model} -> {args.out}")
    print("note: K and sigma_G are on darktable's scale (measured on its processed image), which for the cameras "
          "checked is 5-12x below a raw frame's K; calibrate from one flat pair per ISO for raw K (README)")
    return 0
