"""Stage 2 of calibration: per-ISO parameters -> the joint model over K -> a NoiseProfile.

As in ELD (section 3.2): ``log(sigma_TL)``, ``log(sigma_r)`` (and ``log(sigma_G)``) are
linear in ``log(K)`` with Gaussian residuals (least squares); lambda and the colour bias
are kept as tables against K. Sigmas in DN, K in DN per electron.
"""
from __future__ import annotations

import csv
import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..distributions import tukey_lambda_variance
from ..profile import NoiseProfile
from ..relations import KTable, LogLinear
from ..validate import finite


@dataclass
class IsoParameters:
    """Noise parameters measured at one ISO (sigmas in DN, K in DN/e-)."""

    iso: float
    k: float
    sigma_tl: float | None  # None: no Tukey-lambda fit (a Poisson-Gaussian table)
    sigma_r: float | None  # None: row noise not measured
    lam: float | None
    sigma_g: float | None = None
    color_bias_dn: tuple | None = None  # (R, G1, B, G2)
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        where = f"ISO {self.iso!r} parameters"
        for name in ("iso", "k"):
            value = float(getattr(self, name))
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"{where}: {name} must be a positive finite number, got {getattr(self, name)!r}")
            setattr(self, name, value)
        if (self.sigma_tl is None) != (self.lam is None):
            raise ValueError(f"{where}: sigma_tl and lambda come together (a Tukey-lambda fit) or not at all, "
                             f"got sigma_tl={self.sigma_tl!r}, lambda={self.lam!r}")
        if self.sigma_tl is None and self.sigma_g is None:
            raise ValueError(f"{where}: needs a read-noise scale: sigma_tl with lambda, or sigma_g")
        if self.sigma_tl is not None:
            self.sigma_tl = float(self.sigma_tl)
            if not math.isfinite(self.sigma_tl) or self.sigma_tl <= 0:
                raise ValueError(f"{where}: sigma_tl must be a positive finite number, got {self.sigma_tl!r}")
            self.lam = float(self.lam)
            if not -1.0 <= self.lam <= 1.0:
                raise ValueError(f"{where}: lambda must be in [-1, 1], got {self.lam!r}")
        if self.sigma_r is not None:
            self.sigma_r = float(self.sigma_r)
            if not math.isfinite(self.sigma_r) or self.sigma_r < 0:
                raise ValueError(f"{where}: sigma_r must be >= 0 and finite, got {self.sigma_r!r}")
        if self.sigma_g is not None:
            self.sigma_g = float(self.sigma_g)
            if not math.isfinite(self.sigma_g) or self.sigma_g <= 0:
                raise ValueError(f"{where}: sigma_g must be a positive finite number, got {self.sigma_g!r}")
        if self.color_bias_dn is not None:
            bias = np.broadcast_to(np.asarray(self.color_bias_dn, dtype=np.float64), (4,))
            if not np.all(np.isfinite(bias)):
                raise ValueError(f"{where}: color_bias_dn must be finite, got {self.color_bias_dn!r}")
            self.color_bias_dn = tuple(float(v) for v in bias)

    def to_dict(self) -> dict:
        out = {"iso": self.iso, "k": self.k, "sigma_tl": self.sigma_tl, "sigma_r": self.sigma_r, "lambda": self.lam,
               "sigma_g": self.sigma_g, "color_bias_dn": list(self.color_bias_dn) if self.color_bias_dn else None}
        return {**out, "extra": self.extra}


# ----------------------------------------------------------------------------- table input
_ALIASES = {
    "iso": ("iso",),
    "k": ("k", "kmax", "system_gain", "k_dn_per_e"),
    "sigma_tl": ("sigma_tl", "sigtl", "sigma_tukey"),
    "sigma_r": ("sigma_r", "sigr", "sigma_row"),
    "lam": ("lambda", "lam", "tukey_lambda"),
    "sigma_g": ("sigma_g", "sigg", "siggs", "sigma_gauss"),
    "bias": ("bias", "color_bias", "color_bias_dn"),
}
_BIAS_COLUMNS = ("bias_r", "bias_g1", "bias_b", "bias_g2")


