"""Frame: one raw sensor frame with the levels and CFA needed to read it.

Units: ``mosaic`` holds raw sensor codes (black NOT subtracted); "DN" are
black-subtracted digital numbers; "normalized" is ``DN / (white - black)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..bayer import CFA_PATTERNS, cfa_offsets


def _check_levels(black_level, white_level, where):
    black = np.asarray(black_level, dtype=np.float64)
    if black.ndim not in (0, 1) or (black.ndim == 1 and black.shape[0] != 4):
        raise ValueError(f"{where}: black_level must be a number or 4 values in packed (R, G1, B, G2) order, got {black_level!r}")
    if not np.all(np.isfinite(black)):
        raise ValueError(f"{where}: black_level must be finite, got {black_level!r}")
    try:
        white = float(white_level)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: white_level must be a number, got {white_level!r}") from None
    if not math.isfinite(white) or white <= float(black.max()):
        raise ValueError(f"{where}: white_level must be finite and exceed black_level, got white={white_level!r}, black={black_level!r}")


@dataclass
class Frame:
    """One raw frame.

    Attributes
    ----------
    mosaic : (H, W) raw sensor codes, black not subtracted (uint16 or float).
    black_level : scalar, or 4 values in packed (R, G1, B, G2) order (raw codes).
    white_level : saturation code (raw codes).
    cfa : 'RGGB' | 'BGGR' | 'GRBG' | 'GBRG'.
    iso, exposure_s : capture settings (None when unknown).
    path : where it was read from (None for in-memory frames).
    """

    mosaic: np.ndarray
    black_level: float | tuple
    white_level: float
    cfa: str
    iso: float | None = None
    exposure_s: float | None = None
    path: str | None = None

    def __post_init__(self):
        where = self.path or "frame"
        mosaic = np.asarray(self.mosaic)
        if mosaic.ndim != 2:
            raise ValueError(f"{where}: mosaic must be a 2-D (H, W) Bayer array, got shape {mosaic.shape}")
        if mosaic.shape[0] < 2 or mosaic.shape[1] < 2 or mosaic.shape[0] % 2 or mosaic.shape[1] % 2:
            raise ValueError(f"{where}: mosaic height and width must be even and >= 2, got {mosaic.shape[0]}x{mosaic.shape[1]}")
        if not (np.issubdtype(mosaic.dtype, np.integer) or np.issubdtype(mosaic.dtype, np.floating)):
            raise ValueError(f"{where}: mosaic must hold integer or float codes, got dtype {mosaic.dtype}")
        self.mosaic = mosaic
        self.cfa = str(self.cfa).upper()
        if self.cfa not in CFA_PATTERNS:
            raise ValueError(f"{where}: cfa must be one of {CFA_PATTERNS}, got {self.cfa!r}")
        _check_levels(self.black_level, self.white_level, where)
        if isinstance(self.black_level, (list, tuple, np.ndarray)):
            self.black_level = tuple(float(v) for v in self.black_level)
        else:
            self.black_level = float(self.black_level)
        self.white_level = float(self.white_level)
        for name in ("iso", "exposure_s"):
            value = getattr(self, name)
            if value is not None:
                value = float(value)
                if not math.isfinite(value) or value <= 0:
                    raise ValueError(f"{where}: {name} must be a positive number or None, got {value!r}")
                setattr(self, name, value)

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.mosaic.shape)

    def black_packed(self) -> np.ndarray:
        """Black level per packed channel, shape (4,), raw codes."""
        return np.broadcast_to(np.asarray(self.black_level, dtype=np.float32), (4,)).copy()

    @property
    def span_dn(self) -> float:
        """White minus the largest channel black: the DN that normalized 1.0 stands for."""
        return float(self.white_level - float(np.max(self.black_packed())))

    def packed_dn(self, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """(4, H/2, W/2) float32, black-subtracted DN, in packed (R, G1, B, G2) order; with
        ``window`` (top, left, h, w in packed pixels) only that part (4, h, w)."""
        mosaic = self.mosaic
        if window is not None:
            top, left, h, w = (int(v) for v in window)
            mosaic = mosaic[2 * top : 2 * (top + h), 2 * left : 2 * (left + w)]
        black = self.black_packed()  # the mosaic is 2-D with even sides (checked on creation)
        out = np.empty((4, mosaic.shape[0] // 2, mosaic.shape[1] // 2), dtype=np.float32)
        for i, (r, c) in enumerate(cfa_offsets(self.cfa)):  # one pass per channel, no stacked copy
            np.subtract(mosaic[r::2, c::2], black[i], out=out[i], dtype=np.float32, casting="unsafe")
        return out

    def packed_normalized(self) -> np.ndarray:
        """(4, H/2, W/2) float32: DN / (white - black); 0 is black, 1 is white."""
        return self.packed_dn() / np.float32(self.span_dn)

    def saturated_fraction(self) -> float:
        """Fraction of pixels at or above the white level."""
        return float(np.mean(self.mosaic >= self.white_level))
