"""Bayer packing and level normalization.

Canonical packed order, used everywhere in rawaug: ``(R, G1, B, G2)`` where
``G1`` is the green on the same sensor row as red and ``G2`` the green on the
same sensor row as blue. With this order, for every 2x2 CFA:

* channels 0 and 1 (R, G1) come from one sensor row, channels 2 and 3 (B, G2)
  from the other: they share row noise;
* channels 0 and 3 (R, G2) come from one sensor column, 1 and 2 (G1, B) from
  the other: they share column noise.

Units: "DN" means black-subtracted digital numbers; "normalized" means
``DN / (white - black)``, so 0 is black and 1 is white.
"""
from __future__ import annotations

import numpy as np
import torch

CFA_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
PACKED_ORDER = ("R", "G1", "B", "G2")
ROW_PARTNERS = ((0, 1), (2, 3))  # packed channels sharing a sensor row
COLUMN_PARTNERS = ((0, 3), (1, 2))  # packed channels sharing a sensor column


def cfa_offsets(cfa: str) -> list[tuple[int, int]]:
    """(row, col) offset inside the 2x2 tile of R, G1, B, G2 for a CFA name."""
    cfa = str(cfa).upper()
    if cfa not in CFA_PATTERNS:
        raise ValueError(f"cfa must be one of {CFA_PATTERNS}, got {cfa!r}")
    where = {(i // 2, i % 2): c for i, c in enumerate(cfa)}
    red = next(pos for pos, c in where.items() if c == "R")
    blue = next(pos for pos, c in where.items() if c == "B")
    green_red_row = next(pos for pos, c in where.items() if c == "G" and pos[0] == red[0])
    green_blue_row = next(pos for pos, c in where.items() if c == "G" and pos[0] == blue[0])
    return [red, green_red_row, blue, green_blue_row]


def _check_mosaic(mosaic, name="mosaic"):
    if mosaic.ndim < 2:
        raise ValueError(f"{name} must have at least 2 dimensions (..., H, W), got shape {tuple(mosaic.shape)}")
    h, w = mosaic.shape[-2:]
    if h % 2 or w % 2:
        raise ValueError(f"{name} height and width must be even, got {h}x{w}")


def pack(mosaic, cfa: str = "RGGB"):
    """Bayer mosaic (..., H, W) -> packed (..., 4, H/2, W/2) in R, G1, B, G2 order.

    Works on NumPy arrays and torch tensors alike; the dtype is kept.
    """
    _check_mosaic(mosaic)
    planes = [mosaic[..., r::2, c::2] for r, c in cfa_offsets(cfa)]
    if isinstance(mosaic, torch.Tensor):
        return torch.stack(planes, dim=-3)
    return np.stack(planes, axis=-3)


def unpack(packed, cfa: str = "RGGB"):
    """Packed (..., 4, h, w) in R, G1, B, G2 order -> mosaic (..., 2h, 2w)."""
    if packed.ndim < 3 or packed.shape[-3] != 4:
        raise ValueError(f"packed must have shape (..., 4, h, w), got {tuple(packed.shape)}")
    h, w = packed.shape[-2:]
    shape = tuple(packed.shape[:-3]) + (2 * h, 2 * w)
    if isinstance(packed, torch.Tensor):
        mosaic = packed.new_empty(shape)
    else:
        mosaic = np.empty(shape, dtype=packed.dtype)
    for i, (r, c) in enumerate(cfa_offsets(cfa)):
        mosaic[..., r::2, c::2] = packed[..., i, :, :]
    return mosaic


def dn_to_normalized(dn, black_level: float, white_level: float):
    """Black-subtracted DN -> normalized [0, 1] (white - black maps to 1)."""
    span = float(white_level) - float(black_level)
    if span <= 0:
        raise ValueError(f"white_level must exceed black_level, got white={white_level}, black={black_level}")
    return dn / span


def normalized_to_dn(x, black_level: float, white_level: float):
    """Normalized [0, 1] -> black-subtracted DN."""
    span = float(white_level) - float(black_level)
    if span <= 0:
        raise ValueError(f"white_level must exceed black_level, got white={white_level}, black={black_level}")
    return x * span


def raw_to_normalized(raw, black_level, white_level: float):
    """Raw sensor codes (black not subtracted) -> normalized float32.

    ``black_level`` may be a scalar or a per-packed-channel sequence of 4 when
    ``raw`` is packed (..., 4, h, w).
    """
    raw = np.asarray(raw, dtype=np.float32)
    black = np.asarray(black_level, dtype=np.float32)
    if black.ndim == 1:
        if black.shape[0] != 4 or raw.ndim < 3 or raw.shape[-3] != 4:
            raise ValueError(f"per-channel black_level needs packed (..., 4, h, w) input, got black {black.tolist()} and shape {raw.shape}")
        black = black[:, None, None]
    span = float(white_level) - float(np.max(black))
    if span <= 0:
        raise ValueError(f"white_level must exceed black_level, got white={white_level}, black={black_level}")
    return (raw - black) / span
