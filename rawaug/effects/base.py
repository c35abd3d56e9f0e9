"""The effect unit: one physical noise stage.

An effect is a small class with

* ``token``: its name in model strings (``"G*+P*+R+U"``) and in ``profile.effects``;
* ``order``: where it acts along photons -> electrons -> voltage -> DN;
* ``flag``: its stage in the fused kernels (``rawaug.engine.layout``); the stage itself,
  what it does to one value given its parameters and random numbers, is written in its
  module's docstring and, once per backend, in ``rawaug/cpu/fused.py`` and
  ``rawaug/gpu/fused.py`` under the same flag;
* ``draw(ctx)``: its per-sample parameters, ``{column: (B,) tensor}`` on the host,
  given the drawn gain K (the (B, P) table then moves to the device in one copy);
* ``pattern_streams()``: keys of its fixed patterns (keyed by the profile's seed, the
  sample's sensor instance and the pixel position: one sensor's are the same in every call),
  and ``tables()`` where it needs a small table.

Effects found by the closed loop also carry ``validate_params`` (for their
``profile.effects`` entry) and, in their own module, ``estimate`` (from measured frames)
and ``STATISTICS`` (which statistic of a measured frame shows them). ``@register`` makes an
effect available by its token to ``RawNoiseAugment`` and to the loop.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

import torch

from ..rng import host_normal, host_unit, stream_key, torch_normal, torch_unit

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
    """What an effect needs to draw its per-sample parameters: all draws are counter-based
    (``rawaug.rng``), keyed by the call seed and a purpose, on the device of ``k`` (the host
    in ``RawNoiseAugment``: numpy counters there)."""

    profile: "object"  # NoiseProfile
    k: torch.Tensor  # (B,) system gain, DN per electron, float64
    batch: int  # B
    n_draw: int  # B, or 1 when same_on_batch
    seed: int
    fixed: dict  # user-fixed parameter values by key
    shape: tuple | None = None  # (H, W) per packed channel of the input, when known
    grid_slots: dict | None = None  # token -> (first record, gh, gw) of its grids in the kernels' grids table

    def grid_slot(self, token: str) -> tuple[int, int, int]:
        """(first record, gh, gw) of ``token``'s grids in the kernels' shared grids table."""
        if not self.grid_slots or token not in self.grid_slots:
            raise RuntimeError(f"effect {token!r} has no grids in this call's table")
        return self.grid_slots[token]

    @property
    def device(self):
        return self.k.device

    def _counter(self):
        return torch.arange(self.n_draw, device=self.device)

    def _expand(self, t):
        return t.expand((self.batch,) + t.shape[1:]) if self.n_draw == 1 else t

    def uniform(self, purpose: str) -> torch.Tensor:
        key = stream_key(self.seed, "parameter:" + purpose)
        u = host_unit(key, self.n_draw) if self.device.type == "cpu" else torch_unit(key, self._counter())
        return self._expand(u)

    def normal(self, purpose: str) -> torch.Tensor:
        key = stream_key(self.seed, "parameter:" + purpose)
        z = host_normal(key, self.n_draw) if self.device.type == "cpu" else torch_normal(key, self._counter())
        return self._expand(z)

    def scale(self, relation, fixed_key: str) -> torch.Tensor:
        """A noise scale (DN) per sample: ``fixed[fixed_key]`` if the user fixed it, else drawn
        from the profile's log-linear relation on K (paper Eq. 7)."""
        value = self.fixed.get(fixed_key)
        if value is not None:
            return as_sample(value, self.batch, self.device)
        return log_linear_draw(relation, torch.log(self.k), self.normal(fixed_key))

    def nearest(self, table, purpose: str) -> torch.Tensor:
        """A KTable's record nearest each drawn K; ties (frames of one ISO) drawn uniformly."""
        return nearest_in_k(table, self.k, self.uniform(purpose))


