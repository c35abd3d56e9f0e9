"""Residual diagnosis on parameters, and the loop on parameter tables.

1. Per-ISO tables (stage 1 of calibration, or a published table): each relation
   ``log(sigma)`` against ``log(K)`` starts as the ELD single line; its residuals are
   tested for structure -- a *jump* (a change of regime across ISO: a conversion-gain
   switch, or digital gain above the top analog ISO or below the base ISO; each jump adds
   a line, its break chosen by least squares; at most ``MAX_JUMPS``), a *floor* (``sigma =
   sqrt(line^2 + floor^2)``: a read-noise floor) and *curvature* (a quadratic, diagnostic
   only) -- and the loop keeps the structure with the best BIC when it is significant
   against the line (BIC drop > ``BIC_DROP`` and nested F-test p < ``F_TEST_P``). Jumps and floor are stored
   in the profile's ``LogLinear.segments`` / ``floor_dn``. Errors are rms residuals of
   ``log(sigma)``.

2. Per-frame fit tables (one row per bias frame and channel with the frame's mean): the
   covariance of the four channel means across frames against the model's prediction
   (row noise couples only the channels of a sensor row; read noise averages out) tells
   whether a frame-to-frame black-level error (effect ``BLE``: a common part from the
   covariance of channels sharing no row, a per-channel part from the rest of the
   variance) is missing. The mean column is the frame mean in DN.
"""
from __future__ import annotations

import csv
import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import optimize
from scipy import stats as sstats

from ..effects import black_drift
from ..effects.frame_black_level import split_excess
from ..profile import LogLinear
from ..statistics import frame_mean_common_cov, frame_mean_lag1, frame_mean_std
from .registry import effects_for

BIC_DROP = 6.0  # 'strong' evidence (Kass & Raftery); with F_TEST_P, 0-3 % false structure on pure lines
F_TEST_P = 1e-2
MIN_SEGMENT = 3  # points per segment of a jump
MAX_JUMPS = 2  # low-ISO pull, analog range, high-ISO push
SCREENED = 12  # break sets refined with a floor, best by the closed-form fit without one


# ----------------------------------------------------------------------------- relation fits
@dataclass
class RelationFit:
    """One candidate structure of ``log(sigma)`` against ``log(K)``."""

    structures: tuple  # () line, ("jump",), ("floor",), ("jump", "floor"), ("curvature",)
    n_params: int
    rss: float
    residuals: np.ndarray
    relation: LogLinear | None  # None for the diagnostic-only curvature
    breaks_k: tuple = ()

    @property
    def break_k(self) -> float | None:
        """The first break (K), None without a jump."""
        return self.breaks_k[0] if self.breaks_k else None

    @property
    def name(self) -> str:
        return "+".join(("line",) + self.structures)

    def bic(self, n: int) -> float:
        return n * math.log(max(self.rss, 1e-300) / n) + self.n_params * math.log(n)

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))


def _predict(x, pieces, floor):
    """log sigma at log K ``x`` for (x_from, slope, intercept) pieces and a floor (DN)."""
    y = np.full_like(x, np.nan)
    for x_from, s, b in sorted(pieces):
        y = np.where(x >= x_from, s * x + b, y)
    first = sorted(pieces)[0]
    y = np.where(np.isnan(y), first[1] * x + first[2], y)
    return 0.5 * np.log(np.exp(2 * y) + floor**2) if floor > 0 else y


def _fit(x, y, breaks: tuple, with_floor: bool):
    """Least squares of pieces starting at ``breaks`` (log K), optionally with a floor."""
    edges = (-np.inf,) + tuple(breaks)
    init = []
    for i, lo in enumerate(edges):
        hi = edges[i + 1] if i + 1 < len(edges) else np.inf
        sel = (x >= lo) & (x < hi)
        s, b = np.polyfit(x[sel], y[sel], 1) if sel.sum() >= 2 else (0.0, float(np.mean(y)))
        init += [s, b]
    if with_floor:
        init.append(math.log(max(float(np.exp(y).min()) * 0.5, 1e-6)))

    def unpack(p):
        pieces = [(edges[i] if i else -np.inf, p[2 * i], p[2 * i + 1]) for i in range(len(edges))]
        floor = math.exp(p[-1]) if with_floor else 0.0
        return pieces, floor

    sol = optimize.least_squares(lambda p: _predict(x, *unpack(p)) - y, np.array(init, dtype=np.float64))
    pieces, floor = unpack(sol.x)
    return pieces, floor, sol.fun


