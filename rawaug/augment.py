"""RawNoiseAugment: the ELD noise formation model as a kornia-style batch augmentation."""
from __future__ import annotations

import math
import os

import numpy as np
import torch
from kornia.augmentation import IntensityAugmentationBase2D

from .cpu.poisson import stream_keys as shot_streams
from .effects import EFFECTS
from .effects.base import DrawContext, as_sample, stack_grids
from .engine import layout as L
from .engine.backend import synthesize_op
from .engine.transfer import to_device
from .profile import NoiseProfile
from .rng import host_unit, stream_key

PAPER_MODELS = ("G", "G+P", "G+P*", "G*+P*", "G*+P*+R", "G*+P*+R+U")
_EXCLUSIVE = ({"G", "G*"}, {"P", "P*"})
_GOLDEN = 0x9E3779B97F4A7C15


def parse_model(model: str) -> list[str]:
    """``"G*+P*+R+U"`` -> ``["G*", "P*", "R", "U"]``, checked against the effect registry."""
    if not isinstance(model, str) or not model.strip():
        raise ValueError(f"model must be a non-empty string like 'G*+P*+R+U', got {model!r}")
    tokens = [t.strip() for t in model.split("+")]
    for t in tokens:
        if t not in EFFECTS:
            raise ValueError(f"unknown noise component {t!r} in model {model!r}; known: {sorted(EFFECTS)}")
    if len(set(tokens)) != len(tokens):
        raise ValueError(f"model {model!r} names a component twice")
    for pair in _EXCLUSIVE:
        if pair <= set(tokens):
            raise ValueError(f"model {model!r} has both {sorted(pair)}: pick one")
    return tokens


def _rank() -> int:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank()
    return int(os.environ.get("RANK", os.environ.get("LOCAL_RANK", 0)))


def _range(value, name):
    try:
        lo, hi = (value, value) if isinstance(value, (int, float)) else tuple(value)
        lo, hi = float(lo), float(hi)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number or a (low, high) pair, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(f"{name} must be a finite positive number or a (low, high) pair with 0 < low <= high, got {value!r}")
    return lo, hi


# Keys of ``fixed=``: what each fixes, and the values it takes.
FIXED_KEYS = {
    "k": "system gain K, DN/e- (> 0)",
    "ratio": "low-light ratio (> 0)",
    "sigma_tl": "Tukey-lambda read-noise scale, DN (>= 0)",
    "lambda": "Tukey-lambda shape, in [-1, 1]",
    "sigma_g": "Gaussian read-noise sigma, DN (>= 0)",
    "sigma_r": "row-noise sigma, DN (>= 0)",
    "step_dn": "quantization step, DN (> 0)",
    "color_bias_dn": "per-channel black-level error, DN (4 values R, G1, B, G2)",
    "exposure_s": "exposure time, seconds, for the dark signal of a profile's Dark, DarkHot, DarkCluster, DarkRTS, DarkCol, DarkRow, Glow, DarkDrift and DarkOffset effects and the noise of DarkNoise (>= 0)",
    "sensor": f"sensor instance of the fixed patterns, an integer in [0, {L.SENSORS}); 0 is the profile's own",
    "sequence": "1: the batch's samples are consecutive frames of one sequence, in order (a profile's BlackDrift and DarkDrift "
                "walk across them); 0 (default): independent shots",
}


