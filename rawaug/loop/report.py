"""report.json and report.md of a loop run, written atomically."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..atomic import write_text_atomic


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
    """Markdown table of loop steps (one row per candidate tried): round, effect, evidence,
    error of the evidence before/after, battery mean relative error after (frame loop), kept."""
    frames = any("battery_after" in _jsonable(s) for s in steps)
    head = "| step | effect | evidence | error before | error after |" + (" battery after |" if frames else "") + " kept |"
    out = [head, "|---|---|---|---|---|" + ("---|" if frames else "") + "---|"]
    for i, s in enumerate(steps, 1):
        s = _jsonable(s)
        ev = s.get("evidence")
        if isinstance(ev, dict):
            ev = f"{ev['statistic']} z={ev['z']:.1f} ({s.get('stack', '')})"
        name = s.get("effect") or f"{s.get('relation')}: {s.get('structure')}"
        battery = f" {s['battery_after']['mean_rel_error']:.3f} |" if frames else ""
        kept = "yes" if s.get("accepted", True) else "no"
        if s.get("note") and not s.get("accepted", True):
            kept += f" ({s['note']})"
        out.append(f"| {s.get('round', i)} | {name} | {ev} | {s['error_before']:.3f} | {s['error_after']:.3f} |{battery} {kept} |")
    return "\n".join(out) + "\n"


def write_report(folder, report: dict, markdown: str) -> None:
    """Write ``report.json`` (``report``) and ``report.md`` (``markdown``) into ``folder``."""
    folder = Path(folder)
    write_text_atomic(folder / "report.json", json.dumps(_jsonable(report), indent=2))
    write_text_atomic(folder / "report.md", markdown)


def outcome_summary(result) -> str:
    """Plain sentences: what was explained physically, what was reproduced by measurement,
    what stayed unexplained."""
    lines = []
    if not result.added:
        lines.append("Nothing was added: no significant residual pointed to an effect that the model lacks "
                     "and that cut its error.")
    if result.explained_physically:
        lines.append("Explained physically: " + ", ".join(f"`{t}`" for t in result.explained_physically) + ".")
    if result.reproduced_by_measurement:
        lines.append("Reproduced by measurement (no physical effect explained these residuals): "
                     + ", ".join(f"`{t}`" for t in result.reproduced_by_measurement) + ".")
    for refit in getattr(result, "refits", []):
        if refit["kept"]:
            lines.append(f"After `{refit['after']}` was added, the base read noise was re-fitted (it had counted "
                         f"the temporal noise `{refit['after']}` now explains): sigma x "
                         + ", ".join(f"{f:.3f} ({label})" for label, f in refit["factors"].items()) + ".")
    left = result.unexplained()
    if left:
        lines.append("Unexplained (still significant at the end): "
                     + "; ".join(f"{label}: `{r.statistic}` (z {r.z:.1f}, rel. error {r.rel_error:.2f})" for label, r in left) + ".")
    else:
        lines.append("No significant residual is left.")
    return "\n\n".join(lines)


def figure_steps(steps: list[dict], path) -> bool:
    """One panel per added effect: the statistic that drove it, measured (line) against the
    model's syntheses before and after (mean +- spread). Returns False when nothing was added."""
    added = [s for s in steps if s.get("accepted")]
    if not added:
        return False
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from ..atomic import atomic_write

    fig, axes = plt.subplots(len(added), 1, figsize=(6, 1.3 * len(added) + 0.4), squeeze=False)
    for ax, step in zip(axes[:, 0], added):
        ev, af = step["evidence"], step.get("evidence_after") or {}
        ax.axvline(ev["measured"], color="k", lw=2, label="measured")
        ax.errorbar([ev["synth_mean"]], [1], xerr=[[ev["synth_std"]]], fmt="o", color="tab:red", label="model before")
        if af:
            ax.errorbar([af["synth_mean"]], [0], xerr=[[af["synth_std"]]], fmt="o", color="tab:green", label="model after")
        ax.set_yticks([0, 1], ["after", "before"])
        ax.set_ylim(-0.7, 1.7)
        ax.set_title(f"{step['effect']} ({step.get('kind', 'physical')}): {ev['statistic']} on {step['stack']}, "
                     f"error {step['error_before']:.3f} -> {step['error_after']:.3f}", fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="best")
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=90, format="png"))
    plt.close(fig)
    return True
