"""Calibration report: ``report.json`` (every number), figures like the paper's, ``report.md``.

Figures (matplotlib, Agg backend): PPCC against lambda; probability plots, Gaussian against
Tukey lambda, with R^2; the centralized FFT of a bias frame; photon transfer; the joint
log-linear fits with the band sampling draws from (+-1 and +-2 residual sigma); lambda and
colour bias against K. Every file is written atomically.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..atomic import atomic_write


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items() if not str(k).startswith("_")}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(float(value)) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _save_figure(fig, path: Path):
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=90, format="png", bbox_inches="tight"))


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def figure_ppcc(params, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for p in params:
        grid = np.asarray(p.extra.get("ppcc_grid", []))
        if grid.size:
            ax.plot(grid[:, 0], grid[:, 1], marker=".", label=f"ISO {p.iso:g} (lambda={p.lam:.3f})")
    ax.set_xlabel("Tukey lambda shape")
    ax.set_ylabel("PPCC")
    ax.set_title("Probability plot correlation coefficient")
    ax.legend(fontsize=7)
    _save_figure(fig, path)
    plt.close(fig)


def figure_probplots(p, path):
    """Gaussian and Tukey-lambda probability plots of one ISO's read-noise residual."""
    from scipy import stats

    plt = _plt()
    x = np.sort(np.asarray(p.extra.get("_residual_sample", [])))
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.5))
    if x.size:
        for ax, dist, args, name, r2 in ((axes[0], stats.norm, (), "Gaussian", p.extra.get("r2_gauss")),
                                         (axes[1], stats.tukeylambda, (p.lam,), f"Tukey lambda ({p.lam:.3f})",
                                          p.extra.get("r2_tukey"))):
            (osm, osr), (slope, icpt, _) = stats.probplot(x, sparams=args, dist=dist)
            ax.plot(osm, osr, ".", ms=2)
            ax.plot(osm, slope * osm + icpt, "r-", lw=1)
            ax.set_title(f"{name}: R^2 = {r2:.5f}" if r2 is not None else name, fontsize=9)
            ax.set_xlabel("theoretical quantiles")
            ax.set_ylabel("ordered residual, DN")
    fig.suptitle(f"ISO {p.iso:g} read noise")
    _save_figure(fig, path)
    plt.close(fig)


def figure_fft(spectrum, title, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(4.5, 4))
    im = ax.imshow(spectrum, cmap="inferno")
    fig.colorbar(im, ax=ax, label="log10 power")
    ax.set_title(title, fontsize=9)
    ax.set_axis_off()
    _save_figure(fig, path)
    plt.close(fig)


