"""The effect unit: one physical noise stage, synthesized on a batch on the device.

An effect is a small ``nn.Module`` with

* ``token``: its name in model strings (``"G*+P*+R+U"``) and in ``profile.effects``;
* ``order``: where it acts along photons -> electrons -> voltage -> DN;
* ``draw(ctx)``: its per-sample scalar parameters, on the device, given the drawn gain K;
* ``forward(signal_dn, clean_dn, params, generator)``: the batch after this stage, in DN
  at the sensor (black-subtracted, before the low-light ratio is multiplied back).
  ``signal_dn`` is the pipeline's own working tensor: an effect may update it in place
  (``writable``, ``add_noise``) and return it. ``clean_dn`` (the noiseless signal) is passed
  only to effects that set ``uses_clean = True``, else it is None: copying it costs as much
  as drawing a noise component on the CPU.

Effects found by the closed loop also carry ``validate_params`` (for their
``profile.effects`` entry) and, in their own module, how they are estimated and
which statistic of a measured frame shows them. Register new effects with
``@register``; ``RawNoiseAugment`` then uses them by token.
"""
from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import nn

EFFECTS: dict[str, type["NoiseEffect"]] = {}

# Physical stage order (lower acts first).
PHOTON, SHOT, DARK, READ, BANDING, ADC, OFFSET, CLIP = 10, 20, 30, 40, 50, 60, 70, 80


def register(cls):
    """Class decorator: make an effect available by its token."""
    if cls.token in EFFECTS and EFFECTS[cls.token] is not cls:
        raise ValueError(f"effect token {cls.token!r} is already registered by {EFFECTS[cls.token].__name__}")
    EFFECTS[cls.token] = cls
    return cls


@dataclass
class DrawContext:
    """What an effect needs to draw its per-sample parameters."""

    profile: "object"  # NoiseProfile
    k: torch.Tensor  # (B,) system gain, DN per electron
    batch: int  # B
    n_draw: int  # B, or 1 when same_on_batch
    generator: torch.Generator
    fixed: dict  # user-fixed parameter values by key

    @property
    def device(self):
        return self.k.device

    def normal(self):
        z = torch.randn(self.n_draw, device=self.device, generator=self.generator, dtype=torch.float64)
        return z.expand(self.batch) if self.n_draw == 1 else z

    def scale(self, relation, fixed_key: str) -> torch.Tensor:
        """A noise scale (DN) per sample: ``fixed[fixed_key]`` if the user fixed it, else drawn
        from the profile's log-linear relation on K (paper Eq. 7)."""
        value = self.fixed.get(fixed_key)
        if value is not None:
            return as_sample(value, self.batch, self.device)
        return log_linear_draw(relation, torch.log(self.k), self)

    def nearest(self, table) -> torch.Tensor:
        """A KTable's record nearest each drawn K (shared when same_on_batch)."""
        values = nearest_in_k(table, self.k[: self.n_draw], self.generator)
        return values.expand((self.batch,) + values.shape[1:]) if self.n_draw == 1 else values

    def uniform(self):
        u = torch.rand(self.n_draw, device=self.device, generator=self.generator, dtype=torch.float64)
        return u.expand(self.batch) if self.n_draw == 1 else u


class NoiseEffect(nn.Module):
    token: ClassVar[str] = ""
    order: ClassVar[int] = 0
    param_keys: ClassVar[tuple[str, ...]] = ()  # keys this effect records in params
    uses_clean: ClassVar[bool] = False  # forward reads clean_dn

    def __init__(self, profile):
        super().__init__()
        self.profile = profile

    def draw(self, ctx: DrawContext) -> dict[str, torch.Tensor]:
        return {}

    def forward(self, signal_dn, clean_dn, params, generator):  # pragma: no cover - abstract
        raise NotImplementedError

    @classmethod
    def validate_params(cls, params) -> None:
        """Check this effect's ``profile.effects`` entry; raise ValueError naming the bad value."""
        if params not in (None, {}) and not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r}")

    def extra_repr(self):
        return f"token={self.token!r}"


