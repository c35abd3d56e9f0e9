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
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from threadpoolctl import threadpool_limits

from ..io import find_flat_pairs, group_by_iso, read_frame, read_manifest
from ..io.manifest import ManifestEntry
from ..io.readers import RAWPY_EXTENSIONS
from ..outputs import check_outputs, write_set
from .censored import code_floor
from .diagnostics import CalibrationWarning, frame_anomalies
from .joint import fit_joint, pick_camera, read_parameter_tables
from .stage1 import calibrate_iso, centered_spectrum, estimate_quantization_step

BIAS_MEAN_FRACTION = 0.01  # directory mode: mean below black + 1% of (white - black) -> bias


def add_arguments(parser) -> None:
    parser.add_argument("input", help="CSV manifest, a folder of camera raw files (or with manifest.csv), "
                                      "or a per-ISO parameter table (.json/.csv) for stage 2 only")
    parser.add_argument("--out", required=True, help="profile YAML to write (atomically)")
    parser.add_argument("--report", default=None, help="folder for report.json, report.md and the figures")
    add_calibration_options(parser)


def add_calibration_options(parser) -> None:
    """The options of a calibration, shared by ``rawaug calibrate`` and ``rawaug loop``."""
    parser.add_argument("--camera", default=None,
                        help="camera name stored in the profile (default: the table's camera name, else the "
                        "input's name); in a table of several cameras, the one to calibrate")
    parser.add_argument("--cfa", default=None, choices=["RGGB", "BGGR", "GRBG", "GBRG"],
                        help="CFA (table input, or to override the frames')")
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
    with path.open(newline="", encoding="utf-8-sig") as f:  # a UTF-8 BOM is not part of the header
        for line in f:
            if line.strip() and not line.lstrip().startswith("#"):
                header = [h.strip().lower() for h in next(csv.reader([line]))]
                if len(header) == 1 and ";" in line:
                    raise ValueError(f"{path}: fields are separated by ';'; rawaug reads comma-separated CSV "
                                     f"(header found: {line.strip()!r})")
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
    """Reads frames on demand, checks they agree in size/levels, and keeps what the report
    needs. ``on_frame(entry, frame)`` sees each frame once, when it is first read."""

    def __init__(self, overrides, bar, on_frame=None):
        self.overrides = overrides
        self.bar = bar
        self.on_frame = on_frame
        self.reference = None
        self.quant_steps = []
        self.notes = []
        self.spectrum = None
        self.seen: set[int] = set()  # id() of the entries read
        self._held = None  # (entry, frame): the reference, read ahead of its turn
        self._shown: dict = {}  # is the last bias frame -> (its anomalies, its spectrum)

    def read(self, entry):
        if self._held is not None and self._held[0] is entry:
            frame, self._held = self._held[1], None
            return frame
        hints = {**entry.hints, **{k: v for k, v in self.overrides.items() if v is not None}}
        frame = read_frame(entry.path, **hints)
        if self.reference is None:
            self.reference = frame
            self._held = (entry, frame)
        ref = self.reference
        if frame.shape != ref.shape:
            raise ValueError(f"frames differ in size: {entry.path} is {frame.shape[1]}x{frame.shape[0]}, "
                             f"{ref.path} is {ref.shape[1]}x{ref.shape[0]}")
        if not np.array_equal(frame.black_packed(), ref.black_packed()):
            raise ValueError(f"frames differ in black level: {entry.path} has {frame.black_packed().tolist()}, "
                             f"{ref.path} has {ref.black_packed().tolist()} (raw codes, R G1 B G2); calibrate frames "
                             "of one black level together, or give --black-level")
        if frame.cfa != ref.cfa or frame.white_level != ref.white_level:
            raise ValueError(f"frames differ in CFA/white level: {entry.path} ({frame.cfa}, {frame.white_level:g}) "
                             f"vs {ref.path} ({ref.cfa}, {ref.white_level:g})")
        if id(entry) not in self.seen:
            self.seen.add(id(entry))
            if self.on_frame is not None:
                self.on_frame(entry, frame)
        return frame

    def read_rest(self, entries):
        """The entries no step has read yet, for ``on_frame`` (none without it)."""
        if self.on_frame is None:
            return
        for entry in entries:
            if id(entry) not in self.seen:
                self.read(entry)

    def loader(self, entry):
        def load():
            frame = self.read(entry)
            if entry.kind in ("bias", "dark"):
                step = estimate_quantization_step(frame.mosaic, max_values=200_000)
                if step is not None:
                    self.quant_steps.append(step)
                if entry is self._first or entry is self._last_bias:  # the first frame's anomalies and the last's
                    self._shown[entry is self._last_bias] = (
                        frame_anomalies(frame), (centered_spectrum(frame.mosaic, 512), f"{Path(entry.path).name}, ISO {entry.iso:g}"))
            if self.bar is not None:
                self.bar.update(1)
            return frame.packed_dn()

        return load

    _first = _last_bias = None

    @property
    def shown(self) -> tuple[list, object]:
        """(the anomalies of the first bias frame and of the last one of the highest ISO, the
        spectrum of that last one, else of the first), whatever order they were read in."""
        parts = [self._shown[k] for k in (False, True) if k in self._shown]
        return [n for notes, _ in parts for n in notes], parts[-1][1] if parts else None