def figure_ptc(params, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for p in params:
        ptc = p.extra.get("_ptc")
        if ptc is None:
            continue
        m, v = ptc
        sc = ax.plot(m, v, ".", ms=2, alpha=0.4)
        xs = np.linspace(0.0, float(np.max(m)), 64)  # a line, or a parabola where the curve bends
        q = p.extra.get("ptc_curvature_per_dn", 0.0)
        ax.plot(xs, p.k * xs * (1 + q * xs) + p.extra.get("ptc_intercept_dn2", 0.0), "-", color=sc[0].get_color(),
                label=f"ISO {p.iso:g}: K = {p.k:.4g} DN/e-")
    ax.set_xlabel("tile mean, DN")
    ax.set_ylabel("tile variance, DN^2")
    ax.set_title("Photon transfer (flat pairs)")
    ax.legend(fontsize=7)
    _save_figure(fig, path)
    plt.close(fig)


def figure_joint(profile, params, path):
    """sigma_TL, sigma_r, sigma_G against K with the fitted line and the sampled band."""
    plt = _plt()
    k = np.array([p.k for p in params])
    series = [("sigma_TL", [p.sigma_tl or np.nan for p in params], profile.tukey_scale),
              ("sigma_r", [p.sigma_r or np.nan for p in params], profile.row_scale),
              ("sigma_G", [p.sigma_g if p.sigma_g else np.nan for p in params], profile.gaussian_scale)]
    series = [s for s in series if s[2] is not None]  # a Poisson-Gaussian table has sigma_G alone
    fig, axes = plt.subplots(1, len(series), figsize=(4 * len(series), 3.5), squeeze=False)
    axes = axes[0]
    grid = np.linspace(np.log(k.min()) - 0.2, np.log(k.max()) + 0.2, 100)
    for ax, (name, sig, rel) in zip(axes, series):
        line = rel.slope * grid + rel.intercept
        for n_sigma, alpha in ((2, 0.15), (1, 0.3)):
            ax.fill_between(grid, line - n_sigma * rel.residual_std, line + n_sigma * rel.residual_std, alpha=alpha,
                            color="tab:blue", lw=0)
        ax.plot(grid, line, "b-", lw=1)
        sig = np.asarray(sig, dtype=float)
        ok = np.isfinite(sig) & (sig > 0)
        ax.plot(np.log(k[ok]), np.log(sig[ok]), "ro", ms=4)
        ax.set_xlabel("log K")
        ax.set_ylabel(f"log {name}")
        ax.set_title(f"{name}: slope {rel.slope:.3f}, resid {rel.residual_std:.3f}", fontsize=9)
    _save_figure(fig, path)
    plt.close(fig)


def figure_tables(profile, path):
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
    if profile.tukey_shape is not None:
        axes[0].semilogx(profile.tukey_shape.k, profile.tukey_shape.values, "o")
    axes[0].set_xlabel("K, DN/e-")
    axes[0].set_ylabel("Tukey lambda")
    bias = np.asarray(profile.color_bias.values)
    for j, name in enumerate(("R", "G1", "B", "G2")):
        axes[1].semilogx(profile.color_bias.k, bias[:, j], "o-", ms=3, label=name)
    axes[1].set_xlabel("K, DN/e-")
    axes[1].set_ylabel("colour bias, DN")
    axes[1].legend(fontsize=7)
    _save_figure(fig, path)
    plt.close(fig)


def write_report(report_dir, profile, params, *, inputs=None, warnings_list=(), spectrum=None, spectrum_title="",
                 timing=None) -> Path:
    """Write report.json, the figures and report.md into ``report_dir``; returns the .md path."""
    out = Path(report_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures = {}
    if any(p.extra.get("ppcc_grid") for p in params):
        figure_ppcc(params, out / "ppcc.png")
        figures["PPCC against Tukey lambda"] = "ppcc.png"
    for p in params:
        if "_residual_sample" in p.extra:
            name = f"probplot_iso{p.iso:g}.png"
            figure_probplots(p, out / name)
            figures[f"Probability plots, ISO {p.iso:g}"] = name
    if spectrum is not None:
        figure_fft(spectrum, spectrum_title, out / "bias_fft.png")
        figures["Centralized FFT of a bias frame"] = "bias_fft.png"
    if any("_ptc" in p.extra for p in params):
        figure_ptc(params, out / "photon_transfer.png")
        figures["Photon transfer"] = "photon_transfer.png"
    figure_joint(profile, params, out / "joint_fits.png")
    figures["Joint fits (band: +-1 and +-2 residual sigma, what sampling draws from)"] = "joint_fits.png"
    figure_tables(profile, out / "lambda_color_bias.png")
    figures["Lambda and colour bias against K"] = "lambda_color_bias.png"
    data = {
        "inputs": inputs or {},
        "profile": profile.to_dict(),
        "per_iso": [p.to_dict() for p in params],
        "warnings": list(warnings_list),
        "timing_s": timing or {},
        "figures": figures,
    }
    text = json.dumps(_jsonable(data), indent=2)
    atomic_write(out / "report.json", lambda tmp: Path(tmp).write_text(text))
    md = _markdown(profile, params, figures, warnings_list)
    atomic_write(out / "report.md", lambda tmp: Path(tmp).write_text(md))
    return out / "report.md"


def _markdown(profile, params, figures, warnings_list):
    lines = [f"# Noise calibration: {profile.camera}", "", f"Source: {profile.source}", "",
             f"K range {profile.k_min:.4g} .. {profile.k_max:.4g} DN/e-; sensor black {profile.black_level:g}, "
             f"white {profile.white_level:g}, {profile.bit_depth} bit, {profile.cfa}; quantization step "
             f"{profile.quantization_step_dn:g} DN.", "", "## Per-ISO parameters (DN)", "",
             "| ISO | K (DN/e-) | sigma_TL | lambda | sigma_r | sigma_G | R^2 Tukey | R^2 Gauss |",
             "|---|---|---|---|---|---|---|---|"]
    for p in params:
        r2t, r2g = p.extra.get("r2_tukey"), p.extra.get("r2_gauss")
        fmt = lambda v: f"{v:.5f}" if isinstance(v, (int, float)) else "-"  # noqa: E731
        sg = f"{p.sigma_g:.4g}" if p.sigma_g else "-"
        num = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
        lines.append(f"| {p.iso:g} | {p.k:.4g} | {num(p.sigma_tl, '.4g')} | {num(p.lam, '.3f')} | {num(p.sigma_r, '.4g')} "
                     f"| {sg} | {fmt(r2t)} | {fmt(r2g)} |")
    clipped = [(p.iso, p.extra["black_floor"]) for p in params if p.extra.get("black_floor")]
    if clipped:
        lines += ["", "Bias frames clipped from below (no value under a floor): the read noise and the colour bias "
                  "were fitted to the values above the clip (censored probability plot), the row noise scaled up by "
                  "the share of the noise the clip hides. A clip at the file's lowest code (code 0) is in the profile "
                  "as `Clip` (the recording format's floor, like the white level); a clip above it is the loop's to "
                  "find (`Clip`).", ""]
        lines += [f"- ISO {iso:g}: floor {c['floor_dn']:g} DN, {100 * c['fraction']:.1f} % of the noise below it" for iso, c in clipped]
    lines += ["", "## Joint model: log(sigma) = slope log(K) + intercept + N(0, resid^2)", "",
              "| relation | slope | intercept | residual sigma |", "|---|---|---|---|"]
    for name, rel in (("sigma_TL", profile.tukey_scale), ("sigma_r", profile.row_scale), ("sigma_G", profile.gaussian_scale)):
        if rel is None:
            lines.append(f"| {name} | not measured | | |")
            continue
        lines.append(f"| {name} | {rel.slope:.4f} | {rel.intercept:.4f} | {rel.residual_std:.4f} |")
    if warnings_list:
        lines += ["", "## Warnings", ""] + [f"- {w}" for w in warnings_list]
    lines += ["", "## Figures", ""]
    for title, name in figures.items():
        lines += [f"### {title}", "", f"![{title}]({name})", ""]
    lines += ["All numbers: `report.json`.", ""]
    return "\n".join(lines)
