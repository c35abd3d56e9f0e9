"""Data sources: what a data set's files are and how they pair up, as map-style datasets.

Every item is a dict of packed, normalized ``(4, h, w)`` float32 arrays (R, G1, B, G2;
0 = black, 1 = white) and labels:

* ``target``: the clean (reference) frame;
* ``input``: the noisy frame already multiplied by the low-light ratio (only for real
  noisy data: paired-real, Noise2Noise, ELD/SID evaluation, prediction); clean-only items
  have none and the model synthesizes it on the device;
* ``ratio``: the low-light factor used to label results (0 for clean items);
* ``camera``, ``name``: labels for results tables and outputs.

Files are read through a shared :class:`~rawaug.train.cache.FrameCache` (bound by the
data module), so each file is decoded once.
"""
from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from ..io import SUPPORTED_EXTENSIONS
from .cache import FrameCache

BUNDLED_SCENES = Path(__file__).resolve().parent.parent / "data" / "scenes"
BUNDLED_PHOTOS = Path(__file__).resolve().parent.parent / "data" / "photos"


def find_any_extension(path: str | os.PathLike) -> Path:
    """``path`` itself if it exists, else the one file with the same stem and any extension
    ``read_frame`` supports (so a layout's list files also work for .npy/.png stand-ins)."""
    path = Path(path)
    if path.is_file():
        return path
    found = sorted(p for p in path.parent.glob(path.stem + ".*") if p.suffix.lower() in SUPPORTED_EXTENSIONS) if path.parent.is_dir() else []
    if len(found) == 1:
        return found[0]
    if not found:
        raise FileNotFoundError(f"raw frame {str(path)!r} does not exist (nor any file {path.stem}.<ext> with a supported extension)")
    raise ValueError(f"raw frame {str(path)!r} is ambiguous: {[p.name for p in found]} share its stem")


class Source(Dataset):
    """Base class: a list of entries, each loaded into an item dict through a cache.

    Args:
        camera: label for results tables.
        repeat: each entry appears ``repeat`` times per epoch (random crops differ each time).
        window: for training with frames of different sizes or batches of big frames: a
            random ``window x window`` region (packed pixels) is cut on the CPU before the
            batch is sent to the device, where the training crop is taken inside it.
            ``None`` sends whole frames.
    """

    def __init__(self, camera: str = "", repeat: int = 1, window: int | None = None) -> None:
        super().__init__()
        if not isinstance(repeat, int) or repeat < 1:
            raise ValueError(f"repeat must be a positive integer, got {repeat!r}")
        if window is not None and (not isinstance(window, int) or window < 1):
            raise ValueError(f"window must be a positive integer (packed pixels) or None, got {window!r}")
        self.camera = str(camera)
        self.repeat = repeat
        self.window = window
        self.cache = FrameCache()
        self._entries: list | None = None

    def bind(self, cache: FrameCache) -> "Source":
        self.cache = cache
        return self

    @property
    def entries(self) -> list:
        if self._entries is None:
            self._entries = self.list_entries()
            if not self._entries:
                raise ValueError(f"{type(self).__name__} found no frames ({self.describe()})")
        return self._entries

    def list_entries(self) -> list:  # pragma: no cover - abstract
        raise NotImplementedError

    def load(self, entry) -> dict:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> str:
        return ""

    def __len__(self) -> int:
        return len(self.entries) * self.repeat

    def __getitem__(self, index: int) -> dict:
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} items")
        index %= len(self)
        item = self.load(self.entries[index % len(self.entries)])
        item.setdefault("ratio", 0.0)
        item.setdefault("camera", self.camera)
        arrays = [k for k in ("input", "target") if k in item]
        if self.window is not None:
            h, w = item[arrays[0]].shape[-2:]
            if h < self.window or w < self.window:
                raise ValueError(f"frame {item.get('name')} is {h}x{w} packed pixels, smaller than window {self.window}")
            top = int(torch.randint(0, h - self.window + 1, (1,)))
            left = int(torch.randint(0, w - self.window + 1, (1,)))
            for k in arrays:
                item[k] = item[k][:, top : top + self.window, left : left + self.window]
        for k in arrays:
            item[k] = torch.from_numpy(np.array(item[k], dtype=np.float32, copy=True))  # never share the cache
        return item


