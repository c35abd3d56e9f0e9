"""RawNoiseAugment: the ELD noise formation model as a kornia-style batch augmentation."""
from __future__ import annotations

import os
from typing import Any

import torch
from kornia.augmentation import IntensityAugmentationBase2D

from .effects import EFFECTS
from .effects.base import DrawContext, as_sample, effect_seed, per_sample
from .profile import NoiseProfile

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
    lo, hi = (value, value) if isinstance(value, (int, float)) else tuple(value)
    lo, hi = float(lo), float(hi)
    if not 0 < lo <= hi:
        raise ValueError(f"{name} must be a positive number or a (low, high) pair with 0 < low <= high, got {value!r}")
    return lo, hi


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
            quantization, ``C`` colour bias, and any registered loop effect.
        ratio: low-light factor, a number or a ``(low, high)`` range drawn uniformly.
        k: fix the system gain K (DN/e-), or a ``(low, high)`` range drawn log-uniformly;
            default: the profile's calibrated range.
        iso: fix K to the profile's K at this ISO (overrides ``k``).
        fixed: fix any drawn parameter, e.g. ``{"sigma_tl": 2.0, "lambda": 0.1, "sigma_r": 0.3}``.
        include_profile_effects: also apply every effect in ``profile.effects`` (those the
            closed loop added).
        clip_white: clip the noisy short-exposure signal at white.
        p, same_on_batch, keepdim: kornia conventions. ``same_on_batch`` shares the drawn
            parameters (K, ratio, sigmas, lambda, bias, gate); noise realizations still differ.
        generator: optional ``torch.Generator`` for the per-call seed.
        rank_seeding: offset the seed by the distributed rank, so DDP ranks seeded alike by
            ``seed_everything`` still draw different noise.
        check_finite: refuse NaN/Inf inputs (costs one device sync per call).

    ``aug(x, params=aug._params)`` replays a call bit-exactly: ``_params`` holds the seed
    and the per-sample scalars, never a noise map.
    """

    def __init__(
        self,
        profile: NoiseProfile | str = "SonyA7S2",
        model: str = "G*+P*+R+U",
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
        check_finite: bool = True,
    ) -> None:
        super().__init__(p=p, same_on_batch=same_on_batch, keepdim=keepdim)
        if not 0.0 <= float(p) <= 1.0:
            raise ValueError(f"p must be in [0, 1], got {p}")
        self.profile = NoiseProfile.load(profile)
        self.model = model
        tokens = parse_model(model)
        if include_profile_effects:
            tokens += [t for t in self.profile.effects if t not in tokens]
        effects = [EFFECTS[t](self.profile) for t in tokens]
        self.effects = torch.nn.ModuleList(sorted(effects, key=lambda e: e.order))
        self.ratio = _range(ratio, "ratio")
        if iso is not None:
            k = self.profile.k_at_iso(iso)
        self.k_range = _range(k, "k") if k is not None else (self.profile.k_min, self.profile.k_max)
        self.fixed = dict(fixed or {})
        self.clip_white = bool(clip_white)
        self.generator = generator
        self.rank_seeding = bool(rank_seeding)
        self.check_finite = bool(check_finite)

    # ------------------------------------------------------------------ parameters
    def _new_seed(self) -> int:
        gen = self.generator
        if gen is not None:
            seed = int(torch.randint(0, 2**62, (1,), generator=gen, device=gen.device).item())
        else:
            seed = int(torch.randint(0, 2**62, (1,)).item())
        if self.rank_seeding:
            seed = (seed + _rank() * _GOLDEN) % (2**63 - 1)
        return seed

    def draw_parameters(self, batch: int, device: torch.device | str = "cpu", seed: int | None = None) -> dict:
        """All per-sample parameters of one call, drawn on ``device`` from one seed."""
        seed = self._new_seed() if seed is None else int(seed)
        gen = torch.Generator(device=device)
        gen.manual_seed(effect_seed(seed, "parameters"))
        n = 1 if self.same_on_batch else batch

        def uniform():
            u = torch.rand(n, device=device, generator=gen, dtype=torch.float64)
            return u.expand(batch) if n == 1 else u

        gate = self._gate(batch, seed)
        lo, hi = torch.log(torch.tensor(self.k_range, dtype=torch.float64, device=device))
        k = torch.exp(lo + (hi - lo) * uniform())
        if "k" in self.fixed:
            k = as_sample(self.fixed["k"], batch, device)
        ratio = self.ratio[0] + (self.ratio[1] - self.ratio[0]) * uniform()
        if "ratio" in self.fixed:
            ratio = as_sample(self.fixed["ratio"], batch, device)
        ctx = DrawContext(self.profile, k, batch, n, gen, self.fixed)
        params: dict[str, Any] = {"seed": torch.tensor([seed], dtype=torch.int64), "batch_prob": gate, "k": k, "ratio": ratio}
        for effect in self.effects:
            params.update(effect.draw(ctx))
        return params

    def _gate(self, batch: int, seed: int) -> torch.Tensor:
        """Per-sample apply/skip decision, (B,) bool on the CPU (kornia blends with it)."""
        gen = torch.Generator().manual_seed(effect_seed(seed, "gate"))
        u = torch.rand(1 if self.same_on_batch else batch, generator=gen, dtype=torch.float64)
        return (u < self.p).expand(batch) if self.same_on_batch else u < self.p

    def forward_parameters(self, batch_shape) -> dict:
        """Called by kornia containers, which do not pass the device: record the seed and the
        gate here; ``apply_transform`` draws the rest on the input's device from the seed."""
        seed = self._new_seed()
        return {"seed": torch.tensor([seed], dtype=torch.int64), "batch_prob": self._gate(batch_shape[0], seed)}

    # ------------------------------------------------------------------ checks
    def _check_input(self, x) -> None:
        if not isinstance(x, torch.Tensor):
            raise TypeError(f"input must be a torch.Tensor, got {type(x).__name__}")
        if not x.is_floating_point():
            raise TypeError(f"input must be a floating-point tensor (normalized [0, 1]), got dtype {x.dtype}")
        if x.ndim not in (3, 4) or x.shape[-3] != 4:
            raise ValueError(f"input must be packed Bayer of shape (B, 4, H, W) or (4, H, W), got {tuple(x.shape)}")
        if self.check_finite and x.numel() and not bool(torch.isfinite(x).all()):
            raise ValueError("input holds NaN or Inf values; expected finite normalized intensities")

    # ------------------------------------------------------------------ kornia hooks
    def forward(self, input: torch.Tensor, params: dict | None = None, **kwargs) -> torch.Tensor:
        self._check_input(input)
        if params is None:
            batch = input.shape[0] if input.ndim == 4 else 1
            params = self.draw_parameters(batch, input.device)
        return super().forward(input, params=params, **kwargs)

    def apply_transform(self, input, params, flags, transform=None) -> torch.Tensor:
        if "k" not in params:  # container path: finish the (deterministic) draws on the device
            drawn = self.draw_parameters(input.shape[0], input.device, seed=int(params["seed"].reshape(-1)[0]))
            params = {**drawn, **params}
        if params["ratio"].shape[0] != input.shape[0]:
            raise ValueError(f"params were drawn for {params['ratio'].shape[0]} samples, got a batch of {input.shape[0]}")
        work = input.to(torch.float32) if input.dtype in (torch.float16, torch.bfloat16) else input
        span = self.profile.span_dn
        ratio = per_sample(params["ratio"].to(work.device)).to(work.dtype)
        signal = work * (span / ratio)  # DN at the sensor; the working tensor every stage updates
        clean_dn = signal.clone() if any(e.uses_clean for e in self.effects) else None
        seed = int(params["seed"].reshape(-1)[0])
        for effect in self.effects:
            gen = torch.Generator(device=work.device)
            gen.manual_seed(effect_seed(seed, effect.token))
            signal = effect(signal, clean_dn, params, gen)
        if self.clip_white:
            signal = torch.clamp(signal, max=span)
        return (signal * (ratio / span) if signal.requires_grad else signal.mul_(ratio / span)).to(input.dtype)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["generator"] = None  # torch.Generator does not pickle; a copy draws from the global RNG
        return state

    def extra_repr(self) -> str:
        return f"camera={self.profile.camera!r}, model={self.model!r}, ratio={self.ratio}, k={self.k_range}, p={self.p}"
