"""report.json and report.md of a loop run, written atomically."""
from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np


def _jsonable(v):
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, (np.floating, float)):
        return float(v) if math.isfinite(float(v)) else str(float(v))
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    if hasattr(v, "to_dict"):
        return _jsonable(v.to_dict())
    return v


def _atomic_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def residual_table(rows, title="") -> str:
    """Markdown table of residual dicts (statistic, measured, synth mean, z, rel_error)."""
    out = [f"**{title}**", ""] if title else []
    out += ["| statistic | measured | model | z | rel. error | significant | points to |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        r = _jsonable(r)
        to = ", ".join(r.get("effects") or []) or r.get("base", "") or "-"
        out.append(f"| {r['statistic']} | {r['measured']:.4g} | {r['synth_mean']:.4g} | {r['z']:.1f} | "
                   f"{r['rel_error']:.3f} | {'yes' if r['significant'] else ''} | {to} |")
    return "\n".join(out) + "\n"


def steps_table(steps) -> str:
    """Markdown table of loop steps: effect, evidence, error before/after, kept."""
    out = ["| step | added | evidence | error before | error after | kept |", "|---|---|---|---|---|---|"]
    for i, s in enumerate(steps, 1):
        s = _jsonable(s)
        ev = s.get("evidence")
        if isinstance(ev, dict):
            ev = f"{ev['statistic']} z={ev['z']:.1f} ({s.get('stack', '')})"
        name = s.get("effect") or f"{s.get('relation')}: {s.get('structure')}"
        out.append(f"| {i} | {name} | {ev} | {s['error_before']:.3f} | {s['error_after']:.3f} | "
                   f"{'yes' if s.get('accepted', True) else 'no'} |")
    return "\n".join(out) + "\n"


def write_report(folder, report: dict, markdown: str) -> None:
    """Write ``report.json`` (``report``) and ``report.md`` (``markdown``) into ``folder``."""
    folder = Path(folder)
    _atomic_text(folder / "report.json", json.dumps(_jsonable(report), indent=2))
    _atomic_text(folder / "report.md", markdown)
