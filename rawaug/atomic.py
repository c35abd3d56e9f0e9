"""Atomic file writes: a temporary file in the target's folder, then ``os.replace``, so a
reader never sees a half-written file and a failed write leaves the old one intact. The new
file gets the old file's permissions, or the umask's for a new file (not mkstemp's 0600)."""
from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path


def current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _mode_for(path: Path) -> int:
    if path.exists():
        return stat.S_IMODE(path.stat().st_mode)
    return 0o666 & ~current_umask()


def atomic_write(path, write, before_replace=None) -> None:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then move it into place
    (after ``before_replace()``, when given: the last step that may still fail)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, _mode_for(path))
        if before_replace is not None:
            before_replace()
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text_atomic(path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))