def _hints(**kw) -> dict:
    return {k: v for k, v in kw.items() if v is not None}


class CleanFolder(Source):
    """Clean raw frames in a folder (any format ``rawaug.io.read_frame`` reads).

    Args:
        root: the folder; ``None`` means the real scenes bundled with rawaug.
        pattern: glob pattern inside ``root`` (recursive patterns like ``**/*.dng`` work).
        split: when ``root`` holds a ``manifest.csv`` with a ``split`` column (as the
            bundled scenes do), only rows of this split (e.g. ``train``, ``val``); without
            a manifest, the frames in the folder ``root/<split>/``; ``None`` (or the string
            ``null``/``None`` from a command line): every frame in ``root``.
        files: explicit file names (relative to ``root``) instead of ``pattern``/``split``.
        cfa, black_level, white_level, width, height, dtype: read hints for files that do
            not store them (headerless ``.raw``, plain ``.npy``/``.png``); levels in raw codes.
    """

    def __init__(self, root: str | None = None, pattern: str = "*", split: str | None = None, files: list[str] | None = None,
                 cfa: str | None = None, black_level: float | None = None, white_level: float | None = None,
                 width: int | None = None, height: int | None = None, dtype: str | None = None,
                 camera: str = "", repeat: int = 1, window: int | None = None) -> None:
        super().__init__(camera=camera, repeat=repeat, window=window)
        self.root = Path(root) if root is not None else BUNDLED_SCENES
        self.pattern, self.files = pattern, files
        self.split = None if split is None or str(split).strip().lower() in ("none", "null", "") else str(split)
        self.hints = _hints(cfa=cfa, black_level=black_level, white_level=white_level, width=width, height=height, dtype=dtype)

    def describe(self) -> str:
        return f"root={str(self.root)!r}, pattern={self.pattern!r}, split={self.split!r}, files={self.files!r}"

    def list_entries(self) -> list[Path]:
        if not self.root.is_dir():
            raise FileNotFoundError(f"clean-frame folder {str(self.root)!r} does not exist")
        if self.files is not None:
            return [find_any_extension(self.root / f) for f in self.files]
        manifest = self.root / "manifest.csv"
        if self.split is not None and not manifest.is_file():
            if (self.root / self.split).is_dir():  # root/train/, root/val/: the split's own folder
                return sorted(p for p in (self.root / self.split).glob(self.pattern)
                              if p.is_file() and p.suffix.lower() in SUPPORTED_EXTENSIONS)
            raise ValueError(f"split={self.split!r}: {str(self.root)!r} has neither a manifest.csv with a 'split' column "
                             f"nor a folder {self.split!r}; to use every frame in it, set split to null")
        if self.split is not None:
            lines = [ln for ln in manifest.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
            rows = list(csv.DictReader(lines))
            if not rows or "split" not in rows[0] or "file" not in rows[0]:
                raise ValueError(f"{manifest}: needs 'file' and 'split' columns")
            return [find_any_extension(self.root / r["file"]) for r in rows if r["split"] == self.split]
        return sorted(p for p in self.root.glob(self.pattern) if p.is_file() and p.suffix.lower() in SUPPORTED_EXTENSIONS)

    def load(self, path: Path) -> dict:
        clean, _ = self.cache.get(path, **self.hints)
        return {"target": clean, "name": path.stem}


class PhotoFolder(Source):
    """Ordinary photos (JPEG, PNG, ... in sRGB) as clean raw training frames, by unprocessing
    (``rawaug.train.unprocess``: inverse tone curve and gamma, the camera's colour matrix
    inverted, white balance divided out, mosaicked). For users without clean raw frames.

    Args:
        root: the folder; ``None`` means the four public-domain / CC0 photos bundled with
            rawaug (``rawaug/data/photos``, licences in its README). pattern: glob inside it.
        xyz_to_cam: the camera's 3x3 XYZ -> camera matrix (``rawpy.imread(f).rgb_xyz_matrix[:3]``
            of one of its raw files); default: the Sony A7S II's, the built-in profile's camera.
        seed: the white-balance gains of item ``i`` are drawn from ``seed + i`` (the same
            every epoch).
    """

    def __init__(self, root: str | None = None, pattern: str = "*", xyz_to_cam: list | None = None, seed: int = 0,
                 camera: str = "unprocessed-photos", repeat: int = 1, window: int | None = None) -> None:
        super().__init__(camera=camera, repeat=repeat, window=window)
        self.root, self.pattern, self.seed = Path(root) if root is not None else BUNDLED_PHOTOS, pattern, int(seed)
        from .unprocess import XYZ_TO_SONY_A7S2

        self.xyz_to_cam = np.asarray(xyz_to_cam if xyz_to_cam is not None else XYZ_TO_SONY_A7S2, dtype=np.float64)
        if self.xyz_to_cam.shape != (3, 3) or not np.all(np.isfinite(self.xyz_to_cam)):
            raise ValueError(f"xyz_to_cam must be a finite 3x3 matrix, got {xyz_to_cam!r}")

    def describe(self) -> str:
        return f"root={str(self.root)!r}, pattern={self.pattern!r}"

    def list_entries(self) -> list[Path]:
        if not self.root.is_dir():
            raise FileNotFoundError(f"photo folder {str(self.root)!r} does not exist")
        return sorted(p for p in self.root.glob(self.pattern) if p.suffix.lower() in PHOTO_EXTENSIONS)

    def load(self, path: Path) -> dict:
        import imageio.v3 as iio

        from .unprocess import unprocess

        image = np.asarray(iio.imread(path))
        if image.ndim != 3 or image.shape[2] not in (3, 4):
            raise ValueError(f"{path}: an RGB photo is expected, got an image of shape {image.shape}")
        scale = float(np.iinfo(image.dtype).max) if np.issubdtype(image.dtype, np.integer) else 1.0
        index = self.entries.index(path)
        packed = unprocess(image[..., :3] / scale, np.random.default_rng(self.seed + index), self.xyz_to_cam)
        return {"target": packed, "name": path.stem}


PHOTO_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")


class NoisyFolder(Source):
    """Real noisy frames to denoise (``predict``): each is multiplied by ``ratio`` (the
    low-light factor to brighten by), no reference needed.

    Args:
        root, pattern: where the frames are.
        ratio: the brightening factor (e.g. long / short exposure of the shot you want).
        cfa, black_level, white_level, width, height, dtype: read hints as in :class:`CleanFolder`.
    """

    def __init__(self, root: str, ratio: float = 100.0, pattern: str = "*", cfa: str | None = None, black_level: float | None = None,
                 white_level: float | None = None, width: int | None = None, height: int | None = None, dtype: str | None = None,
                 camera: str = "") -> None:
        super().__init__(camera=camera)
        if not float(ratio) > 0:
            raise ValueError(f"ratio must be > 0, got {ratio!r}")
        self.root, self.pattern, self.ratio = Path(root), pattern, float(ratio)
        self.hints = _hints(cfa=cfa, black_level=black_level, white_level=white_level, width=width, height=height, dtype=dtype)

    def describe(self) -> str:
        return f"root={str(self.root)!r}, pattern={self.pattern!r}"

    def list_entries(self) -> list[Path]:
        if not self.root.is_dir():
            raise FileNotFoundError(f"noisy-frame folder {str(self.root)!r} does not exist")
        return sorted(p for p in self.root.glob(self.pattern) if p.is_file() and p.suffix.lower() in SUPPORTED_EXTENSIONS)

    def load(self, path: Path) -> dict:
        noisy, _ = self.cache.get(path, **self.hints)
        return {"input": noisy * np.float32(self.ratio), "ratio": self.ratio, "name": path.stem}
