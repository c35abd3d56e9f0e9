"""Input checks whose errors name the value and what was expected."""
from __future__ import annotations

import math


def finite(value, where: str) -> float:
    """``value`` as a finite float, else ValueError naming ``where`` and the value."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where} must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{where} must be finite, got {value}")
    return value
