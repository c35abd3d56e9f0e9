"""Read each raw file once: packed, normalized arrays cached in memory and optionally on disk."""
from __future__ import annotations

import os
import hashlib
import json
from pathlib import Path

import numpy as np

from ..atomic import atomic_write

from ..io import read_frame


class FrameCache:
    """Packed normalized frames ``(4, H/2, W/2)`` float32 (0 = black, 1 = white), read with
    :func:`rawaug.io.read_frame` once per file and kept in memory.

    With ``cache_dir`` the arrays are also written there as ``.npy`` (atomically) and later
    opened memory-mapped, so a second run (or a data-loader worker) skips decoding and a
    large data set need not fit in memory. The key covers the path, size, modification time
    and read hints, so an edited file is read again.
    """

    def __init__(self, cache_dir: str | os.PathLike | None = None) -> None:
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        if self.cache_dir is not None:
            self.cache_dir.mkdir(parents=True, exist_ok=True)
        self._memory: dict[str, tuple[np.ndarray, dict]] = {}

    @staticmethod
    def _key(path: Path, hints: dict) -> str:
        st = path.stat()
        text = json.dumps([str(path.resolve()), st.st_size, st.st_mtime_ns, sorted((k, str(v)) for k, v in hints.items())])
        return hashlib.sha1(text.encode()).hexdigest()[:20]

    def get(self, path: str | os.PathLike, **hints) -> tuple[np.ndarray, dict]:
        """``(packed_normalized, meta)``; ``meta`` holds ``iso`` and ``exposure_s`` (None when unknown)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"raw frame {str(path)!r} does not exist")
        hints = {k: v for k, v in hints.items() if v is not None}
        key = self._key(path, hints)
        if key in self._memory:
            return self._memory[key]
        entry = self._from_disk(key)
        if entry is None:
            frame = read_frame(path, **hints)
            entry = (np.ascontiguousarray(frame.packed_normalized(), dtype=np.float32), {"iso": frame.iso, "exposure_s": frame.exposure_s})
            self._to_disk(key, entry)
        self._memory[key] = entry
        return entry

    def _from_disk(self, key: str):
        if self.cache_dir is None:
            return None
        arr, meta = self.cache_dir / f"{key}.npy", self.cache_dir / f"{key}.json"
        if not (arr.is_file() and meta.is_file()):
            return None
        return np.load(arr, mmap_mode="r"), json.loads(meta.read_text())

    def _to_disk(self, key: str, entry) -> None:
        if self.cache_dir is None:
            return
        array, meta = entry

        def save_array(tmp):
            with open(tmp, "wb") as f:
                np.save(f, array)

        atomic_write(self.cache_dir / f"{key}.npy", save_array)
        atomic_write(self.cache_dir / f"{key}.json", lambda tmp: Path(tmp).write_text(json.dumps(meta)))
