"""``rawaug loop INPUT --out profile.yaml --report DIR``.

INPUT is one of

* a per-ISO parameter table (JSON incl. the PMN ``*_per_ISO`` layout, or CSV with
  ``iso, K, sigma_TL, sigma_r, lambda``): the joint model is fitted
  (``rawaug.calibration.joint.fit_joint``) and its relations get a regime change and a
  noise floor where the residuals demand them;
* a per-frame fit table (CSV with ``frame, channel, meanR, sigmaR, sigmaGs``): the
  frame-to-frame black-level error is diagnosed (needs ``--k`` and ``--frame-size``);
  with ``--profile`` the found ``BLE`` is added to that profile;
* a frame manifest (CSV with ``path, kind, iso, ...``) or a folder (with or without its
  ``manifest.csv``), as ``rawaug calibrate`` takes it: without ``--profile`` the base model
  is first calibrated from it (stage 1 and 2, report in ``DIR/calibration``), and the loop
  keeps the central view of each frame as calibration reads it (each frame is read once);
  then the frame loop compares the bias stacks of every ISO
  with syntheses and adds the missing effects. Dark frames (kind ``dark``, with their
  exposure) are compared with syntheses of the same exposure that carry the read noise and
  offsets of the bias frames of their ISO, so that dark current shows. Flats (kind
  ``flat``) are compared with syntheses at their level; flats of one ISO at >= 3 exposure
  times form a series (``flat_series``) whose linearity is checked too.
"""
from __future__ import annotations

import csv
import math
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..profile import NoiseProfile
from ..statistics import lit_pixels
from . import parameters
from ..outputs import check_outputs, write_set
from .report import (curves_table, figure_curves, figure_steps, outcome_summary, residual_table, setting_curves, steps_table,
                     write_report)


def add_arguments(parser) -> None:
    parser.add_argument("input", help="per-ISO parameter table (.json/.csv), per-frame fit table (.csv) or frame manifest")
    parser.add_argument("--out", help="output profile (YAML)")
    parser.add_argument("--report", required=True, help="report folder (report.json, report.md)")
    parser.add_argument("--profile", help="base profile (built-in name or YAML) for per-frame tables and manifests")
    parser.add_argument("--k", type=float, help="system gain K (DN/e-) of a per-frame table")
    parser.add_argument("--frame-size", type=int, nargs=2, metavar=("ROWS", "COLS"),
                        help="sensor size of the frames of a per-frame table (raw rows, columns)")
    parser.add_argument("--n-synth", type=int, default=12, help="syntheses per diagnosis (frame loop)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--loop-size", type=int, default=LOOP_SIZE, metavar="PIXELS",
                        help="the frame loop diagnoses the central PIXELS x PIXELS of each packed channel "
                             f"(default {LOOP_SIZE}; calibration uses whole frames): the loop's time is then "
                             "independent of the sensor size")
    from ..calibration.command import add_calibration_options

    add_calibration_options(parser)  # the same options, and meaning, as rawaug calibrate


LOOP_SIZE = 256


