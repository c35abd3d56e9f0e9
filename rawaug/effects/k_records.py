"""Shared plumbing of the loop effects: parameters recorded against the gain K, and
seeded fixed patterns.

Effects whose size depends on ISO store one record per calibrated gain::

    {k: [K1, K2, ...], sigma_dn: [s1, s2, ...], ...}

and a synthesized sample uses the record nearest its drawn K (in log K), as the ELD
profiles do for ``tukey_shape`` and ``color_bias``. A fixed pattern (a sensor's
per-pixel or per-column offsets) is keyed by the profile's seed, the sample's sensor
instance (``fixed={"sensor": 0}``: the profile's own, in every frame and every call) and the
pixel position (``rawaug.rng``), so it is identical on every device and nothing is stored.
"""
from __future__ import annotations

import math

import torch

from ..relations import KTable
from ..validate import finite as _number
from .base import nearest_in_k


def validate_records(token: str, params, keys: tuple[str, ...], nonnegative: tuple[str, ...] = ()) -> None:
    """Check ``{k: [...], key: [...]}`` records: equal non-empty lengths, K > 0, finite values."""
    if not isinstance(params, dict):
        raise ValueError(f"effect {token!r} parameters must be a mapping, got {params!r}")
    ks = params.get("k")
    if not isinstance(ks, (list, tuple)) or not ks:
        raise ValueError(f"effect {token!r} needs a non-empty list 'k' (gain K per record, DN/e-), got {ks!r}")
    for v in ks:
        if _number(v, f"{token}.k[]") <= 0:
            raise ValueError(f"effect {token!r}: every k must be > 0, got {v}")
    for key in keys:
        vals = params.get(key)
        if not isinstance(vals, (list, tuple)) or len(vals) != len(ks):
            raise ValueError(f"effect {token!r} needs '{key}' with one value per k ({len(ks)}), got {vals!r:.80}")
        for v in vals:
            if isinstance(v, (list, tuple)):
                continue  # nested records (maps) are checked by the effect
            v = _number(v, f"{token}.{key}[]")
            if key in nonnegative and v < 0:
                raise ValueError(f"effect {token!r}: {key} must be >= 0, got {v}")


def frame_size(token: str, params: dict) -> tuple[int, int] | None:
    """``(frame_h, frame_w)``: the packed frame size a spatial pattern was measured on
    (optional; None for profiles written before it was stored)."""
    if "frame_h" not in params and "frame_w" not in params:
        return None
    h, w = params.get("frame_h"), params.get("frame_w")
    for name, v in (("frame_h", h), ("frame_w", w)):
        if not isinstance(v, int) or isinstance(v, bool) or not 1 <= v <= 1 << 20:
            raise ValueError(f"effect {token!r}: {name} must be a whole number of packed pixels in [1, 2^20], got {v!r}")
    return h, w


def check_edges(token: str, params: dict, key: str = "col_edges", most: int = 7) -> None:
    """``params[key]``: at most ``most`` whole sensor columns strictly increasing inside the
    measured frame (``frame_w`` packed columns: ``(0, 2 frame_w)``); ValueError naming them
    otherwise (the frame size is required)."""
    size = frame_size(token, params)
    if size is None:
        raise ValueError(f"effect {token!r} needs frame_h and frame_w (packed pixels of the frame its edges are on)")
    edges = params.get(key)
    if not isinstance(edges, (list, tuple)) or len(edges) > most:
        raise ValueError(f"effect {token!r}: {key} must be a list of at most {most} sensor columns, got {edges!r:.80}")
    for e in edges:
        if isinstance(e, bool) or not isinstance(e, int) or not 0 < e < 2 * size[1]:
            raise ValueError(f"effect {token!r}: {key} values must be whole sensor columns in (0, {2 * size[1]}), got {e!r}")
    if list(edges) != sorted(set(edges)):
        raise ValueError(f"effect {token!r}: {key} must be strictly increasing, got {list(edges)}")


def record_index(params: dict, k: torch.Tensor) -> torch.Tensor:
    """(B,) index of the record nearest each K (log distance; first of ties)."""
    table = KTable(tuple(float(v) for v in params["k"]), tuple(float(i) for i in range(len(params["k"]))))
    return nearest_in_k(table, k).round().to(torch.int64)


def value_at_k(params: dict, key: str, k: torch.Tensor) -> torch.Tensor:
    """(B,) value of ``params[key]`` at the record nearest each K, float64."""
    table = KTable(tuple(float(v) for v in params["k"]), tuple(float(v) for v in params[key]))
    return nearest_in_k(table, k)


def merge_records(records: list[dict]) -> dict:
    """Concatenate single-K records (as estimated per ISO) into one parameter dict,
    sorted by K. List-valued keys are concatenated, scalar keys taken from the first."""
    if not records:
        raise ValueError("merge_records needs at least one record")
    order = sorted(range(len(records)), key=lambda i: float(records[i]["k"][0]))
    out: dict = {}
    for i in order:
        for key, val in records[i].items():
            if isinstance(val, list):
                out.setdefault(key, []).extend(val)
            else:
                out.setdefault(key, val)
    return out


