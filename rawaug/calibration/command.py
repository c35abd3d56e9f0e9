"""``rawaug calibrate``: measured frames (or a per-ISO table) -> NoiseProfile + report.

Inputs:

* a CSV manifest (header has a ``kind`` column; see :mod:`rawaug.io.manifest`);
* a directory: its ``manifest.csv`` if there is one, otherwise every camera raw file in it
  (DNG, CR2, NEF, ARW, ...), ISO and exposure from EXIF, kind guessed per frame: a bias frame
  when its mean is within 1% of the range (white - black) above black, a flat otherwise;
* a per-ISO parameter table (``.json``, or ``.csv`` without a ``kind`` column): stage 2 only.
"""
from __future__ import annotations

import csv
import math
import time
import warnings
from pathlib import Path

import numpy as np

from ..io import find_flat_pairs, group_by_iso, read_frame, read_manifest
from ..io.manifest import ManifestEntry
from ..io.readers import RAWPY_EXTENSIONS
from .diagnostics import CalibrationWarning, frame_anomalies
from .joint import fit_joint, read_parameter_table
from .stage1 import calibrate_iso, centered_spectrum, estimate_quantization_step

BIAS_MEAN_FRACTION = 0.01  # directory mode: mean below black + 1% of (white - black) -> bias


def add_arguments(parser) -> None:
    parser.add_argument("input", help="CSV manifest, a folder of camera raw files (or with manifest.csv), "
                                      "or a per-ISO parameter table (.json/.csv) for stage 2 only")
    parser.add_argument("--out", required=True, help="profile YAML to write (atomically)")
    parser.add_argument("--report", default=None, help="folder for report.json, report.md and the figures")
    parser.add_argument("--camera", default=None, help="camera name stored in the profile")
    parser.add_argument("--cfa", default=None, help="CFA (table input, or to override the frames')")
    parser.add_argument("--black-level", type=float, default=None, help="black level, raw codes (table input)")
    parser.add_argument("--white-level", type=float, default=None, help="white level, raw codes (table input)")
    parser.add_argument("--bit-depth", type=int, default=None, help="ADC bit depth (default: from the white level)")
    parser.add_argument("--quantization-step", type=float, default=None, help="quantization step, DN (table input)")
    parser.add_argument("--max-samples", type=int, default=200_000,
                        help="values per ISO used by the PPCC read-noise fit (0 = all)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _bit_depth(white, given):
    return int(given) if given else max(1, int(math.ceil(math.log2(float(white) + 1))))


def _is_manifest_csv(path: Path) -> bool:
    with path.open(newline="") as f:
        for line in f:
            if line.strip() and not line.lstrip().startswith("#"):
                header = [h.strip().lower() for h in next(csv.reader([line]))]
                return "kind" in header
    return False


def _directory_entries(folder: Path, tell) -> list[ManifestEntry]:
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in RAWPY_EXTENSIONS)
    if not files:
        raise ValueError(f"folder {str(folder)!r} holds no camera raw files ({', '.join(RAWPY_EXTENSIONS)}) and no "
                         "manifest.csv; write a manifest for other formats")
    entries = []
    for path in files:
        frame = read_frame(path)
        if frame.iso is None:
            raise ValueError(f"{path}: no ISO in EXIF; list the frames in a manifest.csv with an iso column")
        level = float(np.mean(frame.packed_dn()))
        kind = "bias" if level < BIAS_MEAN_FRACTION * frame.span_dn else "flat"
        if kind == "flat" and frame.exposure_s is None:
            raise ValueError(f"{path}: a flat without exposure time in EXIF; use a manifest.csv")
        entries.append(ManifestEntry(path=str(path), kind=kind, iso=frame.iso, exposure_s=frame.exposure_s))
        tell(f"{path.name}: {kind} (mean {level:.1f} DN)")
    return entries


class _FrameSource:
    """Reads frames on demand, checks they agree in size/levels, and keeps what the report needs."""

    def __init__(self, overrides, bar):
        self.overrides = overrides
        self.bar = bar
        self.reference = None
        self.quant_steps = []
        self.notes = []
        self.spectrum = None

    def read(self, entry):
        hints = {**entry.hints, **{k: v for k, v in self.overrides.items() if v is not None}}
        frame = read_frame(entry.path, **hints)
        if self.reference is None:
            self.reference = frame
        ref = self.reference
        if frame.shape != ref.shape:
            raise ValueError(f"frames differ in size: {entry.path} is {frame.shape[1]}x{frame.shape[0]}, "
                             f"{ref.path} is {ref.shape[1]}x{ref.shape[0]}")
        if frame.cfa != ref.cfa or frame.white_level != ref.white_level:
            raise ValueError(f"frames differ in CFA/white level: {entry.path} ({frame.cfa}, {frame.white_level:g}) "
                             f"vs {ref.path} ({ref.cfa}, {ref.white_level:g})")
        return frame

    def loader(self, entry):
        def load():
            frame = self.read(entry)
            if entry.kind in ("bias", "dark"):
                step = estimate_quantization_step(frame.mosaic, max_values=200_000)
                if step is not None:
                    self.quant_steps.append(step)
                if len(self.quant_steps) <= 1 or entry is self._last_bias:
                    self.notes += frame_anomalies(frame)
                    self.spectrum = (centered_spectrum(frame.mosaic, 512), f"{Path(entry.path).name}, ISO {entry.iso:g}")
            self.bar.update(1)
            return frame.packed_dn()

        return load

    _last_bias = None


