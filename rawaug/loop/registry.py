"""Candidate effects of the closed loop: statistic -> effect -> estimator.

Adding an effect to the loop means writing one module in ``rawaug/effects`` (with a
registered ``NoiseEffect``, ``STATISTICS`` and ``estimate``) and listing it here.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType

from ..effects import black_clip, column_noise, dark_shading, frame_black_level, hot_pixels, prnu


@dataclass(frozen=True)
class Candidate:
    token: str
    module: ModuleType

    @property
    def statistics(self) -> tuple[str, ...]:
        return tuple(self.module.STATISTICS)

    @property
    def summary(self) -> str:
        return (self.module.__doc__ or self.token).strip().splitlines()[0]

    def estimate(self, frames, synthesized, k, **kw) -> dict:
        return self.module.estimate(frames, synthesized, k, **kw)


CANDIDATES: dict[str, Candidate] = {
    c.token: c
    for c in (
        Candidate("Col", column_noise),
        Candidate("FPN", dark_shading),
        Candidate("Hot", hot_pixels),
        Candidate("Clip", black_clip),
        Candidate("BLE", frame_black_level),
        Candidate("PRNU", prnu),
    )
}


def effects_for(statistic: str) -> list[str]:
    """Tokens of the candidate effects a statistic points to, in registry order."""
    return [t for t, c in CANDIDATES.items() if statistic in c.statistics]
