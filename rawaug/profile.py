"""NoiseProfile: the calibrated noise parameters of one camera, and its file format.

File format (YAML, ``format: rawaug.noise-profile``, ``version: 1``)::

    format: rawaug.noise-profile
    version: 1
    camera: SonyA7S2
    source: where the numbers come from (free text)
    sensor: {black_level: 512, white_level: 16383, bit_depth: 14, cfa: RGGB}
    system_gain:                      # K, DN per electron
      k_min: 0.0939                   # K at the lowest calibrated ISO
      k_max: 6.0106                   # K at the highest calibrated ISO
      iso: [100, 6400]                # optional ISO -> K table (log-log interpolation)
      k: [0.0939, 6.0106]
    read_noise:
      tukey_scale:    {slope: .., intercept: .., residual_std: ..}   # sigma_TL, DN
      gaussian_scale: {slope: .., intercept: .., residual_std: ..}   # sigma_G, DN
      tukey_shape: {k: [...], lambda: [...]}                        # lambda against K
    row_noise:
      scale: {slope: .., intercept: .., residual_std: ..}           # sigma_r, DN
    quantization: {step_dn: 1.0}
    color_bias: {k: [...], dn: [[R, G1, B, G2], ...]}               # black-level error, DN
    effects: {}                       # effects added by the closed loop, by registered name

A scale relation means ``log(sigma) = slope * log(K) + intercept + N(0, residual_std^2)``
(natural logs, sigma in DN). It may instead hold ``segments`` (a list of such
relations, each with ``k_from``: a change of regime across ISO, e.g. a
conversion-gain switch) and a ``floor_dn`` (sigma never falls below it:
``sigma = sqrt(line^2 + floor^2)``).
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import yaml

from .atomic import write_text_atomic
from .bayer import CFA_PATTERNS
from .effects import EFFECTS
from .relations import KTable, LogLinear, _require  # noqa: F401
from .validate import finite as _finite

FORMAT_NAME = "rawaug.noise-profile"
FORMAT_VERSION = 1
K_PHYSICAL = (1e-4, 1e4)  # DN per electron: any real sensor lies well inside
BUILTIN_PROFILES = ("SonyA7S2", "NikonD850", "CanonEOS70D", "CanonEOS700D", "CanonEOS5D4")


def _positive(value, where):
    value = _finite(value, where)
    if value <= 0:
        raise ValueError(f"{where} must be > 0, got {value}")
    return value


@dataclass
class NoiseProfile:
    """Calibrated noise parameters of one camera. Sigmas in DN, K in DN per electron."""

    camera: str
    black_level: float
    white_level: float
    bit_depth: int
    cfa: str
    k_min: float
    k_max: float
    tukey_scale: LogLinear | None  # None: a Poisson-Gaussian profile (no Tukey-lambda fit)
    gaussian_scale: LogLinear
    row_scale: LogLinear | None  # None: no row noise measured
    tukey_shape: KTable | None
    color_bias: KTable
    quantization_step_dn: float = 1.0
    iso_table: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    effects: dict = field(default_factory=dict)
    source: str = ""

    # ---------------------------------------------------------------- loading
    @classmethod
    def load(cls, name_or_path) -> "NoiseProfile":
        """A built-in camera name (see ``BUILTIN_PROFILES``) or a profile file path."""
        if isinstance(name_or_path, NoiseProfile):
            return name_or_path
        text = None
        if str(name_or_path) in BUILTIN_PROFILES:
            text = resources.files("rawaug.profiles").joinpath(f"{name_or_path}.yaml").read_text()
            where = f"built-in profile {name_or_path}"
        else:
            path = Path(name_or_path)
            if not path.is_file():
                raise ValueError(
                    f"profile {str(name_or_path)!r} is neither a built-in name {BUILTIN_PROFILES} nor an existing file"
                )
            text = path.read_text()
            where = str(path)
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ValueError(f"{where} is not valid YAML: {exc}") from None
        return cls.from_dict(data)

    @classmethod
    def from_dict(cls, data) -> "NoiseProfile":
        if not isinstance(data, dict):
            raise ValueError(f"a profile must be a mapping, got {type(data).__name__}")
        fmt = data.get("format")
        if fmt != FORMAT_NAME:
            raise ValueError(f"profile 'format' must be {FORMAT_NAME!r}, got {fmt!r}")
        version = data.get("version")
        if version != FORMAT_VERSION:
            raise ValueError(f"profile 'version' must be {FORMAT_VERSION}, got {version!r}")
        sensor = _require(data, "sensor", "profile")
        black = _finite(_require(sensor, "black_level", "sensor"), "sensor.black_level")
        white = _finite(_require(sensor, "white_level", "sensor"), "sensor.white_level")
        if white <= black:
            raise ValueError(f"sensor.white_level must exceed black_level, got white={white}, black={black}")
        cfa = str(_require(sensor, "cfa", "sensor")).upper()
        if cfa not in CFA_PATTERNS:
            raise ValueError(f"sensor.cfa must be one of {CFA_PATTERNS}, got {cfa!r}")
        bit_depth = int(_require(sensor, "bit_depth", "sensor"))
        if not 1 <= bit_depth <= 32:
            raise ValueError(f"sensor.bit_depth must be in [1, 32], got {bit_depth}")

        gain = _require(data, "system_gain", "profile")
        k_min = _positive(_require(gain, "k_min", "system_gain"), "system_gain.k_min")
        k_max = _positive(_require(gain, "k_max", "system_gain"), "system_gain.k_max")
        if k_max < k_min:
            raise ValueError(f"system_gain.k_max must be >= k_min, got k_min={k_min}, k_max={k_max}")
        iso_table = None
        if "iso" in gain or "k" in gain:
            isos = [_positive(v, "system_gain.iso[]") for v in _require(gain, "iso", "system_gain")]
            ks = [_positive(v, "system_gain.k[]") for v in _require(gain, "k", "system_gain")]
            if len(isos) != len(ks) or not isos:
                raise ValueError(f"system_gain.iso and system_gain.k must have equal non-zero length, got {len(isos)} and {len(ks)}")
            order = sorted(range(len(isos)), key=isos.__getitem__)
            iso_table = (tuple(isos[i] for i in order), tuple(ks[i] for i in order))

        read = _require(data, "read_noise", "profile")
        gaussian_scale = LogLinear.from_dict(_require(read, "gaussian_scale", "read_noise"), "read_noise.gaussian_scale")
        tukey_scale = shape_table = None
        if ("tukey_scale" in read) != ("tukey_shape" in read):
            raise ValueError("read_noise needs both tukey_scale and tukey_shape (a Tukey-lambda fit) or neither "
                             "(a Poisson-Gaussian profile)")
        if "tukey_scale" in read:
            tukey_scale = LogLinear.from_dict(read["tukey_scale"], "read_noise.tukey_scale")
            shape = read["tukey_shape"]
            shape_k = [_positive(v, "read_noise.tukey_shape.k[]") for v in _require(shape, "k", "read_noise.tukey_shape")]
            lambdas = [_finite(v, "read_noise.tukey_shape.lambda[]") for v in _require(shape, "lambda", "read_noise.tukey_shape")]
            for lam in lambdas:
                if not -1.0 <= lam <= 1.0:
                    raise ValueError(f"read_noise.tukey_shape.lambda must be in [-1, 1], got {lam}")
            if len(shape_k) != len(lambdas) or not lambdas:
                raise ValueError(f"read_noise.tukey_shape.k and .lambda must have equal non-zero length, got {len(shape_k)} and {len(lambdas)}")
            shape_table = KTable(tuple(shape_k), tuple(lambdas))

        row = data.get("row_noise")
        row_scale = LogLinear.from_dict(_require(row, "scale", "row_noise"), "row_noise.scale") if row is not None else None

        quant = data.get("quantization", {"step_dn": 1.0})
        step = _positive(_require(quant, "step_dn", "quantization"), "quantization.step_dn")

        bias = _require(data, "color_bias", "profile")
        bias_k = [_positive(v, "color_bias.k[]") for v in _require(bias, "k", "color_bias")]
        rows = _require(bias, "dn", "color_bias")
        if not isinstance(rows, list) or len(rows) != len(bias_k) or not rows:
            raise ValueError(f"color_bias.dn must be a list with one row per color_bias.k entry ({len(bias_k)}), got {rows!r:.80}")
        bias_rows = []
        for i, r in enumerate(rows):
            if not isinstance(r, (list, tuple)) or len(r) != 4:
                raise ValueError(f"color_bias.dn[{i}] must hold 4 values (R, G1, B, G2), got {r!r}")
            bias_rows.append(tuple(_finite(v, f"color_bias.dn[{i}]") for v in r))

        span = white - black
        if not (K_PHYSICAL[0] <= k_min and k_max <= K_PHYSICAL[1]):
            raise ValueError(f"system_gain K must lie in {list(K_PHYSICAL)} DN/e- (a physical camera), got "
                             f"k_min={k_min}, k_max={k_max}")
        for where, rel in (("read_noise.tukey_scale", tukey_scale), ("read_noise.gaussian_scale", gaussian_scale),
                           ("row_noise.scale", row_scale)):
            for k in (k_min, k_max):
                if rel is not None and not rel.median(k) < span:
                    raise ValueError(f"{where} gives sigma {rel.median(k):.4g} DN at K={k:.4g}, more than the whole "
                                     f"range white - black = {span:g} DN: not a noise scale of this sensor")

        effects = data.get("effects") or {}
        if not isinstance(effects, dict):
            raise ValueError(f"profile 'effects' must be a mapping of effect name -> parameters, got {type(effects).__name__}")
        for name in effects:
            if name not in EFFECTS:
                raise ValueError(f"profile effect {name!r} is not a registered effect; known: {sorted(EFFECTS)}")
            params = effects[name] if isinstance(effects[name], dict) else {}  # a non-mapping: validate_params says so
            private = sorted(k for k in params if isinstance(k, str) and k.startswith("_"))
            if private:
                raise ValueError(f"effect {name!r} parameters hold {private}: an estimator's note for its module's "
                                 f"combine(), not a parameter; pass the per-stack estimates through combine()")
            EFFECTS[name].validate_params(effects[name])

        return cls(
            camera=str(data.get("camera", "unnamed")),
            black_level=black,
            white_level=white,
            bit_depth=bit_depth,
            cfa=cfa,
            k_min=k_min,
            k_max=k_max,
            tukey_scale=tukey_scale,
            gaussian_scale=gaussian_scale,
            row_scale=row_scale,
            tukey_shape=shape_table,
            color_bias=KTable(tuple(bias_k), tuple(bias_rows)),
            quantization_step_dn=step,
            iso_table=iso_table,
            effects=copy.deepcopy(effects),
            source=str(data.get("source", "")),
        )

    # ---------------------------------------------------------------- saving
    def to_dict(self) -> dict:
        gain = {"k_min": self.k_min, "k_max": self.k_max}
        if self.iso_table:
            gain["iso"] = list(self.iso_table[0])
            gain["k"] = list(self.iso_table[1])
        data = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "camera": self.camera,
            "source": self.source,
            "sensor": {
                "black_level": self.black_level,
                "white_level": self.white_level,
                "bit_depth": self.bit_depth,
                "cfa": self.cfa,
            },
            "system_gain": gain,
            "read_noise": {"gaussian_scale": self.gaussian_scale.to_dict()},
            "quantization": {"step_dn": self.quantization_step_dn},
            "color_bias": {"k": list(self.color_bias.k), "dn": [list(r) for r in self.color_bias.values]},
            "effects": copy.deepcopy(self.effects),
        }
        return self._fits(data)

    def _fits(self, data: dict) -> dict:
        if self.tukey_scale is not None:
            data["read_noise"] = {"tukey_scale": self.tukey_scale.to_dict(), **data["read_noise"],
                                  "tukey_shape": {"k": list(self.tukey_shape.k), "lambda": list(self.tukey_shape.values)}}
        if self.row_scale is not None:
            data = {**{k: v for k, v in data.items() if k != "quantization" and k != "color_bias" and k != "effects"},
                    "row_noise": {"scale": self.row_scale.to_dict()},
                    **{k: data[k] for k in ("quantization", "color_bias", "effects")}}
        return data

    @property
    def richest_model(self) -> str:
        """The paper's fullest model this profile can synthesize: ``G*+P*+R+U``, or without
        the parts it has no fit for (``G+P*+U`` for a Poisson-Gaussian profile). The colour
        bias ``C`` is left to the user: it pays when a denoiser is trained at one gain, and
        costs where the black-level error jumps between the gains it is trained over (the
        README's real-noise and TestCam tables)."""
        read = "G*" if self.tukey_scale is not None else "G"
        return "+".join([read, "P*"] + (["R"] if self.row_scale is not None else []) + ["U"])

    def to_yaml(self) -> str:
        """The profile file's text, loaded back and validated first (so no profile that
        ``load`` would refuse is ever written)."""
        text = yaml.safe_dump(self.to_dict(), sort_keys=False)
        NoiseProfile.from_dict(yaml.safe_load(text))
        return text

    def save(self, path) -> None:
        """Write the profile as YAML, atomically (temp file in the same folder, then rename)."""
        write_text_atomic(path, self.to_yaml())

    # ---------------------------------------------------------------- helpers
    @property
    def span_dn(self) -> float:
        """White minus black: the DN that normalized 1.0 stands for."""
        return self.white_level - self.black_level

    def k_at_iso(self, iso: float) -> float:
        """System gain K (DN/e-) at an ISO, by log-log interpolation of the ISO table."""
        iso = _positive(iso, "iso")
        if not self.iso_table:
            raise ValueError(f"profile {self.camera!r} has no system_gain.iso table, so K at ISO {iso} is unknown")
        isos, ks = self.iso_table
        if len(isos) == 1:
            return ks[0] * iso / isos[0]
        lx = [math.log(v) for v in isos]
        ly = [math.log(v) for v in ks]
        x = math.log(iso)
        j = 1
        while j < len(lx) - 1 and x > lx[j]:
            j += 1
        t = (x - lx[j - 1]) / (lx[j] - lx[j - 1])
        return math.exp(ly[j - 1] + t * (ly[j] - ly[j - 1]))

    def with_effect(self, name: str, params: dict) -> "NoiseProfile":
        """A copy of this profile with one more (or a replaced) loop effect."""
        data = self.to_dict()
        data["effects"][name] = params
        return NoiseProfile.from_dict(data)

    def without_effect(self, name: str) -> "NoiseProfile":
        """A copy of this profile without the loop effect ``name``."""
        data = self.to_dict()
        if name not in data["effects"]:
            raise KeyError(f"profile {self.camera!r} has no effect {name!r}; it has {sorted(data['effects'])}")
        del data["effects"][name]
        return NoiseProfile.from_dict(data)
