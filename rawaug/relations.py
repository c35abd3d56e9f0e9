"""Noise-scale relations on the gain K and values recorded against K: the two shapes every
calibrated parameter of a profile takes (no imports from the rest of rawaug but ``validate``)."""
from __future__ import annotations

import math
from dataclasses import dataclass

from .validate import finite as _finite


def _require(mapping, key, where):
    if not isinstance(mapping, dict):
        raise ValueError(f"{where} must be a mapping, got {type(mapping).__name__}")
    if key not in mapping:
        raise ValueError(f"profile is missing required field '{where}.{key}'")
    return mapping[key]


@dataclass(frozen=True)
class LogLinear:
    """``log(sigma) = slope * log(K) + intercept + N(0, residual_std^2)``, optionally
    piecewise in K (``segments``) and with a noise floor (``floor_dn``)."""

    slope: float
    intercept: float
    residual_std: float
    k_from: float = 0.0  # this relation applies for K >= k_from (segments only)
    segments: tuple["LogLinear", ...] = ()
    floor_dn: float = 0.0

    @classmethod
    def from_dict(cls, data, where):
        if isinstance(data, dict) and "segments" in data:
            segs = data["segments"]
            if not isinstance(segs, list) or not segs:
                raise ValueError(f"{where}.segments must be a non-empty list, got {segs!r}")
            parts = tuple(cls.from_dict(s, f"{where}.segments[{i}]") for i, s in enumerate(segs))
            parts = tuple(sorted(parts, key=lambda s: s.k_from))
            floor = _finite(data.get("floor_dn", 0.0), f"{where}.floor_dn")
            first = parts[0]
            return cls(first.slope, first.intercept, first.residual_std, 0.0, parts, floor)
        slope = _finite(_require(data, "slope", where), f"{where}.slope")
        intercept = _finite(_require(data, "intercept", where), f"{where}.intercept")
        resid = _finite(_require(data, "residual_std", where), f"{where}.residual_std")
        if resid < 0:
            raise ValueError(f"{where}.residual_std must be >= 0, got {resid}")
        k_from = _finite(data.get("k_from", 0.0), f"{where}.k_from")
        floor = _finite(data.get("floor_dn", 0.0), f"{where}.floor_dn")
        if floor < 0:
            raise ValueError(f"{where}.floor_dn must be >= 0, got {floor}")
        return cls(slope, intercept, resid, k_from, (), floor)

    def to_dict(self):
        if self.segments:
            out = {"segments": [s.to_dict() for s in self.segments]}
        else:
            out = {"slope": self.slope, "intercept": self.intercept, "residual_std": self.residual_std}
            if self.k_from:
                out["k_from"] = self.k_from
        if self.floor_dn:
            out["floor_dn"] = self.floor_dn
        return out

    def pieces(self):
        """The (k_from, slope, intercept, residual_std) rows, sorted by k_from."""
        parts = self.segments or (self,)
        return [(p.k_from, p.slope, p.intercept, p.residual_std) for p in parts]

    def median(self, k: float) -> float:
        """Median sigma (DN) at gain K, without the residual draw."""
        row = [p for p in self.pieces() if p[0] <= k] or self.pieces()[:1]
        _, slope, intercept, _ = row[-1]
        line = math.exp(slope * math.log(k) + intercept)
        return math.sqrt(line**2 + self.floor_dn**2)


@dataclass(frozen=True)
class KTable:
    """Values recorded at calibration frames, against the K they were measured at."""

    k: tuple[float, ...]
    values: tuple  # scalars or 4-tuples

    def nearest(self, k: float):
        i = min(range(len(self.k)), key=lambda j: abs(math.log(self.k[j]) - math.log(k)))
        return self.values[i]
