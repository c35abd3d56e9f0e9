"""Stuck ADC bits (StuckBit): one or more bits of every raw code the camera writes read 0, or 1,
whatever the converter decided.

Physics: a broken output line of the converter, a firmware's bit mask or a wrong container
shift leaves a bit of the raw code stuck. With bit ``b`` (value ``2^b``) stuck at 0, codes come
in runs of ``2^b`` with gaps of ``2^b`` between them, and a code that had the bit set reads
``2^b`` lower (a 12-bit converter in a 14-bit container is bits 0 and 1 stuck at 0). It acts
on the raw code, black level included: which codes go depends on where black sits, so the
entry keeps the code of 0 DN of each channel.

Stage (DN, after every offset, the code map and dead pixels, before the clips): ``s`` is
rounded to a whole DN, taken to the raw code ``c = s + zero`` (the channel's), and read as
``(c & ~low_mask) | high_mask``, minus ``zero`` again.

Profile entry (one for the camera: the converter's, at every gain)::

    StuckBit: {zero_code: [512, 512, 512, 512], low_mask: 8, high_mask: 0}

(``zero_code``: the raw code of 0 DN per packed channel R, G1, B, G2; ``low_mask`` /
``high_mask``: the bits stuck at 0 / at 1, as an integer's bits.)

Detected by ``code_dnl`` and ``missing_codes`` (the runs and gaps of codes). Estimated by
``estimate`` from raw codes (a stack's DN plus its channels' black codes): a bit is stuck at
0 in a stack when no code has it set while the model's syntheses of that stack set it in
``MIN_EXPECTED`` codes or more (by chance none would, with probability under e^-20), and at
1 likewise; ``combine`` keeps a bit that some stack shows stuck and no stack shows moving.
"""
from __future__ import annotations

import numpy as np
import torch

from ..engine import layout as L
from .base import CLIP, NoiseEffect, register

STATISTICS = ("code_dnl", "missing_codes")
RAW_FRAMES = True  # the codes as written: repairs (defect lines) would write values of their own
SHARES_READ_NOISE = True  # a stuck bit moves half the codes: calibration counted that spread as read noise
BITS = 24  # bits a raw code is checked in
MIN_EXPECTED = 20  # syntheses' codes that set (or clear) a bit, per stack, for its absence to count


@register
class StuckBit(NoiseEffect):
    token = "StuckBit"
    order = CLIP - 2  # on the raw code the converter writes, after dead pixels, before the camera's clips
    flag = L.STUCK_BIT
    columns = ("stuck_z0", "stuck_z1", "stuck_z2", "stuck_z3", "stuck_low", "stuck_high")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        ones = torch.ones(ctx.batch, dtype=torch.float64, device=ctx.device)
        out = {f"stuck_z{c}": ones * float(z) for c, z in enumerate(p["zero_code"])}
        out["stuck_low"] = ones * float(p["low_mask"])
        out["stuck_high"] = ones * float(p.get("high_mask", 0))
        return out

    @classmethod
    def validate_params(cls, params):
        if not isinstance(params, dict):
            raise ValueError(f"effect {cls.token!r} parameters must be a mapping, got {params!r}")
        unknown = set(params) - {"zero_code", "low_mask", "high_mask"}
        if unknown:
            raise ValueError(f"effect {cls.token!r}: unknown keys {sorted(unknown)} (expected zero_code, low_mask, high_mask)")
        zero = params.get("zero_code")
        if not isinstance(zero, (list, tuple)) or len(zero) != 4 or not all(
                isinstance(z, (int, float)) and not isinstance(z, bool) and z == int(z) and 0 <= z < 2 ** BITS for z in zero):
            raise ValueError(f"effect {cls.token!r}: zero_code must hold 4 whole raw codes in [0, 2^{BITS}) (the code of "
                             f"0 DN of R, G1, B, G2), got {zero!r}")
        masks = []
        for key in ("low_mask", "high_mask"):
            m = params.get(key, 0)
            if isinstance(m, bool) or not isinstance(m, (int, float)) or m != int(m) or not 0 <= m < 2 ** BITS:
                raise ValueError(f"effect {cls.token!r}: {key} must be a whole number in [0, 2^{BITS}) (the stuck bits), got {m!r}")
            masks.append(int(m))
        if masks[0] & masks[1]:
            raise ValueError(f"effect {cls.token!r}: a bit cannot be stuck at 0 and at 1: low_mask {masks[0]}, high_mask {masks[1]}")


def stuck_codes(dn, zero_code, low_mask: int, high_mask: int = 0) -> np.ndarray:
    """The stage on a packed array (..., 4, h, w) of DN (NumPy): rounded, as raw codes through the
    stuck bits, back in DN."""
    z = np.asarray(zero_code, dtype=np.float64).reshape(4, 1, 1)
    codes = (np.floor(np.asarray(dn, dtype=np.float64) + 0.5) + z).astype(np.int64)
    return ((codes & ~np.int64(low_mask)) | np.int64(high_mask)) - z


def _bit_counts(codes: np.ndarray) -> np.ndarray:
    """(BITS,) counts of the codes that set each bit (over the histogram of the codes)."""
    lo = int(codes.min())
    counts = np.bincount((codes - lo).ravel())
    values = lo + np.flatnonzero(counts)
    n = counts[counts > 0]
    return np.array([int(n[(values & (1 << b)) != 0].sum()) for b in range(BITS)], dtype=np.int64)


def _raw_codes(frames, black_code) -> np.ndarray:
    return np.rint(np.asarray(frames, dtype=np.float64) + np.asarray(black_code, dtype=np.float64).reshape(4, 1, 1)).astype(np.int64)


def estimate(frames, synthesized, k: float, black_code=None, **_) -> dict:
    """One stack's bits: ``{zero_code, low, high, set, clear}``, masks of the bits no measured code
    sets (``low``) or clears (``high``) while the syntheses do in ``MIN_EXPECTED`` codes or more,
    and of those some measured code sets (``set``) or clears (``clear``)."""
    if black_code is None or not synthesized:
        raise ValueError("StuckBit is measured on raw codes: a stack with its channels' black codes, and its syntheses")
    frames = np.asarray(frames, dtype=np.float64)
    if not np.all(frames == np.rint(frames)):
        raise ValueError("StuckBit needs frames of whole DN (real raw codes)")
    codes = _raw_codes(frames, black_code)
    n = codes.size
    measured = _bit_counts(codes)
    model = np.mean([_bit_counts(_raw_codes(s, black_code)) for s in synthesized], axis=0)
    masks = {"low": (measured == 0) & (model >= MIN_EXPECTED), "high": (measured == n) & (n - model >= MIN_EXPECTED),
             "set": measured > 0, "clear": measured < n}
    out = {key: sum(1 << int(b) for b in np.flatnonzero(m)) for key, m in masks.items()}
    out["zero_code"] = [float(np.rint(z)) for z in np.asarray(black_code, dtype=np.float64).reshape(4)]
    return out


def combine(records: list[dict]) -> dict:
    """The camera's stuck bits: those some stack shows stuck, no stack moving; the zero codes of
    the first stack (every stack of one camera has the same)."""
    set_any = clear_any = low = high = 0
    for r in records:
        set_any, clear_any = set_any | r["set"], clear_any | r["clear"]
        low, high = low | r["low"], high | r["high"]
    return {"zero_code": list(records[0]["zero_code"]), "low_mask": int(low & ~set_any), "high_mask": int(high & ~clear_any)}


def empty(params) -> bool:
    """True when no bit is stuck."""
    return not (int(params["low_mask"]) or int(params.get("high_mask", 0)))