class NoiseEffect:
    token: ClassVar[str] = ""
    order: ClassVar[int] = 0
    flag: ClassVar[int] = 0  # stage flag of rawaug.engine.layout
    columns: ClassVar[tuple[str, ...]] = ()  # parameter columns this effect fills
    exposure: ClassVar[bool] = False  # it grows with the exposure time (the synthesis setting exposure_s)

    def __init__(self, profile):
        self.profile = profile

    def draw(self, ctx: DrawContext) -> dict[str, torch.Tensor]:
        return {}

    @classmethod
    def check(cls, profile, fixed: dict) -> None:
        """Raise ValueError if ``profile`` (with the user's ``fixed`` values) cannot drive this
        stage, naming what is missing."""

    def pattern_streams(self) -> dict[str, int]:
        """Stream keys of fixed patterns, by stream slot: the same in every call."""
        return {}

    def tables(self) -> dict[str, torch.Tensor]:
        """Small tables the kernels read, by name: ``grids`` (records, gh, gw; several
        effects may have them: ``stack_grids`` joins them), ``code_lut`` (records, 4, n) or
        ``read_lut`` (records x 4, n), float64."""
        return {}

    @classmethod
    def validate_params(cls, params) -> None:
        """Check this effect's ``profile.effects`` entry; raise ValueError naming the bad value."""
        if params not in (None, {}) and not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r}")

    def __repr__(self):
        return f"{type(self).__name__}(token={self.token!r})"


def pattern_key(seed: int, token: str, part: str = "") -> int:
    """Stream key of a fixed pattern: the profile's seed for it, the effect and the part."""
    return stream_key(seed, f"pattern:{token}:{part}")


def as_sample(value, batch, device, dtype=torch.float64):
    """A fixed scalar (or per-sample sequence) as a (B,) tensor."""
    t = torch.as_tensor(value, dtype=dtype, device=device)
    if t.ndim == 0:
        return t.expand(batch)
    if t.shape[0] != batch:
        raise ValueError(f"a fixed per-sample value must have {batch} entries, got {tuple(t.shape)}")
    return t


def log_linear_draw(relation, log_k: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """sigma = exp(slope * log K + intercept + residual_std * z), per segment, with floor."""
    pieces = relation.pieces()
    slope = torch.full_like(log_k, pieces[0][1])
    intercept = torch.full_like(log_k, pieces[0][2])
    resid = torch.full_like(log_k, pieces[0][3])
    for k_from, s, b, r in pieces[1:]:
        above = log_k >= _log(k_from)
        slope = torch.where(above, s, slope)
        intercept = torch.where(above, b, intercept)
        resid = torch.where(above, r, resid)
    sigma = torch.exp(slope * log_k + intercept + resid * z)
    if relation.floor_dn:
        sigma = torch.sqrt(sigma**2 + relation.floor_dn**2)
    return sigma


def _log(v: float) -> float:
    import math

    return math.log(v) if v > 0 else -math.inf


@functools.lru_cache(maxsize=64)
def _table_tensors(table, device: str):
    """(log K, values) of a KTable on a device, built once (not on every call)."""
    log_ks = torch.log(torch.tensor(table.k, dtype=torch.float64)).to(device)
    return log_ks, torch.tensor(table.values, dtype=torch.float64).to(device)


def nearest_in_k(table, k: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:
    """Per-sample value of a KTable at the record nearest the drawn K (in log K). Records at
    the same K (several frames per ISO) are tied: ``u`` (uniform per sample) picks one by
    index arithmetic; without it, the first."""
    log_ks, values = _table_tensors(table, str(k.device))
    dist = (log_ks[None, :] - torch.log(k)[:, None]).abs()
    tied = dist <= dist.min(dim=1, keepdim=True).values + 1e-9
    rank = torch.zeros_like(k, dtype=torch.int64) if u is None else (u * tied.sum(dim=1)).to(torch.int64)
    order = tied.to(torch.int64).cumsum(dim=1) - 1
    idx = ((order == rank[:, None]) & tied).to(torch.int8).argmax(dim=1)
    return values[idx]


def stack_grids(by_token: dict) -> tuple[torch.Tensor, dict]:
    """One grids table for the kernels from each effect's (records, gh, gw) grids: zero-padded
    to the largest gh and gw and stacked in ``by_token``'s order. Returns (table, {token:
    (first record, gh, gw)}); an effect reads its grid ``r`` at record ``first + r`` with its
    own gh x gw. Without grids: one 1x1 zero record."""
    if not by_token:
        return torch.zeros(1, 1, 1, dtype=torch.float64), {}
    gh = max(int(g.shape[1]) for g in by_token.values())
    gw = max(int(g.shape[2]) for g in by_token.values())
    parts, slots, first = [], {}, 0
    for token, g in by_token.items():
        g = torch.as_tensor(g, dtype=torch.float64)
        part = torch.zeros(g.shape[0], gh, gw, dtype=torch.float64)
        part[:, : g.shape[1], : g.shape[2]] = g
        parts.append(part)
        slots[token] = (first, int(g.shape[1]), int(g.shape[2]))
        first += g.shape[0]
    return torch.cat(parts), slots