def _pick(row: dict, key: str, where: str, required=True):
    lowered = {str(k).strip().lower(): v for k, v in row.items()}
    for alias in _ALIASES[key]:
        if alias in lowered and lowered[alias] not in (None, ""):
            return lowered[alias]
    if required:
        raise ValueError(f"{where}: missing {key!r} (accepted names: {', '.join(_ALIASES[key])})")
    return None


def _number(value, name, where):
    return finite(value, f"{where}: {name}")


def _row_to_params(row: dict, where: str, iso=None) -> IsoParameters:
    iso = _number(iso if iso is not None else _pick(row, "iso", where), "iso", where)
    values = {"k": _number(_pick(row, "k", where), "k", where)}
    for key in ("sigma_tl", "sigma_r", "lam"):  # optional: a Poisson-Gaussian table has sigma_g alone
        raw = _pick(row, key, where, required=False)
        values[key] = None if raw is None else _number(raw, key, where)
    sigma_g = _pick(row, "sigma_g", where, required=False)
    lowered = {str(k).strip().lower(): v for k, v in row.items()}
    bias = None
    if all(c in lowered and lowered[c] not in (None, "") for c in _BIAS_COLUMNS):
        bias = tuple(_number(lowered[c], c, where) for c in _BIAS_COLUMNS)
    else:
        raw = _pick(row, "bias", where, required=False)
        if isinstance(raw, str):
            raw = [p for p in raw.replace(";", " ").split() if p]
        if raw is not None:
            vals = np.atleast_1d(np.asarray(raw, dtype=object))
            if vals.size not in (1, 4):
                raise ValueError(f"{where}: colour bias must be one number or 4 (R, G1, B, G2), got {raw!r}")
            bias = tuple(_number(v, "bias", where) for v in np.broadcast_to(vals, (4,)))
    known = {a for names in _ALIASES.values() for a in names} | set(_BIAS_COLUMNS)
    extra = {k: v for k, v in lowered.items() if k not in known}
    try:
        return IsoParameters(iso=iso, k=values["k"], sigma_tl=values["sigma_tl"], sigma_r=values["sigma_r"],
                             lam=values["lam"], sigma_g=None if sigma_g is None else _number(sigma_g, "sigma_g", where),
                             color_bias_dn=bias, extra=extra)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def read_parameter_tables(path) -> dict[str, list[IsoParameters]]:
    """Every camera's per-ISO parameters in a CSV or JSON table: camera name -> rows sorted by K.

    A file of one unnamed table maps ``""`` to it. Several cameras are told apart by
    a ``camera`` column (CSV); several ``<Camera>_per_ISO`` keys, or an object mapping
    camera names to tables (JSON).

    CSV: header with ``iso, K`` and ``sigma_TL, lambda`` (a Tukey-lambda fit) and/or
    ``sigma_G`` (Gaussian), optional ``sigma_r``,
    ``bias_R, bias_G1, bias_B, bias_G2`` (or ``bias``); other columns go to ``extra``.
    JSON: a list of such objects; ``{"per_iso": [...]}``; or the PMN layout
    ``{"<Camera>_per_ISO": {"<iso>": {"Kmax": K, "sigTL":, "sigR":, "sigGs":, "lam":, "bias":}}}``.
    Column names are case-insensitive; sigmas in DN.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"parameter table {str(path)!r} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
        tables: dict[str, list] = {}
        for i, row in enumerate(csv.DictReader(lines, skipinitialspace=True), start=2):
            key = next((k for k in row if k is not None and k.strip().lower() == "camera"), None)
            camera = str(row.pop(key, "") or "").strip() if key is not None else ""
            tables.setdefault(camera, []).append(_row_to_params(row, f"{path.name} row {i}"))
    elif suffix == ".json":
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON: {exc}") from None
        tables = _tables_from_json(data, path.name)
    else:
        raise ValueError(f"{path}: a parameter table must be .csv or .json, got {suffix!r}")
    if not tables or not any(tables.values()):
        raise ValueError(f"{path}: the parameter table has no rows")
    for camera, params in tables.items():
        if not params:
            raise ValueError(f"{path}: camera {camera!r} has no rows")
    return {camera: sorted(params, key=lambda p: (p.k, p.iso)) for camera, params in tables.items()}


def pick_camera(tables: dict, camera: str | None, where) -> str:
    """The key of ``camera`` in ``tables`` (case-insensitive). With one table, that one
    whatever ``camera`` says (it only names the profile); with several, ``camera`` must name one."""
    if len(tables) == 1:
        return next(iter(tables))
    names = sorted(tables)
    if camera is None:
        raise ValueError(f"{where}: the table holds {len(names)} cameras ({', '.join(names)}); "
                         f"choose one with --camera")
    match = [name for name in names if name.lower() == camera.lower()]
    if not match:
        raise ValueError(f"{where}: no camera {camera!r} in the table; it holds {', '.join(names)}")
    return match[0]


def read_parameter_table(path, camera: str | None = None) -> list[IsoParameters]:
    """Per-ISO parameters of one camera, sorted by K (see :func:`read_parameter_tables`)."""
    tables = read_parameter_tables(path)
    return tables[pick_camera(tables, camera, path)]


def _tables_from_json(data, name) -> dict[str, list]:
    if isinstance(data, dict):
        per_iso_keys = [k for k in data if str(k).lower().endswith("per_iso") and str(k).lower() != "per_iso"]
        if per_iso_keys:
            tables = {}
            for key in per_iso_keys:
                table = data[key]
                if not isinstance(table, dict):
                    raise ValueError(f"{name}: {key!r} must map ISO -> parameters, got {type(table).__name__}")
                camera = str(key)[: -len("per_iso")].rstrip("_- ")
                tables[camera] = [_row_to_params(row, f"{name} {key}[{iso}]", iso=iso) for iso, row in table.items()]
            return tables
        if "per_iso" not in data and data and all(_is_table(v) for v in data.values()):
            return {str(camera): _rows_from_json(table, f"{name} {camera}") for camera, table in data.items()}
    return {"": _rows_from_json(data, name)}


def _is_table(value) -> bool:
    return (isinstance(value, list) and bool(value) and all(isinstance(r, dict) for r in value)) or (
        isinstance(value, dict) and isinstance(value.get("per_iso"), list))


def _rows_from_json(data, name):
    if isinstance(data, dict) and isinstance(data.get("per_iso"), list):
        data = data["per_iso"]
    if not isinstance(data, list) or not all(isinstance(r, dict) for r in data):
        raise ValueError(f"{name}: JSON must be a list of per-ISO objects, {{'per_iso': [...]}}, a PMN "
                         f"'<Camera>_per_ISO' mapping or an object mapping camera names to such tables")
    return [_row_to_params(row, f"{name}[{i}]") for i, row in enumerate(data)]


# ----------------------------------------------------------------------------- joint fit
def fit_log_linear(k, sigma) -> LogLinear:
    """Least squares ``log(sigma) = slope * log(K) + intercept``; ``residual_std`` is the
    unbiased residual standard deviation (ddof = 2; 0 with only two points, with a warning)."""
    k = np.asarray(k, dtype=np.float64).ravel()
    sigma = np.asarray(sigma, dtype=np.float64).ravel()
    if k.shape != sigma.shape:
        raise ValueError(f"k and sigma must have the same length, got {k.size} and {sigma.size}")
    if k.size < 2:
        raise ValueError(f"a log-linear fit needs at least 2 points, got {k.size}")
    if np.any(~np.isfinite(k)) or np.any(k <= 0) or np.any(~np.isfinite(sigma)) or np.any(sigma <= 0):
        raise ValueError(f"k and sigma must be positive and finite, got k={k.tolist()}, sigma={sigma.tolist()}")
    x, y = np.log(k), np.log(sigma)
    if np.ptp(x) == 0:
        raise ValueError(f"a log-linear fit needs at least 2 distinct K values, got {np.unique(k).tolist()}")
    slope, intercept = np.polyfit(x, y, 1)
    residual = y - (slope * x + intercept)
    if k.size > 2:
        resid_std = float(np.sqrt(np.sum(residual**2) / (k.size - 2)))
    else:
        warnings.warn("log-linear fit through 2 points: residual_std is set to 0 (unknown)", stacklevel=2)
        resid_std = 0.0
    return LogLinear(slope=float(slope), intercept=float(intercept), residual_std=resid_std)


def gaussian_equivalent_sigma(sigma_tl: float, lam: float) -> float:
    """Std (DN) of a Tukey-lambda distribution with scale sigma_TL: the Gaussian of equal variance."""
    var = tukey_lambda_variance(lam)
    if not math.isfinite(var):
        raise ValueError(f"Tukey lambda {lam} has infinite variance; no Gaussian equivalent")
    return sigma_tl * math.sqrt(var)


def fit_joint(params, *, camera, black_level, white_level, bit_depth, cfa, quantization_step_dn=1.0,
              source="") -> NoiseProfile:
    """Joint model over K from per-ISO parameters, as a :class:`NoiseProfile`.

    sigma_TL, sigma_r and sigma_G relations are log-linear least-squares fits (sigma_G from
    each ISO's own sigma_g, or the Gaussian of equal variance where it is missing); lambda
    and the colour bias are tables against K; ``k_min/k_max`` is the measured K range and
    the ISO table maps ISO to K. A zero sigma_r (no row noise found) cannot enter a log fit:
    those ISOs are left out of the row relation (with a warning).
    """
    params = sorted(list(params), key=lambda p: p.k)
    if len(params) < 2:
        raise ValueError(f"the joint model needs parameters at >= 2 ISOs, got {len(params)}")
    for p in params:
        if not isinstance(p, IsoParameters):
            raise TypeError(f"params must be IsoParameters, got {type(p).__name__}")
    k = np.array([p.k for p in params])
    if np.unique(k).size < 2:
        raise ValueError(f"the joint model needs >= 2 distinct K values, got {np.unique(k).tolist()}")
    tukey = shape = None
    if all(p.sigma_tl is not None for p in params):
        tukey = fit_log_linear(k, [p.sigma_tl for p in params])
        shape = KTable(tuple(float(v) for v in k), tuple(float(p.lam) for p in params))
    sigma_g = [p.sigma_g if p.sigma_g is not None else gaussian_equivalent_sigma(p.sigma_tl, p.lam) for p in params]
    gaussian = fit_log_linear(k, sigma_g)
    with_rows = [p for p in params if p.sigma_r is not None and p.sigma_r > 0]
    row = None
    if any(p.sigma_r is not None for p in params):
        if len(with_rows) < len(params):
            warnings.warn(f"no sigma_r > 0 at ISO {[p.iso for p in params if p not in with_rows]}: left out of the "
                          "row-noise fit", stacklevel=2)
        if len({p.k for p in with_rows}) < 2:
            raise ValueError("row noise (sigma_r > 0) was found at fewer than 2 distinct K: cannot fit its relation")
        row = fit_log_linear([p.k for p in with_rows], [p.sigma_r for p in with_rows])
    bias_rows = [tuple(p.color_bias_dn) if p.color_bias_dn is not None else (0.0, 0.0, 0.0, 0.0) for p in params]
    isos = {}
    for p in params:
        isos.setdefault(p.iso, []).append(p.k)
    iso_sorted = sorted(isos)
    iso_k = [float(np.exp(np.mean(np.log(isos[i])))) for i in iso_sorted]
    return NoiseProfile(
        camera=str(camera), black_level=float(black_level), white_level=float(white_level), bit_depth=int(bit_depth),
        cfa=str(cfa).upper(), k_min=float(k.min()), k_max=float(k.max()), tukey_scale=tukey, gaussian_scale=gaussian,
        row_scale=row, tukey_shape=shape,
        color_bias=KTable(tuple(float(v) for v in k), tuple(bias_rows)), quantization_step_dn=float(quantization_step_dn),
        iso_table=(tuple(float(i) for i in iso_sorted), tuple(iso_k)), effects={}, source=str(source),
    )
