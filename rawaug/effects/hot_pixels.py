"""Hot pixels (Hot): a sparse set of pixels with a large fixed dark offset.

Physics: crystal defects give a few pixels a dark current far above the rest; in a bias
or short dark frame they sit at a fixed position with a fixed, gain-dependent offset
(stuck-high pixels are the extreme case).

Synthesis: positions are the pixels where a seeded U(0, 1) pattern falls below
``density``; each has a log-normal amplitude ``median_dn * exp(log_std * z)`` with a
seeded standard-normal ``z``; the amplitude scale is a per-K record. The temporal
(shot) noise of a hot pixel's dark current is not modelled. Since the twenty-sixth session a
hot site may be a whole 2x2 tile (``tile_density``, optional: packed positions whose four
pixels carry one amplitude, as a defect of a shared floating diffusion or source follower
makes them), from a seeded pattern of its own.

Profile entry::

    Hot: {seed: 13, density: 1.0e-4, log_std: 0.5, k: [K, ...], median_dn: [...], tile_density: 0.0}

Detected by ``hot_fraction`` (pixels of the stack mean 8 robust sigma above the median)
and ``tail_mass``. Estimated by ``estimate`` on bias and dark stacks: density = excess hot
fraction over the current model (tiles with 3 or 4 hot pixels counted as tiles), amplitudes from the detected pixels (``combine``: one
population over the stacks). Hot pixels dimmer than the 8-sigma
threshold are not seen, so density and median are those of the detectable population.
"""
from __future__ import annotations

import math

import numpy as np
from ..engine import layout as L
from ..statistics import center_scale, grid_step
from .base import DARK, NoiseEffect, pattern_key, register
from .k_records import _number, check_density, check_seed, validate_records, value_at_k

STATISTICS = ("hot_fraction", "tail_mass")
THRESHOLD_SIGMA = 8.0


@register
class HotPixels(NoiseEffect):
    token = "Hot"
    order = DARK
    flag = L.HOT
    columns = ("hot_density", "hot_median", "hot_log_std", "hot_tile_density")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        n = ctx.k.shape[0]
        return {"hot_density": ctx.k.new_full((n,), float(p["density"])), "hot_median": value_at_k(p, "median_dn", ctx.k),
                "hot_log_std": ctx.k.new_full((n,), float(p["log_std"])),
                "hot_tile_density": ctx.k.new_full((n,), float(p.get("tile_density", 0.0)))}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"hot_where": pattern_key(seed, self.token, "where"), "hot_size": pattern_key(seed, self.token, "size"),
                "hot_tile_where": pattern_key(seed, self.token, "tile_where"), "hot_tile_size": pattern_key(seed, self.token, "tile_size")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("median_dn",), nonnegative=("median_dn",))
        check_seed(cls.token, params)
        check_density(cls.token, params)
        if _number(params.get("log_std"), "Hot.log_std") < 0:
            raise ValueError(f"effect 'Hot': log_std must be >= 0, got {params.get('log_std')}")
        if "tile_density" in params and not 0.0 <= _number(params["tile_density"], "Hot.tile_density") <= 0.1:
            raise ValueError(f"effect 'Hot': tile_density (fraction of the 2x2 tiles) must be in [0, 0.1], got {params['tile_density']}")


def detect(frames):
    """Boolean (4, h, w) mask of hot pixels of the stack mean and their amplitude (DN above
    the channel median)."""
    frames = np.asarray(frames, dtype=np.float64)
    m = frames.mean(axis=0).reshape(4, -1)
    step = grid_step(frames) / frames.shape[0]  # as hot_fraction reads the mean map
    med, scale = (v[:, None] for v in np.array([center_scale(row, step) for row in m]).T)
    hot = (m - med) / scale > THRESHOLD_SIGMA
    return hot, (m - med)[hot]


TILE_CHANNELS = 3  # of a tile's four pixels hot that make a hot tile (one may fall under the threshold)


def hot_tiles(hot) -> np.ndarray:
    """(h, w) packed positions whose 2x2 tile has at least TILE_CHANNELS hot pixels of a (4, h, w)
    mask: a shared readout's defect (independent hot pixels of density d make one with
    probability ~4 d^3)."""
    return hot.sum(axis=0) >= TILE_CHANNELS


def estimate(frames, synthesized, k: float, seed: int = 13, kind: str = "bias", **_) -> dict:
    """Hot-pixel parameters at gain ``k`` from measured bias or dark frames (N, 4, h, w) in DN:
    isolated hot pixels and hot 2x2 tiles (``tile_density``, where the stack has more than the
    model's), one population of amplitudes. In a flat the light's shot noise raises the
    threshold: a flat of 300 DN at K 0.4 saw half the hot pixels of its bias frames."""
    if kind == "flat":
        raise ValueError("Hot is measured on bias and dark stacks")
    frames = np.asarray(frames, dtype=np.float64)
    hot, amp = detect(frames)
    tiles = hot_tiles(hot)
    found = [detect(s)[0] for s in synthesized]
    base = float(np.mean([(f & ~hot_tiles(f)[None]).mean() for f in found])) if found else 0.0
    base_tiles = float(np.mean([hot_tiles(f).mean() for f in found])) if found else 0.0
    density = max(float((hot & ~tiles[None]).mean()) - base, 0.0)
    tile_density = max(float(tiles.mean()) - base_tiles, 0.0)
    amp = amp[amp > 0]
    if (density == 0.0 and tile_density == 0.0) or amp.size == 0:
        return {"seed": int(seed), "density": 0.0, "log_std": 0.0, "k": [float(k)], "median_dn": [0.0]}
    logs = np.log(amp)
    out = {
        "seed": int(seed),
        "density": min(density, 0.1),
        "log_std": float(logs.std(ddof=1)) if amp.size > 1 else 0.0,
        "k": [float(k)],
        "median_dn": [float(math.exp(logs.mean()))],
    }
    if tile_density > 0.0:
        out["tile_density"] = min(tile_density, 0.1)
    return out


def combine(records: list[dict]) -> dict:
    """One population from the stacks' records: the density and log spread their mean, the
    median amplitude per gain the geometric mean of the stacks at that K (bias and dark)."""
    seen = [r for r in records if r["density"] > 0 or r.get("tile_density", 0.0) > 0]
    if not seen:
        return {**records[0], "k": [float(records[0]["k"][0])], "median_dn": [0.0]}
    by_k: dict = {}
    for r in seen:
        by_k.setdefault(float(r["k"][0]), []).append(r["median_dn"][0])
    ks = sorted(by_k)
    return {"seed": seen[0]["seed"], "density": float(np.mean([r["density"] for r in seen])),
            "log_std": float(np.mean([r["log_std"] for r in seen])), "k": ks,
            "median_dn": [float(np.exp(np.mean(np.log(by_k[k])))) for k in ks],
            **({"tile_density": float(np.mean([r.get("tile_density", 0.0) for r in seen]))}
               if any(r.get("tile_density", 0.0) > 0 for r in seen) else {})}


def empty(params) -> bool:
    """True when no pixel and no tile is drawn (densities 0): it would add nothing."""
    return float(params["density"]) == 0.0 and float(params.get("tile_density", 0.0)) == 0.0