def input_paths(source: Path) -> list[Path]:
    """Every input of a calibration: the source, and the frames a manifest lists."""
    paths = [source]
    manifest = source / "manifest.csv" if source.is_dir() else source
    if manifest.is_file() and manifest.suffix.lower() == ".csv" and _is_manifest_csv(manifest):
        paths += [Path(e.path) for e in read_manifest(manifest)]
    return paths


@dataclass
class CalibrationOptions:
    """What ``rawaug calibrate`` takes besides its input and outputs (see ``add_arguments``)."""

    camera: str | None = None
    cfa: str | None = None
    black_level: float | None = None
    white_level: float | None = None
    bit_depth: int | None = None
    quantization_step: float | None = None
    max_samples: int | None = 200_000
    quiet: bool = True


@dataclass
class Calibration:
    """A calibrated profile with what its report shows."""

    profile: object  # NoiseProfile
    params: list
    where: str
    notes: list
    spectrum: tuple | None
    elapsed_s: float

    def write_report(self, folder):
        """report.json, report.md and the figures into ``folder``; returns the .md path."""
        return _write_report(folder, self.profile, self.params, self.where, self.notes, self.spectrum, self.elapsed_s)


def options_from(args) -> CalibrationOptions:
    if args.bit_depth is not None and not 1 <= args.bit_depth <= 32:
        raise ValueError(f"--bit-depth must be in [1, 32], got {args.bit_depth}")
    if args.quantization_step is not None and not args.quantization_step > 0:
        raise ValueError(f"--quantization-step must be > 0 DN, got {args.quantization_step}")
    if args.max_samples is not None and args.max_samples != 0 and args.max_samples < 1000:
        raise ValueError(f"--max-samples must be 0 (all) or >= 1000 (values for the Tukey-lambda fit), got {args.max_samples}")
    return CalibrationOptions(camera=args.camera, cfa=args.cfa, black_level=args.black_level, white_level=args.white_level,
                              bit_depth=args.bit_depth, quantization_step=args.quantization_step,
                              max_samples=args.max_samples or None, quiet=args.no_progress)


def is_table(source: Path) -> bool:
    return source.is_file() and (source.suffix.lower() == ".json"
                                 or (source.suffix.lower() == ".csv" and not _is_manifest_csv(source)))


def calibrate(source, options: CalibrationOptions | None = None, on_frame=None) -> Calibration:
    """Calibrate a camera from ``source``: a manifest, a folder (with or without
    ``manifest.csv``) or a per-ISO parameter table. The library under ``rawaug calibrate``
    and ``rawaug loop``.

    ``on_frame(entry, frame)`` is called once for every frame of a manifest or folder, the
    frames calibration does not use included, as each is read and checked: a caller that
    needs the frames (``rawaug loop``) reads none of them again."""
    source, options = Path(source), options or CalibrationOptions()
    if not source.exists():
        raise FileNotFoundError(f"input {str(source)!r} does not exist")
    if is_table(source):
        return _calibrate_table(source, options)
    return _calibrate_frames(source, options, on_frame)


def frame_entries(source: Path, tell=lambda _m: None) -> tuple[list[ManifestEntry], str]:
    """The frames of a manifest or a folder (its ``manifest.csv``, else its raw files with
    their kinds guessed), and where they were listed."""
    if source.is_dir():
        manifest = source / "manifest.csv"
        if manifest.is_file():
            return read_manifest(manifest), str(manifest)
        return _directory_entries(source, tell), f"{source} (kinds guessed from the frame means)"
    return read_manifest(source), str(source)


def visit_frames(source, options: CalibrationOptions | None, on_frame) -> str:
    """Read every frame of a manifest or folder once, with the checks and options of a
    calibration, for ``on_frame(entry, frame)`` (``rawaug loop --profile``: no calibration);
    returns where the frames were listed."""
    options = options or CalibrationOptions()
    entries, where = frame_entries(Path(source))
    overrides = {"cfa": options.cfa, "black_level": options.black_level, "white_level": options.white_level}
    frames = _FrameSource(overrides, None, on_frame)
    frames.read_rest(entries)
    return where