def central_window(h: int, w: int, size: int) -> tuple[int, int, int, int]:
    """(top, left, height, width) of the central ``size`` x ``size`` of a packed h x w frame
    (all of a smaller side)."""
    top, left = max(0, (h - size) // 2), max(0, (w - size) // 2)
    return top, left, min(size, h), min(size, w)



def _is_frame_table(path: Path) -> bool:
    if path.suffix.lower() != ".csv":
        return False
    with path.open() as f:
        head = next(csv.reader(f), [])
    return "frame" in head and "channel" in head


def _run_parameter_table(args, path):
    from ..calibration.command import calibrate, options_from

    calibration = calibrate(path, options_from(args))  # as rawaug calibrate fits it
    base, params = calibration.profile, calibration.params
    result = parameters.parameter_loop(params)
    profile = parameters.apply_to_profile(base, result["fits"])
    md = [f"# rawaug loop: {path.name}", "", f"{len(params)} ISOs, K {params[0].k:.4g} .. {params[-1].k:.4g} DN/e-.",
          "Errors: rms residual of log(sigma) (natural log; 0.1 is about 10 %).", "", steps_table(result["steps"]),
          "## Residual structure of each relation", "", "| relation | structure | rms log | BIC | break K |", "|---|---|---|---|---|"]
    for name, d in result["diagnosis"].items():
        for st, v in d.items():
            bk = f"{v['break_k']:.4g}" if v["break_k"] else ""
            md.append(f"| {name} | {st} | {v['rms_log']:.3f} | {v['bic']:.1f} | {bk} |")
    report = {"input": str(path), "kind": "parameter_table", "steps": result["steps"], "diagnosis": result["diagnosis"],
              "final": {n: f.relation.to_dict() for n, f in result["fits"].items()}}
    return profile, report, "\n".join(md) + "\n", None  # the table's report is the loop's own


def _run_frame_table(args, path):
    if args.k is None or args.frame_size is None:
        raise ValueError("a per-frame table needs --k (DN/e-) and --frame-size ROWS COLS (raw sensor size)")
    table = parameters.read_frame_table(path)
    rows, cols = args.frame_size[0] // 2, args.frame_size[1] // 2
    result = parameters.frame_table_loop(table, rows, cols, args.k, seed=args.seed)
    profile = None
    if args.profile and result["effects"]:
        profile = NoiseProfile.load(args.profile)
        for token, params in result["effects"].items():
            profile = profile.with_effect(token, params)
    md = [f"# rawaug loop: {path.name}", "", f"{table['means'].shape[0]} frames, K = {args.k:g} DN/e-.", "",
          steps_table(result["steps"]), residual_table(result["before"], "before"), residual_table(result["after"], "after")]
    return profile, {"input": str(path), "kind": "frame_table", **result}, "\n".join(md), None


LEVEL_SPLIT = 0.02  # flats of one setting whose means differ by more were taken under different lights
JITTER_MARGIN = 10  # ... and by more than this many times the camera's frame-to-frame jitter (``_camera_jitter``),
JITTER_GAP_MAX = 0.15  # up to this: a gain does not jitter by 1.5 %, and one frame per unlisted light still splits
SERIES_SPREAD = 0.25  # flats further than this from one line through zero do not share one light


class _Flat(NamedTuple):
    """One usable flat stack of the manifest, before it becomes a FrameStack."""

    stack: np.ndarray
    k: float
    level: np.ndarray  # (4,) DN above the bias offsets
    exposure: float
    light: float | None
    base: dict
    bias_stack: object
    label: str

    @property
    def dose(self) -> float:
        """Exposure time x relative light (1 when the manifest gives none)."""
        return self.exposure * (self.light or 1.0)


def _camera_jitter(means: list) -> float:
    """The frame-to-frame spread of the flats' log means (``means``: each setting's frame
    means), from every gap between a setting's sorted frames, over the camera: their median
    over that of a pair's gap, 0.954 sigma. Most gaps lie within one level (a pair holds
    one), so the median is the jitter's, not an unlisted light's step; the median of a few
    gaps is uncertain by some 40 %."""
    gaps = [np.diff(np.sort(np.log(np.maximum(m, 1e-9)))) for m in means if len(m) >= 2]
    return float(np.median(np.concatenate(gaps))) / 0.954 if gaps else 0.0


def _split_levels(flats: dict) -> dict:
    """Flats of one setting (ISO, exposure, light) split where their sorted means jump by more
    than ``LEVEL_SPLIT``, by more than 6 x the spread of the frames within the levels that
    leaves and by more than ``JITTER_MARGIN`` x the camera's jitter (a gain jitter spreads one
    level's frames; a pair holds one gap): under lights the manifest does
    not list, one exposure holds several levels, and each is a stack of its own (keys gain
    the level's index)."""
    out = {}
    means_of = {key: np.array([float(np.mean(packed)) for packed, _ in frames]) for key, frames in flats.items()}
    jitter = _camera_jitter(list(means_of.values()))
    for (iso, exposure, light), frames in flats.items():
        means = means_of[(iso, exposure, light)]
        order = np.argsort(means)

        def split(gap_ok):
            level, groups = 0, {}
            for before, i in zip([None] + list(order[:-1]), order):
                if before is not None and gap_ok(means[i] / max(means[before], 1e-9) - 1):
                    level += 1
                groups.setdefault(level, []).append(i)
            return groups

        groups = split(lambda gap: gap > LEVEL_SPLIT)
        # a frame-to-frame gain (or light) jitter spreads one level's frames: a gap counts only
        # where it also exceeds 6 x the spread of the frames within the levels it would leave
        within = [np.log(means[g]) - np.log(means[g]).mean() for g in groups.values() if len(g) > 1]
        spread = float(np.sqrt(np.sum(np.concatenate(within) ** 2) / sum(len(w) - 1 for w in within))) if within else 0.0
        if spread > 0 or jitter > 0:  # (a pair 2 % apart has no spread within the levels it would leave)
            groups = split(lambda gap: gap > max(LEVEL_SPLIT, 6 * spread, min(JITTER_MARGIN * jitter, JITTER_GAP_MAX)))
        if len(groups) > 1:
            print(f"warning: ISO {iso:g}: the flats at {exposure:g} s" + (f", light {light:g}" if light else "")
                  + f" fall at {len(groups)} levels (was the light changed?): each level is a stack of its own; "
                  "give each flat's relative light in the manifest's 'light' column for the response's linearity "
                  "to be checked")
        for level, members in groups.items():
            out[(iso, exposure, light, level)] = [frames[i] for i in sorted(members)]
    return out


def flat_series(iso, points, offsets):
    """The ISO's flats as a ``FlatSeries`` (``points``: (dose, (4,) signal DN) per stack;
    the dose is the exposure time, times the manifest's relative ``light`` where given),
    if they can show the response: >= 3 distinct doses, each flat within ``SERIES_SPREAD``
    of a line through zero (flats at one exposure under unlisted lights are not a
    series). Else None, with a warning when a series was tried."""
    from ..effects.gain_nonlinearity import MIN_EXPOSURES
    from .diagnose import FlatSeries

    doses = np.array([float(t or 0.0) for t, _ in points])
    if np.unique(doses[doses > 0]).size < MIN_EXPOSURES or not np.all(doses > 0):
        return None
    series = FlatSeries(doses, np.array([level for _, level in points]), offsets)
    spread = np.abs(series.signal_dn / (series.rates[None, :] * doses[:, None]) - 1).max()
    if spread > SERIES_SPREAD:
        print(f"warning: ISO {iso:g}: the flats' means are up to {100 * spread:.0f} % off a line through zero against "
              f"their exposures (was the light changed? give each flat's relative light in the manifest's 'light' "
              f"column): the response's linearity is not checked")
        return None
    return series


class _Collected:
    """What the frame loop keeps of each frame as calibration reads it: the central
    ``size`` x ``size`` of its packed channels (DN), by kind and setting."""

    def __init__(self, size: int):
        self.size = size
        self.bias: dict = {}  # ISO -> crops
        self.darks: dict = {}  # (ISO, exposure s) -> crops
        self.flats: dict = {}  # (ISO, exposure s, light) -> (crop, headroom DN per channel)
        self.bias_exposure: dict = {}  # ISO -> shortest exposure of its bias frames (s)
        self.shapes = None  # (whole, diagnosed) packed shape
        self.black: dict = {}  # ISO -> raw code of 0 DN per channel, None where the ISO's frames differ

    def black_code(self, iso) -> list | None:
        codes = self.black.get(iso)
        return None if codes is None else [float(c) for c in codes]

    def add(self, entry, frame) -> None:
        kind = getattr(entry, "kind", "bias")
        whole = (frame.shape[0] // 2, frame.shape[1] // 2)
        packed = frame.packed_dn(central_window(*whole, self.size))  # packs the crop only
        self.shapes = (whole, packed.shape[1:])
        black = frame.black_packed()
        known = self.black.setdefault(frame.iso, black)
        if known is not None and not np.array_equal(known, black):
            self.black[frame.iso] = None  # black levels of their own per frame: no one raw code per DN
        if kind == "flat":
            self.flats.setdefault((frame.iso, float(frame.exposure_s or 0.0), getattr(entry, "light", None)), []).append(
                (packed, frame.white_level - frame.black_packed()))
        elif kind == "dark":
            if not frame.exposure_s:
                raise ValueError(f"{entry.path}: a dark frame needs its exposure_s (manifest column or EXIF)")
            self.darks.setdefault((frame.iso, float(frame.exposure_s)), []).append(packed)
        else:
            self.bias.setdefault(frame.iso, []).append(packed)
            self.bias_exposure[frame.iso] = min(self.bias_exposure.get(frame.iso, math.inf), float(frame.exposure_s or 0.0))


def light_on_live_pixels(stack) -> np.ndarray:
    """(4,) mean of a flat stack (N, 4, h, w; DN before black) over the pixels whose value moves
    from frame to frame: a dead pixel or line, stuck at one code, carries no light, while a
    line of pixels that collect less light (phase-detection rows) or read an offset does
    (repairing every defect line had taken those out, and a gain grid of mean 1 then fell
    short of the flat); nor do the lines without light at its edges (``lit_pixels``: a shield).
    A stack of one frame, or with most pixels constant: its mean over the lit pixels."""
    stack = np.asarray(stack, dtype=np.float64)
    lit = lit_pixels(stack.mean(axis=0))  # optically black lines at the edges get no light
    live = (stack.min(axis=0) != stack.max(axis=0)) & lit  # (4, h, w)
    if stack.shape[0] < 2 or live.mean() < 0.5:
        return np.array([stack[:, c][:, lit[c]].mean() for c in range(4)])
    return np.array([stack[:, c][:, live[c]].mean() for c in range(4)])


def _run_manifest(args, path):
    from ..calibration.stage1 import bias_frame_noise
    from ..statistics import spike_outliers, stuck_outliers
    from .diagnose import FrameStack, channel_offsets
    from ..calibration.command import calibrate, options_from, visit_frames
    from .frames_loop import run_frame_loop
    from ..effects.tap_gain import consensus_edges

    frames = _Collected(args.loop_size)
    calibration = None
    if args.profile:  # every frame read once, with the checks and options of a calibration
        profile = NoiseProfile.load(args.profile)
        visit_frames(path, options_from(args), frames.add)
    else:  # the base model, as rawaug calibrate fits it (report in REPORT/calibration), from the same reads
        calibration = calibrate(path, options_from(args), on_frame=frames.add)
        profile = calibration.profile
    bias, darks, flats, bias_exposure, shapes = frames.bias, frames.darks, frames.flats, frames.bias_exposure, frames.shapes
    black_code = frames.black_code
    if not bias:
        raise ValueError(f"{path}: no bias frames (kind 'bias') among the frames")
    stacks, measured, settings = [], {}, {}  # settings: label -> what the report's curves need
    for iso, frames in sorted(bias.items()):
        frames = np.stack(frames).astype(np.float64)
        lowest = frames.min(axis=0) if len(frames) >= 3 else None
        dead = stuck_outliers(lowest, frames.max(axis=0), frames[0]) if lowest is not None else None
        if dead is not None:  # impulses: bright single-frame events beyond the dark ones (``spike_outliers``)
            dead = dead | spike_outliers(frames)[0]
        # dead pixels and spikes left out; a clip's censoring too, and then its hot pixels
        read, sigma_r, _ = bias_frame_noise(frames[0], exclude=dead, lowest=lowest, black_code=black_code(iso))
        k = profile.k_at_iso(iso) if iso else 1.0
        settings[f"ISO {iso:g}"] = {"kind": "bias", "iso": iso, "k": k, "exposure_s": bias_exposure[iso], "level_dn": None}
        stacks.append(FrameStack(frames, k, label=f"ISO {iso:g}", base={"sigma_tl": read.sigma_tl, "lambda": read.lam,
                                                                        "sigma_g": read.sigma_g, "sigma_r": sigma_r},
                                 black_code=black_code(iso)))
        measured[iso] = (stacks[-1].base, channel_offsets(frames), k, stacks[-1])
    for (iso, exposure), frames in sorted(darks.items()):
        if iso not in measured or len(frames) < 2:
            print(f"warning: dark frames at ISO {iso:g}, {exposure:g} s left out: "
                  + ("no bias frames at that ISO to compare them with" if iso not in measured else "fewer than 2 frames"))
            continue
        base, _, k, bias_stack = measured[iso]
        # synthesized with the bias frames' read noise and offsets: what the dark adds shows
        settings[f"ISO {iso:g} dark {exposure:g} s"] = {"kind": "dark", "iso": iso, "k": k, "exposure_s": exposure, "level_dn": None}
        stacks.append(FrameStack(np.stack(frames).astype(np.float64), k, kind="dark", exposure_s=exposure,
                                 label=f"ISO {iso:g} dark {exposure:g} s", base=base, offsets_of=bias_stack,
                                 black_code=black_code(iso)))
    flats = _split_levels(flats)
    flat_stacks: dict = {}  # ISO -> its usable flat stacks
    for (iso, exposure, light, _), frames in sorted(flats.items(), key=lambda item: (item[0][0], item[0][1], item[0][2] or 0.0, item[0][3])):
        if iso not in measured or len(frames) < 2:
            continue  # calibration reports flats it cannot use
        base, offsets, k, bias_stack = measured[iso]
        stack = np.stack([f for f, _ in frames]).astype(np.float64)
        level = light_on_live_pixels(stack) - np.asarray(offsets)
        headroom = min(float(np.min(room)) for _, room in frames)
        if level.min() < 20 * k or stack.max() >= 0.98 * headroom:
            continue  # too dark to carry shot noise, or clipped at white
        label = f"ISO {iso:g} flat {float(level.mean()):.0f} DN"
        while label in settings:  # two flat settings of one rounded level
            label += "'"
        settings[label] = {"kind": "flat", "iso": iso, "k": k, "exposure_s": exposure, "level_dn": float(level.mean())}
        flat_stacks.setdefault(iso, []).append(_Flat(stack, k, level, exposure, light, base, bias_stack, label))
    for iso, items in flat_stacks.items():
        listed = [f.light is not None for f in items]
        if any(listed) and not all(listed):
            print(f"warning: ISO {iso:g}: some flats have a 'light' and some not: the response's linearity is not checked")
            series = None
        else:
            series = flat_series(iso, [(f.dose, f.level) for f in items], measured[iso][1])
        for f in items:
            stacks.append(FrameStack(f.stack, f.k, kind="flat", level_dn=[float(v) for v in (series.nominal(f.dose) if series else f.level)],
                                     base=f.base, offsets_of=f.bias_stack, label=f.label, exposure_s=f.exposure or None,
                                     series=series, dose=f.dose if series else None, black_code=black_code(iso)))
    sensor_taps = consensus_edges([s.gain_edges for s in stacks if s.kind == "flat"])  # the same at every ISO and level
    for s in stacks:
        if s.kind == "flat":
            s.tap_edges = sensor_taps
    given = tuple(t for t in ("Clip",) if calibration is not None and t in profile.effects)  # the code floor calibration found
    result = run_frame_loop(stacks, profile, n_synth=args.n_synth, seed=args.seed, log=print, given=given)
    (h, w), (ch, cw) = shapes
    view = (f"The frame loop diagnosed the central {ch} x {cw} of each frame's packed channels ({h} x {w}; "
            "`--loop-size`); calibration used whole frames." if (ch, cw) != (h, w) else
            f"The frame loop diagnosed whole frames ({h} x {w} per packed channel).")
    floor = [f"`Clip` came with the calibration: the frames hold no code under 0 ({profile.effects['Clip']['floor_dn']:g} DN, "
             "the file's lowest code), as they hold none over white; the profile clips there.", ""] if given else []
    md = [f"# rawaug loop: {path.name}", "", *floor, outcome_summary(result), "", view, "",
          steps_table([s.to_dict() for s in result.steps])]
    for label in result.initial:
        md += [residual_table([r.to_dict() for r in result.initial[label]], f"{label}: before"),
               residual_table([r.to_dict() for r in result.final[label]], f"{label}: after")]
    report = {"input": str(path), "kind": "frames", "loop_view": {"frame": [h, w], "diagnosed": [ch, cw]}, "stacks": settings,
              "steps": [s.to_dict() for s in result.steps],
              "explained_physically": result.explained_physically,
              "reproduced_by_measurement": result.reproduced_by_measurement,
              "unexplained": [{"stack": label, **r.to_dict()} for label, r in result.unexplained()],
              "unconfirmed": result.unconfirmed,
              "removed": result.removed,
              "resized_through_clip": result.resized,
              "read_noise_refits": result.refits,
              "colour_bias_fitted_dn": {str(k): list(v) for k, v in result.colour_bias.items()},
              "initial": {k: [r.to_dict() for r in v] for k, v in result.initial.items()},
              "final": {k: [r.to_dict() for r in v] for k, v in result.final.items()}}
    curves = setting_curves(report)
    if curves:
        md += ["## Statistics across settings", "", curves_table(curves)]
    return result.profile, report, "\n".join(md), calibration


def _is_manifest(path: Path) -> bool:
    from ..calibration.command import _is_manifest_csv

    return path.is_dir() or (path.suffix.lower() == ".csv" and _is_manifest_csv(path))


def run(args) -> int:
    path = Path(args.input)
    if not path.exists():
        raise FileNotFoundError(f"loop input {str(path)!r} does not exist")
    if args.frame_size is not None and min(args.frame_size) < 2:
        raise ValueError(f"--frame-size ROWS COLS must be at least 2 2 (raw sensor size), got {args.frame_size}")
    if args.k is not None and not args.k > 0:
        raise ValueError(f"--k (system gain, DN/e-) must be > 0, got {args.k}")
    if args.n_synth < 3:
        raise ValueError(f"--n-synth must be >= 3 (the spread of the syntheses), got {args.n_synth}")
    if args.loop_size < 16:
        raise ValueError(f"--loop-size must be >= 16 (packed pixels per side the frame loop diagnoses), got {args.loop_size}")
    from ..calibration.command import input_paths

    check_outputs(args.out, args.report, input_paths(path))
    start = time.time()
    if _is_manifest(path):
        profile, report, md, calibration = _run_manifest(args, path)
    elif _is_frame_table(path):
        profile, report, md, calibration = _run_frame_table(args, path)
    else:
        profile, report, md, calibration = _run_parameter_table(args, path)
    report["elapsed_s"] = time.time() - start
    def write_all(folder):
        text = md
        if report.get("kind") == "frames" and figure_steps(report["steps"], Path(folder) / "steps.png"):
            text += "\n\n## What each added effect changed\n\n![steps](steps.png)\n"
        if report.get("kind") == "frames" and figure_curves(setting_curves(report), Path(folder) / "curves.png"):
            text += "\n\n## Statistics against exposure and level\n\n![curves](curves.png)\n"
        write_report(folder, report, text)
        if calibration is not None:  # the base model and its calibration report
            calibration.write_report(Path(folder) / "calibration")
            calibration.profile.save(Path(folder) / "calibration" / "base_profile.yaml")

    write_set(profile, args.out if profile is not None else None, args.report, write_all)
    if profile is not None and args.out:
        print(f"profile -> {args.out}")
    print(f"report -> {Path(args.report) / 'report.md'}")
    return 0
