"""CSV manifest of a calibration frame set, grouping by ISO and flat-pair finding.

Manifest format (CSV with a header row; ``#`` lines are comments; paths relative to the
manifest's folder)::

    path,kind,iso,exposure_s,width,height,dtype,cfa,black_level,white_level,light
    bias_0001.dng,bias,1600,0.000125,,,,,,,
    flat_a.raw,flat,1600,0.01,4000,3000,uint16,RGGB,512,16383,0.25

Required columns: ``path``, ``kind`` (``bias`` | ``flat`` | ``dark``), ``iso``; ``exposure_s``
is required for flats (pairs are matched on it). The optional columns give what the file
cannot tell: ``width, height, dtype`` of a headerless file, ``cfa``, ``black_level`` (one
number or 4 separated by spaces or ``;`` in packed R, G1, B, G2 order), ``white_level``
(raw codes). An empty cell means "take it from the file". ``light`` (optional, flats only)
is the relative light level of a flat (any unit: a source current, an ND filter's
transmission): flat pairs are matched on it too, and flats of one exposure time under known
lights form a series that shows the response's linearity (dose = exposure x light).
"""
from __future__ import annotations

import csv
import math
import warnings
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from .frame import Frame
from .readers import read_frame

KINDS = ("bias", "flat", "dark")
COLUMNS = ("path", "kind", "iso", "exposure_s", "width", "height", "dtype", "cfa", "black_level", "white_level", "light")
REQUIRED = ("path", "kind", "iso")


@dataclass
class ManifestEntry:
    """One manifest row: a frame file, its kind and settings, and reading hints."""

    path: str
    kind: str
    iso: float
    exposure_s: float | None = None
    width: int | None = None
    height: int | None = None
    dtype: str | None = None
    cfa: str | None = None
    black_level: float | tuple | None = None
    white_level: float | None = None
    light: float | None = None  # a flat's relative light level (any unit)

    @property
    def hints(self) -> dict:
        """Keyword arguments for :func:`read_frame` (only the given ones)."""
        keys = ("width", "height", "dtype", "cfa", "black_level", "white_level", "iso", "exposure_s")
        return {k: getattr(self, k) for k in keys if getattr(self, k) is not None}

    def read(self) -> Frame:
        """Read the frame, with the manifest's hints overriding the file's metadata."""
        return read_frame(self.path, **self.hints)


def _number(text, name, where, positive=True, integer=False):
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{where}: column {name!r} must be a number, got {text!r}") from None
    if not math.isfinite(value) or (positive and value <= 0):
        raise ValueError(f"{where}: column {name!r} must be a positive finite number, got {text!r}")
    if integer:
        if value != int(value):
            raise ValueError(f"{where}: column {name!r} must be an integer, got {text!r}")
        return int(value)
    return value


def _black(text, where):
    parts = [p for p in text.replace(";", " ").replace(",", " ").split() if p]
    values = [_number(p, "black_level", where, positive=False) for p in parts]
    if len(values) == 1:
        return values[0]
    if len(values) == 4:
        return tuple(values)
    raise ValueError(f"{where}: black_level must be one number or 4 (R G1 B G2), got {text!r}")


def read_manifest(path) -> list[ManifestEntry]:
    """Parse a CSV manifest (format in the module docstring) into entries.

    Raises ValueError naming the row and column of any bad value; FileNotFoundError when the
    manifest is missing. Frame files are not opened here (see :meth:`ManifestEntry.read`).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"manifest {str(path)!r} does not exist")
    lines = [ln for ln in path.read_text(encoding="utf-8-sig").splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise ValueError(f"manifest {str(path)!r} is empty; expected a header row {','.join(COLUMNS)}")
    reader = csv.DictReader(lines, skipinitialspace=True)
    header = [h.strip().lower() for h in (reader.fieldnames or [])]
    unknown = [h for h in header if h not in COLUMNS]
    missing = [c for c in REQUIRED if c not in header]
    if unknown or missing:
        raise ValueError(f"manifest {str(path)!r}: header must use columns {COLUMNS} (required {REQUIRED}); "
                         f"unknown {unknown}, missing {missing}")
    entries = []
    for i, row in enumerate(reader, start=2):
        row = {k.strip().lower(): (v or "").strip() for k, v in row.items() if k is not None}
        where = f"manifest {path.name} row {i}"
        if not row.get("path"):
            raise ValueError(f"{where}: empty 'path'")
        kind = row["kind"].lower()
        if kind not in KINDS:
            raise ValueError(f"{where}: kind must be one of {KINDS}, got {row['kind']!r}")
        if not row.get("iso"):
            raise ValueError(f"{where}: missing ISO; every frame needs its ISO (frames are grouped by it)")
        entry = ManifestEntry(path=str((path.parent / row["path"]).resolve()) if not Path(row["path"]).is_absolute() else row["path"],
                              kind=kind, iso=_number(row["iso"], "iso", where))
        if row.get("exposure_s"):
            entry.exposure_s = _number(row["exposure_s"], "exposure_s", where)
        elif kind == "flat":
            raise ValueError(f"{where}: a flat needs exposure_s (flat pairs are matched on ISO and exposure)")
        for name in ("width", "height"):
            if row.get(name):
                setattr(entry, name, _number(row[name], name, where, integer=True))
        if row.get("dtype"):
            entry.dtype = row["dtype"]
        if row.get("cfa"):
            entry.cfa = row["cfa"].upper()
        if row.get("black_level"):
            entry.black_level = _black(row["black_level"], where)
        if row.get("white_level"):
            entry.white_level = _number(row["white_level"], "white_level", where)
        if row.get("light"):
            if kind != "flat":
                raise ValueError(f"{where}: 'light' is a flat's relative light level; a {kind} frame has none, got {row['light']!r}")
            entry.light = _number(row["light"], "light", where)
        entries.append(entry)
    if not entries:
        raise ValueError(f"manifest {str(path)!r} lists no frames")
    return entries


def group_by_iso(items) -> dict[float, list]:
    """Entries (or frames; anything with ``.iso``) grouped by ISO, ISOs ascending.

    Raises ValueError when an item has no ISO."""
    groups = defaultdict(list)
    for item in items:
        if item.iso is None:
            raise ValueError(f"frame {getattr(item, 'path', item)!r} has no ISO; give it in the manifest or EXIF")
        groups[float(item.iso)].append(item)
    return dict(sorted(groups.items()))


def find_flat_pairs(flats) -> list[tuple]:
    """Pair flats taken at equal settings (same ISO, exposure time and ``light`` where
    given), in listed order.

    A setting with an odd number of flats leaves its last one unpaired (with a warning);
    items need ``.iso`` and ``.exposure_s`` (``.light`` optional).
    """
    groups = defaultdict(list)
    for item in flats:
        groups[(item.iso, item.exposure_s, getattr(item, "light", None))].append(item)
    pairs = []
    for (iso, exposure, light), members in groups.items():
        if len(members) % 2:
            at = f", light {light:g}" if light is not None else ""
            warnings.warn(f"flat at ISO {iso}, exposure {exposure} s{at}: {len(members)} frames, the last "
                          f"({getattr(members[-1], 'path', '?')}) has no partner and is not used", stacklevel=2)
        pairs += [(members[i], members[i + 1]) for i in range(0, len(members) - 1, 2)]
    return pairs