def run(args) -> int:
    source = Path(args.input)
    if not source.exists():
        raise FileNotFoundError(f"input {str(source)!r} does not exist")
    out = Path(args.out)
    check_outputs(out, args.report, input_paths(source))
    result = calibrate(source, options_from(args))
    write_set(result.profile, out, args.report, result.write_report)
    p = result.profile
    floor = f"; frames clipped at code 0: Clip at {p.effects['Clip']['floor_dn']:g} DN" if "Clip" in p.effects else ""
    print(f"wrote {out} ({len(result.params)} ISOs, K {p.k_min:.4g}..{p.k_max:.4g} DN/e-{floor}) in {result.elapsed_s:.1f} s")
    if args.report:
        print(f"wrote report {Path(args.report) / 'report.md'}")
    return 0


def _calibrate_frames(source: Path, args: CalibrationOptions, on_frame=None) -> Calibration:
    from tqdm import tqdm

    start = time.perf_counter()
    max_samples = args.max_samples
    quiet = args.quiet
    tell = (lambda _m: None) if quiet else (lambda m: tqdm.write(m))
    entries, where = frame_entries(source, tell)

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
        frames = _FrameSource(overrides, bar, on_frame)
        frames.read(plan[min(plan)][0][0])  # reference frame: levels and CFA
        ref = frames.reference
        saturation = ref.white_level - float(np.max(ref.black_packed()))
        black_clip = -float(np.min(ref.black_packed()))
        frames._first, frames._last_bias = plan[min(plan)][0][0], plan[max(plan)][0][-1]  # what the report shows of a frame

        def one(item):
            iso, (bias, pairs) = item
            p = calibrate_iso([frames.loader(e) for e in bias], [(frames.loader(a), frames.loader(b)) for a, b in pairs], iso,
                              max_samples=max_samples, saturation_dn=saturation, black_clip_dn=black_clip, progress=None,
                              black_code=ref.black_packed())
            bar.set_postfix_str(f"ISO {iso:g}: K={p.k:.3g}")
            return p

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            workers = min(len(plan), torch.get_num_threads())
            if workers < 2:
                params = [one(item) for item in plan.items()]
            else:  # the ISOs on threads (reads and NumPy release the GIL), one BLAS thread each
                with threadpool_limits(limits=1, user_api="blas"), ThreadPoolExecutor(max_workers=workers) as pool:
                    params = list(pool.map(one, plan.items()))
        frames.read_rest(entries)  # the frames calibration left out (unpaired flats, ...), for on_frame
        shown_notes, frames.spectrum = frames.shown
        notes += [str(w.message) for w in caught] + shown_notes + frames.notes
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
    floor = code_floor([(p.extra.get("black_floor") or {}).get("floor_dn") for p in params], ref.black_packed())
    if floor is not None:  # the frames hold no code under 0: the format's floor, like the white level
        profile = profile.with_effect("Clip", {"floor_dn": floor})
    return Calibration(profile, params, where, notes, frames.spectrum, time.perf_counter() - start)




def _write_report(folder, profile, params, where, notes, spectrum, elapsed):
    from .report import write_report

    spec, title = spectrum if spectrum else (None, "")
    return write_report(folder, profile, params, inputs={"source": where}, warnings_list=notes, spectrum=spec,
                        spectrum_title=title, timing={"total": elapsed})


def _calibrate_table(source: Path, args: CalibrationOptions) -> Calibration:
    start = time.perf_counter()
    tables = read_parameter_tables(source)
    chosen = pick_camera(tables, args.camera, source)
    params = tables[chosen]
    first = params[0].extra
    black = args.black_level if args.black_level is not None else first.get("bl", first.get("black_level"))
    white = args.white_level if args.white_level is not None else first.get("wp", first.get("white_level"))
    cfa = args.cfa or first.get("cfa")
    missing = [name for name, v in (("--black-level", black), ("--white-level", white), ("--cfa", cfa)) if v in (None, "")]
    if missing:
        raise ValueError(f"{source}: the table does not give {', '.join(missing)}; pass them on the command line")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        camera = chosen if len(tables) > 1 else (args.camera or chosen or source.stem)  # --camera only names a lone table
        profile = fit_joint(params, camera=camera, black_level=float(black),
                            white_level=float(white), bit_depth=_bit_depth(white, args.bit_depth), cfa=cfa,
                            quantization_step_dn=args.quantization_step or 1.0,
                            source=f"rawaug calibrate (stage 2) of per-ISO table {source.name}")
    notes = [str(w.message) for w in caught]
    return Calibration(profile, params, str(source), notes, None, time.perf_counter() - start)