def combine_mean(records: list[dict], key: str) -> dict:
    """One record per gain from single-K records ``{k: [K], key: [value]}`` (one per stack):
    the stacks at one K averaged."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r[key][0])
    ks = sorted(by_k)
    return {"k": ks, key: [float(sum(v) / len(v)) for v in (by_k[k] for k in ks)]}


def combine_first(records: list[dict], key: str) -> dict:
    """One record per gain from single-K records ``{k: [K], key: [value]}``: the first stack's
    at each K (where every stack of a gain gives the same record, as a flat series' do)."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), r[key][0])
    ks = sorted(by_k)
    return {"k": ks, key: [float(by_k[k]) for k in ks]}


def combine_sigma(records: list[dict], key: str = "sigma_dn") -> dict:
    """One record per gain from single-K records ``{k: [K], key: [sigma]}`` (one per stack):
    the stacks at one K averaged in variance."""
    by_k: dict = {}
    for r in records:
        by_k.setdefault(float(r["k"][0]), []).append(r[key][0] ** 2)
    ks = sorted(by_k)
    return {"k": ks, key: [float(math.sqrt(sum(v) / len(v))) for v in (by_k[k] for k in ks)]}


def check_density(token: str, params: dict, most: float = 0.1, of: str = "pixels") -> float:
    """``params["density"]``, a fraction of ``of`` in [0, most]; ValueError naming it otherwise."""
    density = _number(params.get("density"), f"{token}.density")
    if not 0.0 <= density <= most:
        raise ValueError(f"effect {token!r}: density (fraction of {of}) must be in [0, {most:g}], got {density}")
    return density


def check_gain_pattern(token: str, params, keys: tuple[str, ...]) -> None:
    """A seeded pattern of gains on the photo signal (``PRNU``, ``ColGain``, ``RowGain``): a
    mapping with an integer ``seed`` and each of ``keys`` (absent: 0) a spread that is a fraction
    of the signal, in [0, 0.5)."""
    if not isinstance(params, dict):
        raise ValueError(f"effect {token!r} parameters must be a mapping, got {params!r}")
    check_seed(token, params)
    for key in keys:
        value = _number(params.get(key, 0.0), f"{token}.{key}")
        if not 0.0 <= value < 0.5:
            raise ValueError(f"effect {token!r}: {key} (fraction of the signal) must be in [0, 0.5), got {value}")


def check_seed(token: str, params: dict) -> None:
    seed = params.get("seed")
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"effect {token!r} needs an integer 'seed' >= 0 for its fixed pattern, got {seed!r}")


def window_columns(ctx, token: str, params: dict, names: tuple[str, str, str, str]) -> dict:
    """Kernel columns ``names`` = (oy, ox, h, w) of the window an input is of the measured
    frame: an input smaller than the frame (``frame_h``/``frame_w``) is a window of it at a
    whole-pixel offset drawn per sample (``ctx.uniform``), so a measured pattern keeps its
    scale and place on training crops; an input as large or larger (or a pattern without
    ``frame_h``/``frame_w``) is the sensor (all 0)."""
    frame = frame_size(token, params)
    zero = torch.zeros_like(ctx.k)
    out = {}
    for axis, (oy, size) in enumerate(((names[0], names[2]), (names[1], names[3]))):
        if frame is None or ctx.shape is None or ctx.shape[axis] >= frame[axis]:
            out[oy], out[size] = zero, zero
        else:
            room = frame[axis] - ctx.shape[axis] + 1
            out[oy] = torch.floor(ctx.uniform(oy) * room).clamp(max=room - 1)
            out[size] = torch.full_like(ctx.k, float(frame[axis]))
    return out


def column_edge_columns(ctx, token: str, params: dict, prefix: str, most: int) -> dict:
    """Kernel columns of a profile's column-tap edges (``col_edges``, sensor columns of the
    measured frame): ``{prefix}_c0 .. c{most - 1}`` the edges as fractions of the frame's sensor
    columns (2: none), and ``{prefix}_ox``/``_w`` the window an input is of the frame
    (``window_columns``)."""
    n = ctx.k.shape[0]
    _, w = frame_size(token, params)
    edges = params["col_edges"]
    out = {f"{prefix}_c{i}": ctx.k.new_full((n,), edges[i] / (2.0 * w) if i < len(edges) else 2.0) for i in range(most)}
    window = window_columns(ctx, token, params, tuple(f"{prefix}_{name}" for name in ("oy", "ox", "h", "w")))
    out[f"{prefix}_ox"], out[f"{prefix}_w"] = window[f"{prefix}_ox"], window[f"{prefix}_w"]
    return out


def grid_columns(ctx, token: str, params: dict, prefix: str) -> dict:
    """Kernel columns of a grid measured over a frame (``FPN`` shading, ``Glow``):
    ``{prefix}_record`` (the record nearest each K, in the call's shared grids table),
    ``{prefix}_gh``/``_gw`` (its size) and its window (``window_columns``)."""
    first, gh, gw = ctx.grid_slot(token)
    out = {f"{prefix}_record": (first + record_index(params, ctx.k)).to(torch.float64),
           f"{prefix}_gh": torch.full_like(ctx.k, float(gh)), f"{prefix}_gw": torch.full_like(ctx.k, float(gw))}
    out.update(window_columns(ctx, token, params, tuple(f"{prefix}_{n}" for n in ("oy", "ox", "h", "w"))))
    return out


def all_zero(params: dict, keys) -> bool:
    """True when every value under ``keys`` (numbers or nested lists of them) is 0: a record
    that would add nothing (the loop's ``empty`` for noise amplitudes)."""
    def values(v):
        return [x for item in v for x in values(item)] if isinstance(v, (list, tuple)) else [v]
    return all(float(x) == 0.0 for key in keys for x in values(params.get(key, [])))