def run(args) -> int:
    from tqdm import tqdm

    start = time.perf_counter()
    source = Path(args.input)
    if not source.exists():
        raise FileNotFoundError(f"input {str(source)!r} does not exist")
    out = Path(args.out)
    max_samples = args.max_samples or None
    if source.is_file() and (source.suffix.lower() == ".json" or (source.suffix.lower() == ".csv" and not _is_manifest_csv(source))):
        return _run_table(args, source, out, start)

    quiet = args.no_progress
    tell = (lambda _m: None) if quiet else (lambda m: tqdm.write(m))
    if source.is_dir():
        manifest = source / "manifest.csv"
        entries = read_manifest(manifest) if manifest.is_file() else _directory_entries(source, tell)
        where = str(manifest) if manifest.is_file() else f"{source} (kinds guessed from the frame means)"
    else:
        entries = read_manifest(source)
        where = str(source)

    by_iso = group_by_iso(entries)
    plan = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for iso, group in by_iso.items():
            bias = [e for e in group if e.kind in ("bias", "dark")]
            flats = [e for e in group if e.kind == "flat"]
            if not bias:
                raise ValueError(f"ISO {iso:g}: no bias (or dark) frames; row and read noise need at least one")
            pairs = find_flat_pairs(flats)
            if not pairs:
                what = f"a single flat ({flats[0].path})" if len(flats) == 1 else f"{len(flats)} flats, none at equal settings"
                raise ValueError(f"ISO {iso:g}: {what}; the gain K needs flat PAIRS at equal ISO and exposure")
            plan[iso] = (bias, pairs)
    notes = [str(w.message) for w in caught]
    if len(plan) < 2:
        raise ValueError(f"the joint model needs frames at >= 2 ISOs, {where} has ISO {sorted(plan)}")

    overrides = {"cfa": args.cfa, "black_level": args.black_level, "white_level": args.white_level}
    total = sum(len(b) + 2 * len(p) for b, p in plan.values())
    params = []
    with tqdm(total=total, desc="calibrate", unit="frame", disable=quiet) as bar:
        frames = _FrameSource(overrides, bar)
        frames.read(plan[min(plan)][0][0])  # reference frame: levels and CFA
        ref = frames.reference
        saturation = ref.white_level - float(np.max(ref.black_packed()))
        black_clip = -float(np.min(ref.black_packed()))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for iso, (bias, pairs) in plan.items():
                frames._last_bias = bias[-1] if iso == max(plan) else None
                p = calibrate_iso([frames.loader(e) for e in bias],
                                  [(frames.loader(a), frames.loader(b)) for a, b in pairs], iso,
                                  max_samples=max_samples, saturation_dn=saturation, black_clip_dn=black_clip,
                                  progress=None)
                bar.set_postfix_str(f"ISO {iso:g}: K={p.k:.3g}")
                params.append(p)
        notes += [str(w.message) for w in caught] + frames.notes
    for note in notes:
        warnings.warn(note, CalibrationWarning, stacklevel=1)
    step = float(np.median(frames.quant_steps)) if frames.quant_steps else 1.0
    camera = args.camera or (source.name if source.is_dir() else source.stem)
    black = ref.black_level if np.isscalar(ref.black_level) else float(np.mean(ref.black_level))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        profile = fit_joint(params, camera=camera, black_level=black, white_level=ref.white_level,
                            bit_depth=_bit_depth(ref.white_level, args.bit_depth), cfa=ref.cfa,
                            quantization_step_dn=step, source=f"rawaug calibrate of {where}")
    notes += [str(w.message) for w in caught]
    profile.save(out)
    elapsed = time.perf_counter() - start
    print(f"wrote {out} ({len(params)} ISOs, K {profile.k_min:.4g}..{profile.k_max:.4g} DN/e-) in {elapsed:.1f} s")
    if args.report:
        md = _write_report(args.report, profile, params, where, notes, frames.spectrum, elapsed)
        print(f"wrote report {md}")
    return 0


def _write_report(folder, profile, params, where, notes, spectrum, elapsed):
    from .report import write_report

    spec, title = spectrum if spectrum else (None, "")
    return write_report(folder, profile, params, inputs={"source": where}, warnings_list=notes, spectrum=spec,
                        spectrum_title=title, timing={"total": elapsed})


def _run_table(args, source, out, start) -> int:
    params = read_parameter_table(source)
    first = params[0].extra
    black = args.black_level if args.black_level is not None else first.get("bl", first.get("black_level"))
    white = args.white_level if args.white_level is not None else first.get("wp", first.get("white_level"))
    cfa = args.cfa or first.get("cfa")
    missing = [name for name, v in (("--black-level", black), ("--white-level", white), ("--cfa", cfa)) if v in (None, "")]
    if missing:
        raise ValueError(f"{source}: the table does not give {', '.join(missing)}; pass them on the command line")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        profile = fit_joint(params, camera=args.camera or source.stem, black_level=float(black),
                            white_level=float(white), bit_depth=_bit_depth(white, args.bit_depth), cfa=cfa,
                            quantization_step_dn=args.quantization_step or 1.0,
                            source=f"rawaug calibrate (stage 2) of per-ISO table {source.name}")
    notes = [str(w.message) for w in caught]
    profile.save(out)
    elapsed = time.perf_counter() - start
    print(f"wrote {out} ({len(params)} ISOs, K {profile.k_min:.4g}..{profile.k_max:.4g} DN/e-)")
    if args.report:
        print(f"wrote report {_write_report(args.report, profile, params, str(source), notes, None, elapsed)}")
    return 0