def _relation(x, residuals, pieces, floor, breaks_k) -> LogLinear:
    """The fitted pieces as a profile ``LogLinear`` (residual_std per segment, ddof 2)."""
    segs = []
    bounds = [0.0] + list(breaks_k)
    edges = [-np.inf] + [math.log(b) for b in breaks_k] + [np.inf]
    for i, (_, s, b) in enumerate(sorted(pieces)):
        sel = (x >= edges[i]) & (x < edges[i + 1])
        r = residuals[sel]
        resid = float(np.sqrt(np.sum(r**2) / max(r.size - 2, 1)))
        segs.append(LogLinear(float(s), float(b), resid, float(bounds[i])))
    if len(segs) == 1:
        s = segs[0]
        return LogLinear(s.slope, s.intercept, s.residual_std, 0.0, (), float(floor))
    return LogLinear(segs[0].slope, segs[0].intercept, segs[0].residual_std, 0.0, tuple(segs), float(floor))


def _break_sets(x, n_jumps: int):
    """Every set of ``n_jumps`` breaks (log K, midway between distinct K values) leaving at
    least ``MIN_SEGMENT`` points in each segment."""
    ux = np.unique(x)
    mids = 0.5 * (ux[:-1] + ux[1:])
    for breaks in itertools.combinations(mids, n_jumps):
        edges = (-np.inf,) + breaks + (np.inf,)
        if all(((x >= edges[i]) & (x < edges[i + 1])).sum() >= MIN_SEGMENT for i in range(n_jumps + 1)):
            yield breaks


def _pieces_rss(x, y, breaks) -> float:
    """Residual sum of squares of independent lines per segment (closed form)."""
    edges = (-np.inf,) + tuple(breaks) + (np.inf,)
    rss = 0.0
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (x >= lo) & (x < hi)
        coef = np.polyfit(x[sel], y[sel], 1)
        rss += float(np.sum((y[sel] - np.polyval(coef, x[sel])) ** 2))
    return rss


