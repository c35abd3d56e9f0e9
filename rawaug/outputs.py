"""Outputs that never lose data: check every output location before any work, refuse one
that is (or would overwrite) an input, and write a profile and its report as one set.

A profile is validated by loading it back before it replaces anything. The report is
written into a new folder beside the target and swapped in with the profile at the end, so
on any failure (Ctrl-C included) the old profile and the old report stay as they were, and
a re-run leaves no stale figure behind. OS errors become one line naming the path.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

REPORT_FILES = ("report.json", "report.md")


class OutputError(ValueError):
    """An output location that cannot or must not be written."""


def _nearest_existing(path: Path) -> Path:
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _writable_parent(path: Path, what: str) -> None:
    parent = _nearest_existing(path.parent)
    if not parent.is_dir():
        raise OutputError(f"{what} {str(path)!r}: {str(parent)!r} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {str(path)!r}: folder {str(parent)!r} is not writable")


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def check_outputs(out=None, report=None, inputs=()) -> None:
    """Refuse, before any work, an ``out`` profile path or ``report`` folder that is or lies
    in an input (``inputs``: files and folders), that exists as the wrong kind, or that
    cannot be written; a non-empty ``report`` folder must already be a rawaug report."""
    ins = [Path(p).resolve() for p in inputs]
    if out is not None:
        o = Path(out).resolve()
        if o.is_dir():
            raise OutputError(f"--out {str(out)!r} is a folder; give a profile file path such as {str(Path(out) / 'profile.yaml')!r}")
        for i in ins:
            if o == i or (i.is_dir() and _inside(o, i) and o.exists()):
                raise OutputError(f"--out {str(out)!r} would overwrite the input {str(i)!r}")
        _writable_parent(o, "--out")
    if report is not None:
        r = Path(report).resolve()
        if r.exists() and not r.is_dir():
            raise OutputError(f"--report {str(report)!r} is a file; give a folder")
        for i in ins:
            if r == i or (i.is_dir() and _inside(r, i)) or (i.is_file() and _inside(i, r)):
                raise OutputError(f"--report {str(report)!r} would mix report files with the input {str(i)!r}; "
                                  "choose a folder outside the inputs")
        if out is not None and Path(out).resolve() == r:
            raise OutputError(f"--out and --report name the same path {str(out)!r}")
        if r.is_dir() and any(r.iterdir()) and not any((r / f).is_file() for f in REPORT_FILES):
            raise OutputError(f"--report {str(report)!r} holds files that are not a rawaug report; choose an empty or "
                              "new folder (a report folder is replaced whole)")
        _writable_parent(r, "--report")


@contextlib.contextmanager
def _os_errors(path):
    try:
        yield
    except OSError as exc:
        raise OutputError(f"cannot write {str(path)!r}: {exc.strerror or exc}") from None


def write_set(profile=None, out=None, report=None, write_report=None) -> None:
    """Write ``profile`` to ``out`` and ``write_report(folder)`` to ``report`` as one set:
    both or neither."""
    from .atomic import atomic_write, current_umask

    text = profile.to_yaml() if profile is not None and out is not None else None
    staged = None
    try:
        if report is not None and write_report is not None:
            target = Path(report)
            with _os_errors(target):
                target.parent.mkdir(parents=True, exist_ok=True)
                staged = Path(tempfile.mkdtemp(prefix=f".{target.name}.new.", dir=target.parent))
            write_report(staged)
            os.chmod(staged, 0o777 & ~current_umask())
        if text is not None:
            with _os_errors(out):
                atomic_write(out, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"),
                             before_replace=lambda: _swap_in(staged, Path(report)) if staged else None)
        elif staged is not None:
            _swap_in(staged, Path(report))
        staged = None
    finally:
        if staged is not None and staged.exists():
            shutil.rmtree(staged, ignore_errors=True)


def _swap_in(staged: Path, target: Path) -> None:
    """Replace folder ``target`` by ``staged`` (the old one removed only once the new is in place)."""
    old = None
    with _os_errors(target):
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old.", dir=target.parent))
            os.rmdir(old)
            os.rename(target, old)
        os.rename(staged, target)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
