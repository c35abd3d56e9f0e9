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
        over = (r.get("pooled") or {}).get("over") or []
        into = (r.get("pooled") or {}).get("into")
        name = r["statistic"] + (f" (pooled over {len(over)} stacks)" if len(over) > 1 else f" (judged pooled, with {into})" if into else "")
        out.append(f"| {name} | {r['measured']:.4g} | {r['synth_mean']:.4g} | {r['z']:.1f} | "
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
        battery = (f" {s['battery_after']['mean_rel_error']:.3f} |" if s.get("battery_after") else " - |") if frames else ""
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
        if not refit["kept"]:
            continue
        what = refit.get("what") or "read noise"
        if refit.get("given"):  # an effect the calibrated profile brought
            lines.append(f"With `{refit['after']}` from calibration (the frames' lowest code), the base read noise was "
                         "re-fitted on the syntheses: "
                         + ", ".join([f"sigma x {f:.3f} ({label})" for label, f in (refit.get("factors") or {}).items()]
                                     + [f"lambda {lam:.3f} ({label})" for lambdas in refit.get("lambdas", [])
                                        for label, lam in lambdas.items()]) + ".")
            continue
        if refit.get("factors") and min(refit["factors"].values()) > 1.0:
            lines.append(f"After `{refit['after']}` was added, the base {what} was given back (`{refit['after']}` had "
                         f"taken the variance of the rows away): sigma x "
                         + ", ".join(f"{f:.3f} ({label})" for label, f in refit["factors"].items()) + ".")
        elif refit.get("factors"):
            lines.append(f"After `{refit['after']}` was added, the base {what} was re-fitted (it had counted "
                         f"the temporal noise `{refit['after']}` now explains): sigma x "
                         + ", ".join(f"{f:.3f} ({label})" for label, f in refit["factors"].items()) + ".")
        for lambdas in refit.get("lambdas", []):
            lines.append(f"After `{refit['after']}` was added, the model's read-noise tail exceeded the measured one: "
                         "the base read noise's Tukey lambda was re-fitted, its variance kept: "
                         + ", ".join(f"{lam:.3f} ({label})" for label, lam in lambdas.items()) + ".")
    for again in getattr(result, "resized", []):
        lines.append(f"After the base was re-fitted with `{again['effect']}`, its size was found again through the clip "
                     f"in the re-fitted base (the share the clip hides depends on the noise around it): battery "
                     f"{again['battery_before']['mean_rel_error']:.3f} -> {again['battery_after']['mean_rel_error']:.3f}, "
                     + ("kept." if again["kept"] else "not kept (the first size stays)."))
    for gone in getattr(result, "removed", []):
        lines.append(f"`{gone['effect']}` was added, then removed: beside " + ", ".join(f"`{t}`" for t in gone["beside"])
                     + (" the model overshot its statistic with it, and the battery is no worse without it (battery "
                        if gone.get("why") == "overshoots" else " no residual is significant without it (battery ")
                     + f"{gone['battery_before']['mean_rel_error']:.3f} -> {gone['battery_after']['mean_rel_error']:.3f}).")
    chance = getattr(result, "unconfirmed", [])
    if chance:
        lines.append("Not confirmed on a larger sample of syntheses (a chance deviation, not acted on): "
                     + "; ".join(f"{u['stack']}: `{u['statistic']}` (z {u['z']:.1f} on the diagnosis, {u['z_confirm']:.1f} on "
                                 f"{u['n_synth_confirm']} syntheses)" for u in chance) + ".")
    left = result.unexplained()
    if left:
        lines.append("Unexplained (still significant at the end): "
                     + "; ".join(f"{label}: `{r.statistic}` (z {r.z:.1f}, rel. error {r.rel_error:.2f})" for label, r in left) + ".")
    else:
        lines.append("No significant residual is left.")
    return "\n\n".join(lines)


def figure_steps(steps: list[dict], path) -> bool:
    """One row per added effect: the statistic that drove it, measured (line) against the
    model's syntheses before and after (mean +- spread), and beside it the curve behind that
    statistic (``rawaug.loop.signatures``: a spectrum, a histogram, a profile), measured
    against the model before and after. Returns False when nothing was added."""
    added = [s for s in steps if s.get("accepted")]
    if not added:
        return False
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from ..atomic import atomic_write

    fig, axes = plt.subplots(len(added), 2, figsize=(11, 2.4 * len(added) + 0.4), squeeze=False,
                             gridspec_kw={"width_ratios": [1, 1.2]})
    for ax, step in zip(axes[:, 1], added):
        _signature_panel(ax, step.get("signature") or {})
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


def _signature_panel(ax, sig: dict) -> None:
    if not sig:
        ax.axis("off")
        return
    x = np.asarray(sig["x"], dtype=np.float64)
    for key, colour, style in (("before", "tab:red", "--"), ("after", "tab:green", "--")):
        mean, std = np.asarray(sig[key], dtype=np.float64), np.asarray(sig[key + "_std"], dtype=np.float64)
        ax.plot(x, mean, style, color=colour, lw=1.2, label=f"model {key}")
        ax.fill_between(x, mean - std, mean + std, color=colour, alpha=0.2, lw=0)
    ax.plot(x, sig["measured"], "k-", lw=1.5, label="measured")
    if sig.get("log_y"):
        ax.set_yscale("log")
    if sig.get("log_x"):
        from matplotlib.ticker import NullFormatter

        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(sig["xlabel"], fontsize=7)
    ax.set_ylabel(sig["ylabel"], fontsize=7)
    unit = "decades" if sig.get("log_y") else "mean abs."
    ax.set_title(f"behind {sig['statistic']}: model off by {sig['distance_before']:.3g} -> {sig['distance_after']:.3g} "
                 f"({unit})", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=6, loc="best")


# ----------------------------------------------------------------------------- curves across settings
CURVE_STATISTICS = {"exposure_s": ("mean_dn", "temporal_std", "fixed_std", "fixed_pixel_var"),  # dark signal, its shot noise, DSNU
                    "level_dn": ("temporal_std", "fixed_std", "flat_fixed_rel")}  # photon transfer, PRNU


def _own(r: dict) -> dict:
    """A residual's figures on its own stack: a pooled statistic's joint residual (carried by
    the first of its stacks) replaced by that stack's own figures, its joint significance kept."""
    own = (r.get("pooled") or {}).get("stack")
    return {**r, **{k: own[k] for k in ("measured", "synth_mean", "synth_std")}} if own else r


def setting_curves(report: dict) -> list[dict]:
    """Each statistic against exposure (the bias and dark stacks of one ISO) and against
    level (its bias and flat stacks; bias at level 0): measured, and the model's syntheses
    before and after the loop (mean, spread, significance), one point per stack.

    Shown per group: the statistics of ``CURVE_STATISTICS`` and every one significant at
    one of the group's stacks before or after, where at least two of its stacks have it.
    Needs ``report["stacks"]`` (label -> kind, iso, exposure_s, level_dn)."""
    stacks = report.get("stacks") or {}
    initial, final = report.get("initial") or {}, report.get("final") or {}
    groups = []
    for iso in sorted({s["iso"] for s in stacks.values()}):
        for axis, kind in (("exposure_s", "dark"), ("level_dn", "flat")):
            members = [(label, s) for label, s in stacks.items() if s["iso"] == iso and s["kind"] in ("bias", kind)]
            if not any(s["kind"] == kind for _, s in members) or len(members) < 2:
                continue
            x_of = {label: float(s.get(axis) or 0.0) for label, s in members}  # bias: its exposure, level 0
            before = {label: {r["statistic"]: _own(r) for r in map(_jsonable, initial.get(label, []))} for label, _ in members}
            after = {label: {r["statistic"]: _own(r) for r in map(_jsonable, final.get(label, []))} for label, _ in members}
            flagged = {name for d in (before, after) for res in d.values() for name, r in res.items() if r["significant"]}
            names = [n for n in dict.fromkeys(CURVE_STATISTICS[axis] + tuple(sorted(flagged)))
                     if sum(n in before[label] and n in after[label] for label, _ in members) >= 2]
            for name in names:
                points = []
                for label, _ in sorted(members, key=lambda m: x_of[m[0]]):
                    if name in before[label] and name in after[label]:
                        b, a = before[label][name], after[label][name]
                        points.append({"x": float(x_of[label]), "stack": label, "measured": b["measured"],
                                       "before": (b["synth_mean"], b["synth_std"], bool(b["significant"])),
                                       "after": (a["synth_mean"], a["synth_std"], bool(a["significant"]))})
                groups.append({"iso": iso, "axis": axis, "statistic": name, "points": points})
    return groups


def curves_table(groups: list[dict]) -> str:
    """Markdown: one table per ISO and axis, a row per statistic and setting (* significant)."""
    out = []
    for (iso, axis) in dict.fromkeys((g["iso"], g["axis"]) for g in groups):
        what = "exposure (s)" if axis == "exposure_s" else "level (DN above black)"
        out += [f"**ISO {iso:g}: statistics against {what}** (model: mean ± spread of its syntheses; * significant)", "",
                f"| statistic | {what} | stack | measured | model before | model after |", "|---|---|---|---|---|---|"]
        for g in (g for g in groups if (g["iso"], g["axis"]) == (iso, axis)):
            for p in g["points"]:
                fmt = lambda m: f"{m[0]:.4g} ± {m[1]:.2g}{' *' if m[2] else ''}"  # noqa: E731
                out.append(f"| {g['statistic']} | {p['x']:.4g} | {p['stack']} | {p['measured']:.4g} | {fmt(p['before'])} | {fmt(p['after'])} |")
        out.append("")
    return "\n".join(out)


def figure_curves(groups: list[dict], path, max_panels: int = 24) -> bool:
    """One panel per statistic and group (the first ``max_panels``; the table in report.md
    holds them all): measured (black) against the model before (red) and after (green),
    mean +- spread, along exposure or level. False when there is none."""
    groups = [g for g in groups if len(g["points"]) >= 2][:max_panels]
    if not groups:
        return False
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from ..atomic import atomic_write

    cols = min(3, len(groups))
    rows = -(-len(groups) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.6 * rows), squeeze=False)
    for ax in axes.ravel()[len(groups):]:
        ax.axis("off")
    for ax, g in zip(axes.ravel(), groups):
        x = np.array([p["x"] for p in g["points"]])
        ax.plot(x, [p["measured"] for p in g["points"]], "ko-", lw=2, label="measured")
        for key, colour in (("before", "tab:red"), ("after", "tab:green")):
            mean = np.array([p[key][0] for p in g["points"]])
            std = np.array([p[key][1] for p in g["points"]])
            ax.errorbar(x, mean, yerr=std, fmt="s--", color=colour, ms=4, capsize=2, label=f"model {key}")
        ax.set_xlabel("exposure (s)" if g["axis"] == "exposure_s" else "level (DN)", fontsize=7)
        ax.set_title(f"ISO {g['iso']:g}: {g['statistic']}", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=6, loc="best")
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=90, format="png"))
    plt.close(fig)
    return True