def check_fixed(fixed) -> dict:
    """Validate ``fixed=``: known keys, finite values in range (errors name the value)."""
    if fixed is None:
        return {}
    if not isinstance(fixed, dict):
        raise ValueError(f"fixed must be a mapping of parameter name -> value, got {type(fixed).__name__}")
    out = {}
    for key, value in fixed.items():
        if key not in FIXED_KEYS:
            raise ValueError(f"unknown fixed parameter {key!r}; known: " + ", ".join(f"{k} ({v})" for k, v in FIXED_KEYS.items()))
        values = torch.as_tensor(value, dtype=torch.float64).reshape(-1)
        if key == "color_bias_dn" and values.numel() % 4:
            raise ValueError(f"fixed color_bias_dn must hold 4 values per sample (R, G1, B, G2), got {value!r}")
        if values.numel() == 0 or not bool(torch.isfinite(values).all()):
            raise ValueError(f"fixed {key} must be finite, got {value!r}")
        lo = float(values.min())
        if key in ("k", "ratio", "step_dn") and lo <= 0:
            raise ValueError(f"fixed {key} must be > 0 ({FIXED_KEYS[key]}), got {value!r}")
        if (key.startswith("sigma") or key == "exposure_s") and lo < 0:
            raise ValueError(f"fixed {key} must be >= 0 ({FIXED_KEYS[key]}), got {value!r}")
        if key == "lambda" and not (-1.0 <= lo and float(values.max()) <= 1.0):
            raise ValueError(f"fixed lambda must be in [-1, 1], got {value!r}")
        if key == "sensor" and not (lo >= 0 and float(values.max()) < L.SENSORS and bool((values == values.round()).all())):
            raise ValueError(f"fixed sensor must be an integer in [0, {L.SENSORS}) ({FIXED_KEYS[key]}), got {value!r}")
        if key == "sequence" and not (values.numel() == 1 and float(values[0]) in (0.0, 1.0)):
            raise ValueError(f"fixed sequence must be 0 or 1 ({FIXED_KEYS[key]}), got {value!r}")
        out[key] = value
    return out


