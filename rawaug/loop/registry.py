"""Candidate effects of the closed loop: statistic -> effect -> estimator.

There is one registry, ``rawaug.effects.EFFECTS``: every registered effect whose module
also defines ``STATISTICS`` (what shows it) and ``estimate`` (how it is measured) is a
candidate. Adding an effect to the loop is writing that one module and registering it.
"""
from __future__ import annotations

import inspect
import sys
from dataclasses import dataclass
from types import ModuleType

from ..effects import EFFECTS


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

    def wants(self, argument: str) -> bool:
        """True when the estimator takes ``argument`` by name (one that costs a pass over frames)."""
        return argument in inspect.signature(self.module.estimate).parameters

    def estimate(self, frames, synthesized, k, **kw) -> dict:
        return self.module.estimate(frames, synthesized, k, **kw)


def _candidates() -> dict[str, Candidate]:
    out = {}
    for token, cls in EFFECTS.items():
        module = sys.modules[cls.__module__]
        if hasattr(module, "estimate") and hasattr(module, "STATISTICS"):
            out[token] = Candidate(token, module)
    return out


CANDIDATES: dict[str, Candidate] = _candidates()


def effects_for(statistic: str) -> list[str]:
    """Tokens of the candidate effects a statistic points to, in registry order."""
    return [t for t, c in CANDIDATES.items() if statistic in c.statistics]
