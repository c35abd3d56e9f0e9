"""Impulsive noise (Spikes): single-frame events at random pixels, far above (or below) the noise.

Physics: a cosmic-ray muon or a radioactive decay in the package deposits hundreds of
electrons in one pixel during an exposure (their rate grows with exposure time); a charge
burst in the readout does the same once per frame. A lost charge packet or a readout
glitch does the opposite: a pixel reads far low in one frame (a dark event). Either hits a
pixel in one frame only, at a new place in the next: unlike ``Hot`` (a fixed pixel), ``RTS``
(a fixed pixel with two states) or a heavy-tailed read noise (every pixel, symmetric).

Stage (DN, after read noise): ``s -> s + median_dn(K) * exp(log_std * z)`` where a U(0, 1) of
the frame and pixel falls below ``d = density + density_per_s * t`` (``t``: the synthesis
setting ``fixed={"exposure_s": t}``, default 0), ``z`` a standard normal of the frame and
pixel; subtracted instead where the U(0, 1) falls below ``negative * d``.

Profile entry (per-K amplitude records; ``negative``, the share of dark events, default 0)::

    Spikes: {density: 5.0e-4, density_per_s: 0.0, log_std: 0.6, negative: 0.0, k: [K, ...], median_dn: [...]}

Detected on bias and dark stacks of >= 3 frames by ``spike_fraction`` (values 8 robust sigmas
above the pixel's other frames, in one frame only, beyond as many below: heavy-tailed read
noise makes both; negative where dark events outnumber bright ones) and ``tail_mass``.
Estimated by ``estimate``: the events of the side in excess (of both sides where each
exceeds the model's own count of that side: a bit error on the data link moves a code by
+-2^b, depending on the bit's state), their size in DN by a
log-normal truncated at the detection threshold (``truncated_log_normal``), the density as
that excess over the model's over the share the threshold lets through;
``combine`` fits the density against exposure (two or more exposures: a per-frame part and a
per-second part).
"""
from __future__ import annotations

import math

import numpy as np
import torch
from scipy import optimize, stats

from ..engine import layout as L
from ..statistics import SPIKE_Z, spike_counts, spike_scale, spikes
from .base import READ, NoiseEffect, register
from .k_records import _number, validate_records, value_at_k

STATISTICS = ("spike_fraction", "tail_mass")
SIGNED = True  # dark events lower spike_fraction: a negative residual calls for them too
RAW_FRAMES = True  # a spike in a line's pixel is a spike: estimated on the frames as measured
MAX_DENSITY = 0.01
SIDE_Z = 5.0  # Poisson sd by which each side's events must exceed the model's for events of both signs


@register
class Impulses(NoiseEffect):
    token = "Spikes"
    order = READ + 5
    flag = L.SPIKES
    columns = ("spike_density", "spike_median", "spike_log_std", "spike_negative")
    exposure = True

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        exposure = torch.as_tensor(ctx.fixed.get("exposure_s", 0.0), dtype=torch.float64, device=ctx.device).expand(ctx.batch)
        n = ctx.k.shape[0]
        return {"spike_density": float(p["density"]) + float(p.get("density_per_s", 0.0)) * exposure,
                "spike_median": value_at_k(p, "median_dn", ctx.k), "spike_log_std": ctx.k.new_full((n,), float(p["log_std"])),
                "spike_negative": ctx.k.new_full((n,), float(p.get("negative", 0.0)))}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("median_dn",), nonnegative=("median_dn",))
        for key, unit in (("density", "fraction of pixels per frame"), ("density_per_s", "... per second of exposure")):
            value = _number(params.get(key, 0.0), f"{cls.token}.{key}")
            if not 0.0 <= value <= MAX_DENSITY:
                raise ValueError(f"effect {cls.token!r}: {key} ({unit}) must be in [0, {MAX_DENSITY:g}], got {value}")
        if _number(params.get("log_std"), f"{cls.token}.log_std") < 0:
            raise ValueError(f"effect {cls.token!r}: log_std must be >= 0, got {params.get('log_std')}")
        if not 0.0 <= _number(params.get("negative", 0.0), f"{cls.token}.negative") <= 1.0:
            raise ValueError(f"effect {cls.token!r}: negative (the share of dark events) must be in [0, 1], got {params.get('negative')}")