class RawNoiseAugment(IntensityAugmentationBase2D):
    r"""Turn clean packed-Bayer batches into realistic low-light noisy ones (ELD, CVPR 2020).

    Input: ``(B, 4, H, W)`` or ``(4, H, W)`` float tensor, packed (R, G1, B, G2), normalized
    (0 = black, 1 = white). Output: same shape, dtype and device, normalized.

    The simulation walks the paper's pipeline per sample: normalized -> DN -> divide by the
    low-light ratio -> noise stages in physical order (shot noise acts on electrons
    ``D / K``; read, row, quantization noise and colour bias act in DN) -> multiply the
    ratio back -> normalized. Negative values are kept by default: a real raw file stores
    codes below the black level, the read noise of dark pixels is zero-mean only if its
    negative half survives, and clipping it would bias every dark region a denoiser sees.

    Args:
        profile: a ``NoiseProfile``, a built-in camera name or a profile file path.
        model: components joined by ``+``: ``G`` / ``G*`` read noise (Gaussian / Tukey lambda),
            ``P`` / ``P*`` shot noise (Gaussian approx. / Poisson), ``R`` row noise, ``U``
            quantization, ``C`` colour bias, and any registered loop effect. Default: the
            profile's ``richest_model`` (``G*+P*+R+U``, or ``G+P*+U`` for a Poisson-Gaussian
            profile without Tukey-lambda and row-noise fits).
        ratio: low-light factor, a number or a ``(low, high)`` range drawn uniformly.
        k: fix the system gain K (DN/e-), or a ``(low, high)`` range drawn log-uniformly;
            default: the profile's calibrated range.
        iso: fix K to the profile's K at this ISO (overrides ``k``).
        fixed: fix any drawn parameter, e.g. ``{"sigma_tl": 2.0, "lambda": 0.1, "sigma_r": 0.3}``.
            ``{"sensor": 0}``: every sample gets the profile's own fixed patterns (one camera);
            by default each sample draws a sensor instance of its own.
        include_profile_effects: also apply every effect in ``profile.effects`` (those the
            closed loop added).
        clip_white: clip the noisy short-exposure signal at white.
        p, same_on_batch, keepdim: kornia conventions. ``same_on_batch`` shares the drawn
            parameters (K, ratio, sigmas, lambda, bias, gate); noise realizations still differ.
        generator: optional ``torch.Generator`` for the per-call seed.
        rank_seeding: offset the seed by the distributed rank, so DDP ranks seeded alike by
            ``seed_everything`` still draw different noise.
        check_finite: refuse NaN/Inf inputs. ``None`` (default): where it is free (the CPU
            kernel counts them as it reads; on CUDA they come out as NaN, no sync); ``True``:
            also on CUDA (one device sync per call); ``False``: never.

    ``aug(x, params=aug._params)`` replays a call bit-exactly: ``_params`` holds the seed
    and the per-sample scalars, never a noise map.
    """

    def __init__(
        self,
        profile: NoiseProfile | str = "SonyA7S2",
        model: str | None = None,
        ratio: float | tuple[float, float] = (100.0, 300.0),
        k: float | tuple[float, float] | None = None,
        iso: float | None = None,
        fixed: dict | None = None,
        include_profile_effects: bool = True,
        clip_white: bool = False,
        p: float = 1.0,
        same_on_batch: bool = False,
        keepdim: bool = False,
        generator: torch.Generator | None = None,
        rank_seeding: bool = True,
        check_finite: bool | None = None,
    ) -> None:
        super().__init__(p=p, same_on_batch=same_on_batch, keepdim=keepdim)
        if not 0.0 <= float(p) <= 1.0:
            raise ValueError(f"p must be in [0, 1], got {p}")
        self.profile = NoiseProfile.load(profile)
        self.fixed = check_fixed(fixed)
        self.model = model = model if model is not None else self.profile.richest_model
        tokens = parse_model(model)
        if include_profile_effects:
            tokens += [t for t in self.profile.effects if t not in tokens]
        for t in tokens:
            EFFECTS[t].check(self.profile, self.fixed)
        self.effects = sorted((EFFECTS[t](self.profile) for t in tokens), key=lambda e: e.order)
        self._flags = sum(e.flag for e in self.effects) | (L.CLIP_WHITE if clip_white else 0)
        tables = {name: t for e in self.effects for name, t in e.tables().items() if name != "grids"}
        self._grids, self._grid_slots = stack_grids({e.token: e.tables()["grids"] for e in self.effects if "grids" in e.tables()})
        self._code_lut = tables.get("code_lut", torch.zeros(1, 4, 5, dtype=torch.float64))
        self._read_lut = tables.get("read_lut", torch.zeros(1, 2, dtype=torch.float64))
        self._tables_by_device: dict = {}  # the three tables, float64, moved once per device
        self._device_keys: dict = {}  # device -> (seed, its stream keys there): the last call's, for replays
        self.ratio = _range(ratio, "ratio")
        if iso is not None:
            k = self.profile.k_at_iso(iso)
        self.k_range = _range(k, "k") if k is not None else (self.profile.k_min, self.profile.k_max)
        self.clip_white = bool(clip_white)
        self.generator = generator
        self.rank_seeding = bool(rank_seeding)
        self.check_finite = None if check_finite is None else bool(check_finite)

    # ------------------------------------------------------------------ parameters
    def _new_seed(self) -> int:
        """The call seed, a host int from a CPU generator: no device synchronization."""
        gen = self.generator
        if gen is not None and gen.device.type == "cpu":
            seed = int(torch.randint(0, 2**62, (1,), generator=gen).item())
        elif gen is not None:
            seed = int(torch.randint(0, 2**62, (1,), generator=gen, device=gen.device).item())
        else:
            seed = int(torch.randint(0, 2**62, (1,)).item())
        if self.rank_seeding:
            seed = (seed + _rank() * _GOLDEN) % (2**63 - 1)
        return seed

    def draw_parameters(self, batch: int, device: torch.device | str = "cpu", seed: int | None = None,
                        shape: tuple | None = None) -> dict:
        """All per-sample parameters of one call as ``values`` (B, P) float64 on ``device``
        (columns: ``rawaug.engine.layout.COLUMNS``), drawn counter-based from one seed.
        ``shape`` (H, W) of the input's packed channels places patterns measured on a larger
        sensor (``FPN`` shading, ``LowFreq``) at their measured scale; without it the input
        is taken for the whole sensor."""
        seed = self._new_seed() if seed is None else int(seed)
        target, device = torch.device(device), torch.device("cpu")  # (B, P) scalars: drawn on the host, moved once
        n = 1 if self.same_on_batch else batch
        ctx = DrawContext(self.profile, torch.ones(batch, dtype=torch.float64, device=device), batch, n, seed, self.fixed,
                          None if shape is None else (int(shape[0]), int(shape[1])), self._grid_slots)
        lo, hi = math.log(self.k_range[0]), math.log(self.k_range[1])
        k = torch.exp(lo + (hi - lo) * ctx.uniform("k")) if "k" not in self.fixed else as_sample(self.fixed["k"], batch, device)
        ratio = (self.ratio[0] + (self.ratio[1] - self.ratio[0]) * ctx.uniform("ratio") if "ratio" not in self.fixed
                 else as_sample(self.fixed["ratio"], batch, device))
        ctx.k = k
        table = np.zeros((batch, L.N_COLUMNS))  # filled in numpy: a column costs a microsecond, not a torch call
        table[:, L.COLUMN["k"]] = k.numpy()
        table[:, L.COLUMN["ratio"]] = ratio.numpy()
        table[:, L.COLUMN["sensor"]] = (torch.floor(ctx.uniform("sensor") * L.SENSORS) if "sensor" not in self.fixed
                                        else as_sample(self.fixed["sensor"], batch, device)).numpy()
        for effect in self.effects:
            for name, column in effect.draw(ctx).items():
                table[:, L.COLUMN[name]] = column.numpy()
        values = torch.from_numpy(table)
        if target.type != "cpu":
            values = to_device(values, target)
        return {"seed": torch.tensor([seed], dtype=torch.int64), "batch_prob": self._gate(batch, seed), "values": values}

    def sample_parameters(self, params: dict) -> dict[str, torch.Tensor]:
        """The (B,) per-sample parameters of a call by name (``k``, ``ratio`` and the columns
        of this model's effects)."""
        names = ["k", "ratio"] + [c for e in self.effects for c in e.columns]
        return {name: params["values"][:, L.COLUMN[name]] for name in names}

    def _gate(self, batch: int, seed: int) -> torch.Tensor:
        """Per-sample apply/skip decision, (B,) bool on the CPU (kornia blends with it)."""
        u = host_unit(stream_key(seed, "gate"), 1 if self.same_on_batch else batch)
        return (u < self.p).expand(batch) if self.same_on_batch else u < self.p

    def forward_parameters(self, batch_shape) -> dict:
        """Called by kornia containers, which do not pass the device: record the seed and the
        gate here; ``apply_transform`` draws the rest on the input's device from the seed."""
        seed = self._new_seed()
        return {"seed": torch.tensor([seed], dtype=torch.int64), "batch_prob": self._gate(batch_shape[0], seed)}

    def _stream_keys(self, seed: int) -> torch.Tensor:
        keys = [stream_key(seed, "stream:" + name) for name in L.STREAMS]
        keys[L.STREAM["shot_rest"]], keys[L.STREAM["shot_coarse"]] = shot_streams(keys[L.STREAM["shot"]])[1:]
        for effect in self.effects:
            for slot, key in effect.pattern_streams().items():
                keys[L.STREAM[slot]] = key
        return torch.tensor(keys, dtype=torch.int64)

    # ------------------------------------------------------------------ checks
    def _check_input(self, x) -> None:
        if not isinstance(x, torch.Tensor):
            raise TypeError(f"input must be a torch.Tensor, got {type(x).__name__}")
        if not x.is_floating_point():
            raise TypeError(f"input must be a floating-point tensor (normalized [0, 1]), got dtype {x.dtype}")
        if x.ndim not in (3, 4) or x.shape[-3] != 4:
            raise ValueError(f"input must be packed Bayer of shape (B, 4, H, W) or (4, H, W), got {tuple(x.shape)}")
        if self.check_finite is True and x.device.type != "cpu" and x.numel() and not bool(torch.isfinite(x).all()):
            raise ValueError("input holds NaN or Inf values; expected finite normalized intensities")

    # ------------------------------------------------------------------ kornia hooks
    def forward(self, input: torch.Tensor, params: dict | None = None, **kwargs) -> torch.Tensor:
        self._check_input(input)
        if params is None:
            batch = input.shape[0] if input.ndim == 4 else 1
            params = self.draw_parameters(batch, "cpu", shape=input.shape[-2:])  # moved with the keys in apply_transform
        return super().forward(input, params=params, **kwargs)

    def apply_transform(self, input, params, flags, transform=None) -> torch.Tensor:
        if "values" not in params:  # container path: finish the (deterministic) draws from the seed
            drawn = self.draw_parameters(input.shape[0], "cpu", seed=int(params["seed"].reshape(-1)[0]),
                                         shape=input.shape[-2:])
            params = {**drawn, **params}
        values = params["values"]
        if values.shape[0] != input.shape[0]:
            raise ValueError(f"params were drawn for {values.shape[0]} samples, got a batch of {input.shape[0]}")
        work = input.detach()
        if work.dtype not in (torch.float32, torch.float64):
            work = work.to(torch.float32)  # half inputs: computed in float32, rounded once at the end
        seed = int(params["seed"].reshape(-1)[0])
        keys = self._stream_keys(seed)
        if work.device.type != "cpu":  # one pinned, non-blocking copy of both: no host synchronization
            last = self._device_keys.get(str(work.device))
            # a replay of the last call's seed needs no copy of the keys, so a CUDA graph captured
            # after one eager call with the same params holds no copy from (reusable) host memory
            if last is not None and last[0] == seed:
                values, keys = to_device(values, work.device), last[1]
            else:
                values, keys = to_device((values, keys), work.device)
                self._device_keys[str(work.device)] = (seed, keys)
        noisy = synthesize_op(work.contiguous(), values, keys, float(self.profile.span_dn), self._flags, *self._tables_on(work.device),
                             self.check_finite is not False)
        noisy = noisy.to(input.dtype)
        if input.requires_grad:  # straight-through: d noisy / d clean = d E[noisy] / d clean
            noisy = noisy + (input - input.detach()) * self._mean_slope(input.detach(), values)
        return noisy

    def _mean_slope(self, clean, values):
        """d E[noisy] / d clean: 1, or with a gain non-linearity ``1 - c (2 x + K)`` at the clean
        level ``x`` DN (clipping and the other stages' bounds are not counted)."""
        if not self._flags & L.NONLIN:
            return 1.0
        v = values.to(clean.device, torch.float64)
        k, ratio = (v[:, L.COLUMN[n]].view(-1, 1, 1, 1) for n in ("k", "ratio"))
        c = v[:, L.COLUMN["nl_c0"]:L.COLUMN["nl_c0"] + 4].view(-1, 4, 1, 1)  # per channel
        x = clean.to(torch.float64) * float(self.profile.span_dn) / ratio
        return (1.0 - c * (2.0 * x.clamp(min=0.0) + k)).to(clean.dtype)

    def _tables_on(self, device) -> tuple:
        """(grids, code_lut, read_lut) on ``device``, copied there once (not in every call)."""
        key = str(device)
        if key not in self._tables_by_device:
            self._tables_by_device[key] = tuple(t.to(device, torch.float64).contiguous()
                                                for t in (self._grids, self._code_lut, self._read_lut))
        return self._tables_by_device[key]

    def __getstate__(self):
        state = self.__dict__.copy()
        state["generator"] = None  # torch.Generator does not pickle; a copy draws from the global RNG
        state["_tables_by_device"] = {}  # device copies are made again where the copy runs
        state["_device_keys"] = {}
        return state

    def extra_repr(self) -> str:
        return f"camera={self.profile.camera!r}, model={self.model!r}, ratio={self.ratio}, k={self.k_range}, p={self.p}"