def effect_seed(seed: int, token: str) -> int:
    """Independent generator seed for one effect: replaying or removing one effect never
    changes the noise another draws (ablation rows share their common noise)."""
    return (seed * 1_000_003 + zlib.crc32(token.encode())) % (2**63 - 1)


def _overwritable(signal_dn: torch.Tensor, clean_dn) -> bool:
    return signal_dn is not clean_dn and signal_dn.is_contiguous() and not signal_dn.requires_grad


def writable(signal_dn: torch.Tensor, clean_dn: torch.Tensor) -> torch.Tensor:
    """Where an effect writes its output: ``signal_dn`` itself (the pipeline's working tensor),
    or a new contiguous tensor where it cannot be overwritten. On the CPU a fresh 32 MB
    tensor costs more in page faults than the noise drawn into it."""
    if _overwritable(signal_dn, clean_dn):
        return signal_dn
    return torch.empty(signal_dn.shape, dtype=signal_dn.dtype, device=signal_dn.device)


def add_noise(signal_dn: torch.Tensor, clean_dn: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """``signal_dn + noise``, in place when the pipeline owns ``signal_dn`` and no gradient flows."""
    if _overwritable(signal_dn, clean_dn) and not noise.requires_grad:
        return signal_dn.add_(noise)
    return signal_dn + noise


def key_from(generator: torch.Generator) -> int:
    """A 64-bit stream key for the counter-based CPU kernels, drawn from the effect's generator."""
    return int(torch.randint(0, 2**63 - 1, (1,), generator=generator, dtype=torch.int64).item())


def as_sample(value, batch, device, dtype=torch.float64):
    """A fixed scalar (or per-sample sequence) as a (B,) tensor."""
    t = torch.as_tensor(value, dtype=dtype, device=device)
    if t.ndim == 0:
        return t.expand(batch)
    if t.shape[0] != batch:
        raise ValueError(f"a fixed per-sample value must have {batch} entries, got {tuple(t.shape)}")
    return t


def per_sample(t: torch.Tensor, ndim: int = 4) -> torch.Tensor:
    """(B,) or (B, C) -> broadcastable against (B, C, H, W), float32."""
    t = t.to(torch.float32)
    return t.reshape(t.shape + (1,) * (ndim - t.ndim))


def log_linear_draw(relation, log_k: torch.Tensor, ctx: DrawContext) -> torch.Tensor:
    """sigma = exp(slope * log K + intercept + residual_std * z), per segment, with floor."""
    pieces = relation.pieces()
    slope = torch.full_like(log_k, pieces[0][1])
    intercept = torch.full_like(log_k, pieces[0][2])
    resid = torch.full_like(log_k, pieces[0][3])
    for k_from, s, b, r in pieces[1:]:
        above = log_k >= torch.log(torch.tensor(k_from, dtype=log_k.dtype, device=log_k.device))
        slope = torch.where(above, s, slope)
        intercept = torch.where(above, b, intercept)
        resid = torch.where(above, r, resid)
    sigma = torch.exp(slope * log_k + intercept + resid * ctx.normal())
    if relation.floor_dn:
        sigma = torch.sqrt(sigma**2 + relation.floor_dn**2)
    return sigma


@functools.lru_cache(maxsize=64)
def _table_tensors(table, device: str):
    """(log K, values) of a KTable on a device, built once (not on every forward call)."""
    log_ks = torch.log(torch.tensor(table.k, dtype=torch.float64, device=device))
    return log_ks, torch.tensor(table.values, dtype=torch.float64, device=device)


def nearest_in_k(table, k: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """Per-sample value of a KTable at the record nearest the drawn K (in log K). Records
    measured at the same K (several frames per ISO) are tied: one is drawn uniformly."""
    log_ks, values = _table_tensors(table, str(k.device))
    dist = (log_ks[None, :] - torch.log(k)[:, None]).abs()
    tied = dist <= dist.min(dim=1, keepdim=True).values + 1e-9
    if generator is None:
        idx = tied.to(torch.int8).argmax(dim=1)
    else:
        idx = torch.multinomial(tied.to(torch.float64), 1, generator=generator).squeeze(1)
    return values[idx]