def fit_structure(k, sigma, structures: tuple = ()) -> RelationFit:
    """Fit ``log(sigma)`` against ``log(K)`` with the given structures (see module doc;
    ``"jump"`` may appear up to ``MAX_JUMPS`` times).

    Breaks are searched over every gap between consecutive distinct K values leaving at
    least ``MIN_SEGMENT`` points in each segment (least squares; with a floor, the
    ``SCREENED`` best break sets without it are refined); a break's ``k_from`` is the
    geometric mean of the two K values around its gap."""
    k = np.asarray(k, dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    if k.shape != sigma.shape or k.ndim != 1 or k.size < 3:
        raise ValueError(f"k and sigma must be 1-D of equal length >= 3, got {k.shape} and {sigma.shape}")
    if np.any(k <= 0) or np.any(sigma <= 0) or not (np.isfinite(k).all() and np.isfinite(sigma).all()):
        raise ValueError("k and sigma must be positive and finite")
    n_jumps = structures.count("jump")
    if n_jumps > MAX_JUMPS:
        raise ValueError(f"at most {MAX_JUMPS} jumps, got {n_jumps}")
    order = np.argsort(k)
    x, y = np.log(k[order]), np.log(sigma[order])
    floor = "floor" in structures
    if "curvature" in structures:
        coef = np.polyfit(x, y, 2)
        r = y - np.polyval(coef, x)
        return RelationFit(("curvature",), 3, float(np.sum(r**2)), r, None)
    if not n_jumps:
        pieces, fl, r = _fit(x, y, (), floor)
        return RelationFit(tuple(structures), 2 + floor, float(np.sum(r**2)), r, _relation(x, r, pieces, fl, []))
    sets = sorted(_break_sets(x, n_jumps), key=lambda b: _pieces_rss(x, y, b))
    if not sets:
        raise ValueError(f"{n_jumps} jump(s) need >= {(n_jumps + 1) * MIN_SEGMENT} points in distinct K, "
                         f"got {len(np.unique(x))} distinct K")
    best = None
    for breaks in sets[:SCREENED] if floor else sets[:1]:
        pieces, fl, r = _fit(x, y, breaks, floor)
        rss = float(np.sum(r**2))
        if best is None or rss < best[0]:
            best = (rss, breaks, pieces, fl, r)
    rss, breaks, pieces, fl, r = best
    ks = tuple(float(math.exp(b)) for b in breaks)
    return RelationFit(tuple(structures), 2 + 3 * n_jumps + floor, rss, r, _relation(x, r, pieces, fl, list(ks)), ks)


def f_test(simple: RelationFit, rich: RelationFit, n: int) -> float:
    """p-value of the nested F-test of ``rich`` against ``simple``."""
    dp = rich.n_params - simple.n_params
    dof = n - rich.n_params
    if dp <= 0 or dof <= 0 or rich.rss <= 0:
        return 0.0 if rich.rss < simple.rss else 1.0
    f = ((simple.rss - rich.rss) / dp) / (rich.rss / dof)
    return float(sstats.f.sf(f, dp, dof))


STRUCTURES = ((), ("floor",), ("jump",), ("jump", "floor"), ("jump", "jump"), ("jump", "jump", "floor"))


def fit_all(k, sigma, structures=STRUCTURES + (("curvature",),)) -> dict:
    """``{structures: RelationFit}`` of every structure the data can carry (too few points
    for a jump leaves it out)."""
    fits = {}
    for st in structures:
        try:
            fits[st] = fit_structure(k, sigma, st)
        except ValueError:
            continue
    return fits


def diagnose_relation(k, sigma, fits: dict | None = None) -> dict:
    """Every candidate structure of one relation with its rms residual and BIC (the
    residual-structure diagnosis: which of jump, curvature, floor the residuals show)."""
    n = len(k)
    return {f.name: {"rms_log": f.rms, "bic": f.bic(n), "n_params": f.n_params, "break_k": f.break_k,
                     "breaks_k": list(f.breaks_k)} for f in (fits or fit_all(k, sigma)).values()}


def relation_loop(k, sigma, name: str = "sigma", fits: dict | None = None) -> tuple[RelationFit, list[dict]]:
    """Fit every structure of ``STRUCTURES``; keep the best BIC if it beats the single line
    by more than ``BIC_DROP`` with a nested F-test p < ``F_TEST_P`` (a global choice: a
    floor and a jump can be significant together where neither is alone).

    Returns the chosen fit and its steps from the line, one structure added at a time
    along the best BIC, ``{structure, evidence, error_before, error_after, ...}``, with
    errors as rms residuals of log(sigma) (natural log: 0.1 = about 10 %). ``fits``: those
    of ``fit_all`` when already made."""
    n = len(k)
    fits = fits or fit_all(k, sigma, STRUCTURES)
    fits = {st: f for st, f in fits.items() if st in STRUCTURES}  # curvature is a diagnostic only
    line = fits[()]
    best = min(fits.values(), key=lambda f: f.bic(n))
    if best is line or not (best.bic(n) < line.bic(n) - BIC_DROP and f_test(line, best, n) < F_TEST_P):
        return line, []
    target_jumps, target_floor = best.structures.count("jump"), "floor" in best.structures
    current, steps = line, []
    while current is not best:
        jumps, floor = current.structures.count("jump"), "floor" in current.structures
        options = []
        if jumps < target_jumps:
            options.append(("jump", fits.get(("jump",) * (jumps + 1) + ("floor",) * floor)))
        if target_floor and not floor:
            options.append(("floor", fits.get(("jump",) * jumps + ("floor",))))
        add, nxt = min(((a, f) for a, f in options if f is not None), key=lambda o: o[1].bic(n))
        steps.append({
            "relation": name, "structure": add, "break_k": nxt.break_k, "breaks_k": list(nxt.breaks_k),
            "floor_dn": nxt.relation.floor_dn if nxt.relation else None,
            "evidence": f"BIC {current.bic(n):.1f} -> {nxt.bic(n):.1f}, F-test p = {f_test(current, nxt, n):.2g}",
            "error_before": current.rms, "error_after": nxt.rms,
            "max_abs_before": float(np.abs(current.residuals).max()), "max_abs_after": float(np.abs(nxt.residuals).max()),
        })
        current = nxt
    return current, steps


def parameter_loop(params) -> dict:
    """Run ``relation_loop`` on sigma_TL, sigma_r and sigma_G of per-ISO ``IsoParameters``.

    Returns ``{"fits": {name: RelationFit}, "steps": [...], "diagnosis": {name: ...}}``."""
    params = sorted(params, key=lambda p: p.k)
    k = np.array([p.k for p in params])
    series = {}
    if all(p.sigma_tl is not None for p in params):
        series["sigma_tl"] = np.array([p.sigma_tl for p in params])
    if all(p.sigma_r is not None and p.sigma_r > 0 for p in params):
        series["sigma_r"] = np.array([p.sigma_r for p in params])
    if all(p.sigma_g is not None for p in params):
        series["sigma_g"] = np.array([p.sigma_g for p in params])
    fits, steps, diagnosis = {}, [], {}
    for name, s in series.items():
        every = fit_all(k, s)  # once, for the diagnosis and the loop
        diagnosis[name] = diagnose_relation(k, s, every)
        fits[name], st = relation_loop(k, s, name, every)
        steps += st
    return {"fits": fits, "steps": steps, "diagnosis": diagnosis}


def apply_to_profile(profile, fits: dict):
    """A copy of ``profile`` with the selected relations (segments, floor) in place."""
    data = profile.to_dict()
    where = {"sigma_tl": ("read_noise", "tukey_scale"), "sigma_g": ("read_noise", "gaussian_scale"),
             "sigma_r": ("row_noise", "scale")}
    for name, fit in fits.items():
        a, b = where[name]
        data[a][b] = fit.relation.to_dict()
    return type(profile).from_dict(data)


# ----------------------------------------------------------------------------- per-frame tables
def read_frame_table(path, mean_column: str = "meanR") -> dict:
    """Per-frame fits (CSV: ``frame, channel`` and fitted columns) -> arrays (frames, 4).

    ``mean_column`` holds the frame-channel mean, DN. In the PMN IMX686 tables that is
    ``meanR`` (mean of the row means = the frame mean); ``meanGs`` / ``meanTL`` are ~1e-8:
    the PMN fit removed the mean before fitting the pixel distributions."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"per-frame table {str(path)!r} does not exist")
    with path.open() as f:
        rows = list(csv.DictReader(f))
    if not rows or "frame" not in rows[0] or "channel" not in rows[0]:
        raise ValueError(f"{path}: a per-frame table needs 'frame' and 'channel' columns")
    for col in (mean_column, "sigmaR", "sigmaGs"):
        if col not in rows[0]:
            raise ValueError(f"{path}: missing column {col!r} (have {sorted(rows[0])})")
    frames = sorted({int(r["frame"]) for r in rows})
    idx = {f: i for i, f in enumerate(frames)}
    out = {c: np.full((len(frames), 4), np.nan) for c in (mean_column, "sigmaR", "sigmaGs")}
    for r in rows:
        ch = int(r["channel"])
        if not 0 <= ch < 4:
            raise ValueError(f"{path}: channel must be 0..3, got {ch}")
        for c in out:
            out[c][idx[int(r["frame"])], ch] = float(r[c])
    for c, v in out.items():
        if np.isnan(v).any():
            raise ValueError(f"{path}: column {c!r} is missing for some frame/channel")
    return {"means": out[mean_column], "sigma_r": out["sigmaR"], "sigma_g": out["sigmaGs"]}


def model_mean_covariance(sigma_r, sigma_pix, rows: int, cols: int, ble_dn: float = 0.0,
                          channel_dn: float = 0.0) -> np.ndarray:
    """(4, 4) covariance (DN^2) across frames of the packed channel means of ``rows x cols``
    packed frames: row noise shared by (0, 1) and (2, 3), independent pixel noise, a
    common black-level error ``ble_dn`` and a per-channel one ``channel_dn``."""
    cov = np.diag(np.full(4, (sigma_r**2 + sigma_pix**2 / cols) / rows + channel_dn**2))
    for a, b in ((0, 1), (2, 3)):
        cov[a, b] = cov[b, a] = sigma_r**2 / rows
    return cov + ble_dn**2


def _table_statistics(means) -> dict:
    """The battery's frame-mean statistics of (n, 4) per-frame channel means (DN), as frames of
    one packed pixel, and the correlation of the channel pairs that share a sensor row."""
    c = np.cov(means.T)
    sd = np.sqrt(np.diag(c))
    corr = c / np.outer(sd, sd)
    frames = means[:, :, None, None]
    return {
        "frame_mean_std": frame_mean_std(frames),
        "frame_mean_common_cov": frame_mean_common_cov(frames),
        "row_pair_corr": float((corr[0, 1] + corr[2, 3]) / 2),
        "frame_mean_lag1": frame_mean_lag1(frames),
    }


def diagnose_frame_table(table: dict, rows: int, cols: int, *, ble_dn: float = 0.0, channel_dn: float = 0.0,
                         drift_dn: float = 0.0, drift_rho: float = 0.0, n_synth: int = 400,
                         seed: int = 0, z_min: float = 6.0, rel_min: float = 0.1) -> list[dict]:
    """Statistics of the per-frame channel means against ``n_synth`` synthesized tables of
    the same number of frames (Gaussian channel means with the model covariance, plus a
    common offset drifting as an AR(1) of spread ``drift_dn`` and lag-1 correlation
    ``drift_rho`` over the frames in their order)."""
    means = np.asarray(table["means"], dtype=np.float64)
    n = means.shape[0]
    if n < 8:
        raise ValueError(f"a per-frame table needs >= 8 frames, got {n}")
    cov = model_mean_covariance(float(np.mean(table["sigma_r"])), float(np.mean(table["sigma_g"])), rows, cols,
                                ble_dn, channel_dn)
    rng = np.random.default_rng(seed)
    synth = []
    for _ in range(n_synth):
        m = rng.multivariate_normal(np.zeros(4), cov, size=n)
        synth.append(_table_statistics(m + black_drift.ar1(rng.standard_normal(n), drift_dn, drift_rho)[:, None] if drift_dn else m))
    out = []
    for name, m in _table_statistics(means).items():
        v = np.array([s[name] for s in synth])
        mean, std = float(v.mean()), float(v.std(ddof=1))
        z = (m - mean) / max(std, 1e-30)
        rel = abs(m - mean) / max(abs(m), 3 * std, 1e-30)
        out.append({"statistic": name, "measured": m, "synth_mean": mean, "synth_std": std, "z": float(z),
                    "rel_error": float(rel), "significant": bool(abs(z) > z_min and rel > rel_min),
                    "effects": effects_for(name)})
    return sorted(out, key=lambda r: -abs(r["z"]))


def frame_table_loop(table: dict, rows: int, cols: int, k: float, **kw) -> dict:
    """The loop on a per-frame table: diagnose; if the common-mode statistics point to BLE,
    estimate it (common covariance minus the model's) and diagnose again; if the frame means
    are then still alike from one frame to the next (their lag-1 autocorrelation), a drifting
    black level (``BlackDrift``) takes over BLE's common part, kept where that residual's error
    falls and nothing else becomes significant. ``effects``: the profile entries found."""
    before = diagnose_frame_table(table, rows, cols, **kw)
    steps, after, effects = [], before, {}
    evidence = next((r for r in before if r["significant"] and "BLE" in r["effects"]), None)
    means = np.asarray(table["means"], dtype=np.float64)
    model = model_mean_covariance(float(np.mean(table["sigma_r"])), float(np.mean(table["sigma_g"])), rows, cols)
    channel = 0.0
    if evidence is not None:
        c = np.cov(means.T)
        sigma, channel = split_excess((c[0, 2] + c[1, 3]) / 2 - (model[0, 2] + model[1, 3]) / 2,
                                      float(np.mean(np.diag(c) - np.diag(model))))
        params = {"k": [float(k)], "sigma_dn": [sigma], "channel_sigma_dn": [channel]}
        after = diagnose_frame_table(table, rows, cols, ble_dn=sigma, channel_dn=channel, **kw)
        new = next(r for r in after if r["statistic"] == evidence["statistic"])
        accepted = new["rel_error"] < evidence["rel_error"]
        steps.append({"effect": "BLE", "params": params, "evidence": evidence, "error_before": evidence["rel_error"],
                      "error_after": new["rel_error"], "z_after": new["z"], "accepted": accepted})
        if accepted:
            effects["BLE"] = params
        else:
            after = before
    lag = next((r for r in after if r["significant"] and r["z"] > 0 and "BlackDrift" in r["effects"]), None)
    if lag is not None:
        # the common part of the frame means as an AR(1): its sums about the mean and of its
        # successive differences (the model's other parts add nothing common to R-B and G1-G2)
        ss, ssd = black_drift.common_sums(means)
        common = (model[0, 2] + model[1, 3]) / 2 * (means.shape[0] - 1)  # a white common part's share of either sum
        drift = black_drift.combine([{"k": [float(k)], "ss": [ss - common], "ssd": [ssd - 2.0 * common],
                                      "n": [means.shape[0]]}])
        trial = diagnose_frame_table(table, rows, cols, channel_dn=channel, drift_dn=drift["sigma_dn"][0],
                                     drift_rho=drift["rho"][0], **kw)
        new = next(r for r in trial if r["statistic"] == lag["statistic"])
        accepted = (new["rel_error"] <= 0.5 * lag["rel_error"]
                    and sum(r["significant"] for r in trial) < sum(r["significant"] for r in after))
        steps.append({"effect": "BlackDrift", "params": drift, "evidence": lag, "error_before": lag["rel_error"],
                      "error_after": new["rel_error"], "z_after": new["z"], "accepted": accepted})
        if accepted:
            after = trial
            effects["BlackDrift"] = drift
            if "BLE" in effects:  # the drift is the common part now: BLE keeps each channel's own
                effects["BLE"] = {**effects["BLE"], "sigma_dn": [0.0]}
    return {"before": before, "after": after, "steps": steps, "effects": effects}
