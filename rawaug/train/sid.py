"""The See-in-the-Dark (SID) Sony layout (Chen et al., CVPR 2018).

Layout under ``root``::

    Sony/short/00001_00_0.04s.ARW     short (noisy) exposures: <scene>_<frame>_<exposure>s
    Sony/long/00001_00_10s.ARW        long (reference) exposures
    Sony_train_list.txt, Sony_val_list.txt, Sony_test_list.txt

with list lines ``./Sony/short/00001_00_0.04s.ARW ./Sony/long/00001_00_10s.ARW ISO200 F8``.
The low-light ratio is long exposure / short exposure from the file names, capped at 300
as in the SID code (0.033 s against 10 s gives 300). Listed files may carry any extension
``read_frame`` supports (``.npy``/``.png`` stand-ins of the same stem are found).
"""
from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import numpy as np

from .sources import Source, find_any_extension

MODES = ("clean", "paired", "noise2noise")


def exposure_from_name(path: str | Path) -> float:
    """``00001_00_0.04s.ARW`` -> 0.04 (seconds)."""
    stem = Path(path).stem
    last = stem.split("_")[-1]
    if not last.endswith("s"):
        raise ValueError(f"SID file name {Path(path).name!r} does not end in '_<exposure>s'; expected e.g. 00001_00_0.04s.ARW")
    try:
        value = float(last[:-1])
    except ValueError:
        raise ValueError(f"SID file name {Path(path).name!r}: exposure {last!r} is not a number of seconds") from None
    if not value > 0:
        raise ValueError(f"SID file name {Path(path).name!r}: exposure must be > 0 s, got {value}")
    return value


def scene_from_name(path: str | Path) -> int:
    """``00001_00_0.04s.ARW`` -> 1."""
    head = Path(path).stem.split("_")[0]
    if not head.isdigit():
        raise ValueError(f"SID file name {Path(path).name!r} does not start with a numeric scene id")
    return int(head)


def read_sid_list(list_file: str | Path, root: str | Path, max_ratio: float = 300.0) -> list[dict]:
    """Parse a SID list file into ``{short, long, ratio, scene, iso}`` dicts (paths under ``root``)."""
    list_file, root = Path(list_file), Path(root)
    if not list_file.is_file():
        raise FileNotFoundError(f"SID list file {str(list_file)!r} does not exist: get the SID Sony set (Chen et al., "
                                "CVPR 2018, 'Learning to See in the Dark', about 25 GB) and set the source's root to the "
                                "folder that holds Sony/ and Sony_*_list.txt")
    pairs = []
    for n, line in enumerate(list_file.read_text().splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) < 2:
            raise ValueError(f"{list_file.name} line {n}: expected '<short> <long> [ISO<n>] [F<n>]', got {line!r}")
        short, long = (root / p.removeprefix("./") for p in parts[:2])
        iso = next((float(p[3:]) for p in parts[2:] if p.upper().startswith("ISO") and p[3:].replace(".", "", 1).isdigit()), None)
        ratio = min(exposure_from_name(long) / exposure_from_name(short), float(max_ratio))
        pairs.append({"short": short, "long": long, "ratio": ratio, "scene": scene_from_name(short), "iso": iso})
    if not pairs:
        raise ValueError(f"SID list file {str(list_file)!r} lists no pairs")
    return pairs


class SIDSony(Source):
    """SID Sony frames from one list file.

    Args:
        root: the folder holding ``Sony/`` and the list files.
        list_file: e.g. ``Sony_train_list.txt`` (relative to ``root``) or an absolute path.
        mode: ``clean``: the distinct long exposures only, for synthetic-noise training;
            ``paired``: (short x ratio, long) real pairs, for paired-real training and for
            evaluation; ``noise2noise``: two short frames of one scene at one exposure time,
            both multiplied by their ratio, as (input, target).
        max_ratio: cap of the long/short ratio (300 in SID).
        scenes: keep only these scene ids (e.g. the indoor scenes of the test set).
    """

    def __init__(self, root: str, list_file: str = "Sony_train_list.txt", mode: str = "clean", max_ratio: float = 300.0,
                 scenes: list[int] | None = None, camera: str = "SonyA7S2", repeat: int = 1, window: int | None = None) -> None:
        super().__init__(camera=camera, repeat=repeat, window=window)
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.root = Path(root)
        self.list_file = Path(list_file) if Path(list_file).is_absolute() else self.root / list_file
        self.mode, self.max_ratio = mode, float(max_ratio)
        self.scenes = None if scenes is None else {int(s) for s in scenes}

    def describe(self) -> str:
        return f"list_file={str(self.list_file)!r}, mode={self.mode!r}, scenes={self.scenes}"

    def list_entries(self) -> list:
        pairs = [p for p in read_sid_list(self.list_file, self.root, self.max_ratio) if self.scenes is None or p["scene"] in self.scenes]
        if self.mode == "clean":
            return list(OrderedDict((p["long"], p) for p in pairs).values())
        if self.mode == "paired":
            return pairs
        groups: OrderedDict[tuple, list] = OrderedDict()
        for p in pairs:
            groups.setdefault((p["scene"], exposure_from_name(p["short"])), []).append(p)
        entries = []
        for members in groups.values():
            members = list(OrderedDict((m["short"], m) for m in members).values())
            if len(members) >= 2:
                entries += [(members[i], members[(i + 1) % len(members)]) for i in range(len(members))]
        return entries

    def _normalized(self, path: Path) -> np.ndarray:
        return self.cache.get(find_any_extension(path))[0]

    def load(self, entry) -> dict:
        if self.mode == "noise2noise":
            a, b = entry
            return {"input": self._normalized(a["short"]) * np.float32(a["ratio"]), "target": self._normalized(b["short"]) * np.float32(b["ratio"]),
                    "ratio": a["ratio"], "name": f"{a['short'].stem}~{b['short'].stem}"}
        target = self._normalized(entry["long"])
        if self.mode == "clean":
            return {"target": target, "name": entry["long"].stem}
        return {"input": self._normalized(entry["short"]) * np.float32(entry["ratio"]), "target": target,
                "ratio": entry["ratio"], "name": entry["short"].stem}