def estimate(frames, synthesized, k: float, exposure_s=None, kind=None, **_) -> dict:
    """One record from a bias or dark stack (N >= 3, 4, h, w) in DN at gain ``k``, against
    stacks of the same shape synthesized by the model: the spike density per pixel and frame
    beyond the model's and the events' size over their pixel's other frames (DN). The events
    are those of the side whose single-frame events outnumber the other's beyond the model's
    (``spike_fraction``: bright ones, or dark ones, ``negative`` 1); where each side's count
    also exceeds the model's own count of that side by ``SIDE_Z`` Poisson sd (a bit error, a
    glitch of either sign), both sides', ``negative`` the dark side's share."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind not in ("bias", "dark") or frames.shape[0] < 3:
        raise ValueError("Spikes are measured on bias or dark stacks of >= 3 frames")
    counts = np.array(spike_counts(frames), dtype=np.float64)
    model = np.mean([spike_counts(s) for s in synthesized], axis=0) if synthesized else np.zeros(2)
    net = float((counts[0] - counts[1]) - (model[0] - model[1])) / frames.size  # heavy tails make both sides alike
    over = counts - model
    both = bool(np.all(over > SIDE_Z * np.sqrt(model + 1.0)))
    sides = (1.0, -1.0) if both else ((1.0,) if net >= 0 else (-1.0,))
    scale = spike_scale(frames)
    excess, floor = [], []
    for sign in sides:
        mask = spikes(sign * frames, scale)
        others = np.sort(sign * frames, axis=0)[:-1]
        e = (sign * frames - np.median(others, axis=0))[mask]
        fl = np.broadcast_to((SPIKE_Z * scale)[None, :, None, None], frames.shape)[mask]
        excess.append(e[e > 0])
        floor.append(fl[e > 0])
    excess, floor = np.concatenate(excess), np.concatenate(floor)
    t = float(exposure_s or 0.0)
    negative = float(over[1] / over.sum()) if both else (0.0 if net >= 0 else 1.0)
    record = {"density": 0.0, "density_per_s": 0.0, "log_std": 0.0, "negative": negative,
              "k": [float(k)], "median_dn": [0.0], "exposure_s": [t]}
    if (net == 0.0 and not both) or excess.size == 0:
        return record
    mu, s = truncated_log_normal(np.log(excess), np.log(floor))
    seen = float(np.mean(stats.norm.sf((np.log(SPIKE_Z * scale) - mu) / max(s, 1e-6))))
    found = float(over.sum()) / frames.size if both else abs(net)
    return record | {"density": min(found / max(seen, 0.1), MAX_DENSITY), "log_std": s, "median_dn": [float(math.exp(mu))]}


def truncated_log_normal(logs, log_floor) -> tuple[float, float]:
    """(mu, sigma) of log amplitudes ``logs`` each seen only above its ``log_floor`` (maximum
    likelihood of a normal truncated below; sigma in [0.05, 2]): spikes near the detection
    threshold are missed, so the plain mean and spread of the seen ones are too high and too
    narrow."""
    logs, log_floor = np.asarray(logs, dtype=np.float64), np.asarray(log_floor, dtype=np.float64)
    if logs.size < 3:
        return float(logs.mean()), 0.0

    def nll(p):
        mu, s = p[0], math.exp(p[1])
        return -float(np.sum(stats.norm.logpdf(logs, mu, s) - stats.norm.logsf(log_floor, mu, s)))

    start = np.array([logs.mean(), math.log(max(logs.std(ddof=1), 0.05))])
    sol = optimize.minimize(nll, start, method="L-BFGS-B", bounds=[(logs.min() - 3.0, logs.max()), (math.log(0.05), math.log(2.0))])
    return float(sol.x[0]), float(math.exp(sol.x[1]))


def combine(records: list[dict]) -> dict:
    """One population: the density as a per-frame part plus a per-second part (least squares
    over the stacks' exposures, both >= 0; one exposure: per frame only); the median per gain
    (log-mean over its stacks); the log spreads pooled; the share of dark events weighted by
    the stacks' densities. Stacks that found none count for the
    density only."""
    t = np.array([r["exposure_s"][0] for r in records])
    d = np.array([r["density"] for r in records])
    per_frame, per_s = float(d.mean()), 0.0
    if np.ptp(t) > 0:
        a = np.stack([np.ones_like(t), t], axis=1)
        (per_frame, per_s), *_ = np.linalg.lstsq(a, d, rcond=None)
        if per_s < 0 or per_frame < 0:  # the nearer bound
            per_frame, per_s = (float(d.mean()), 0.0) if per_s < 0 else (0.0, float(d @ t / (t @ t)))
    found = [r for r in records if r["density"] > 0]
    if not found:
        return {"density": 0.0, "density_per_s": 0.0, "log_std": 0.0, "negative": 0.0, "k": [records[0]["k"][0]], "median_dn": [0.0]}
    by_k: dict = {}
    for r in found:
        by_k.setdefault(r["k"][0], []).append(math.log(r["median_dn"][0]))
    ks = sorted(by_k)
    return {"density": min(float(per_frame), MAX_DENSITY), "density_per_s": min(float(per_s), MAX_DENSITY),
            "log_std": float(math.sqrt(np.mean([r["log_std"] ** 2 for r in found]))),
            "negative": float(np.average([r.get("negative", 0.0) for r in found], weights=[r["density"] for r in found])),
            "k": ks, "median_dn": [float(math.exp(np.mean(by_k[k]))) for k in ks]}


def empty(params) -> bool:
    """True when no spike is drawn (both densities 0): it would add nothing."""
    return float(params["density"]) == 0.0 and float(params.get("density_per_s", 0.0)) == 0.0
