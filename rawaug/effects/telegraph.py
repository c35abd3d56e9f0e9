"""Random telegraph noise (RTS): a few pixels jump between two levels from frame to frame.

Physics: a trap in the gate oxide of a pixel's source follower captures and releases an
electron at random; while it holds one the pixel reads a fixed step higher (random
telegraph signal). It touches a small, fixed set of pixels, each with its own step, and in
any frame a pixel is in either state. ``Hot`` pixels have a fixed offset in every frame; the
ELD read noise has no such pixels.

Synthesis: positions are the pixels where a seeded U(0, 1) pattern falls below ``density``;
each has a log-normal step ``median_dn * exp(log_std * z)`` (seeded standard-normal ``z``),
added in a frame where that frame's U(0, 1) for the pixel falls below ``high`` (the share of
frames in the high state).

Profile entry::

    RTS: {seed: 41, density: 0.01, high: 0.5, log_std: 0.3, k: [K, ...], median_dn: [...]}

Detected by ``flicker_fraction`` (pixels of bias frames with two states: a temporal variance
a white pixel exceeds with probability 1e-6 and, in 4 or more frames, at least 2 frames on
each side of the largest gap in their sorted values, as one extreme value of heavy-tailed
read noise is not a state) and ``hot_fraction`` (in the stack mean they sit high).
Estimated by ``estimate``: the flickering pixels of a bias stack over the model's; each one's step is the gap
between the means of its frames above and below, its share of high frames the count above;
the population is the one whose simulated detected part matches those (steps near the read
noise, and pixels high or low in all but one frame, are seen less often). Over several ISOs
(``combine``) the pixels are one population: its density, share and spread come from the
stack that saw most of it, and a stack whose own steps contradict that density (its noise
hid most of them, and the few it saw were those the noise made larger) gets the step that
makes the population's detected fraction its own.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, stats

from ..engine import layout as L
from ..statistics import flicker_threshold, two_state, two_state_pixels
from .base import DARK, NoiseEffect, pattern_key, register
from .k_records import _number, check_density, check_seed, merge_records, validate_records, value_at_k

STATISTICS = ("flicker_fraction", "hot_fraction")  # a pixel high in some frames is also high in the stack mean
SIMULATED = 20_000  # telegraph pixels simulated per round of the estimate
ROUNDS = 4


@register
class Telegraph(NoiseEffect):
    token = "RTS"
    order = DARK
    flag = L.RTS
    columns = ("rts_density", "rts_median", "rts_log_std", "rts_high")

    def draw(self, ctx):
        p = self.profile.effects[self.token]
        n = ctx.k.shape[0]
        return {"rts_density": ctx.k.new_full((n,), float(p["density"])), "rts_median": value_at_k(p, "median_dn", ctx.k),
                "rts_log_std": ctx.k.new_full((n,), float(p["log_std"])), "rts_high": ctx.k.new_full((n,), float(p["high"]))}

    def pattern_streams(self):
        seed = self.profile.effects[self.token]["seed"]
        return {"rts_where": pattern_key(seed, self.token, "where"), "rts_size": pattern_key(seed, self.token, "size")}

    @classmethod
    def validate_params(cls, params):
        validate_records(cls.token, params, ("median_dn",), nonnegative=("median_dn",))
        check_seed(cls.token, params)
        check_density(cls.token, params)
        high = _number(params.get("high"), "RTS.high")
        if not 0.0 < high < 1.0:
            raise ValueError(f"effect 'RTS': high (share of frames in the high state) must be in (0, 1), got {high}")
        if _number(params.get("log_std"), "RTS.log_std") < 0:
            raise ValueError(f"effect 'RTS': log_std must be >= 0, got {params.get('log_std')}")


def _detected(steps, share, n, sigma, threshold, rng, shot_k=0.0):
    """(fraction detected, log steps of the detected, their shares of high frames) of telegraph pixels with ``steps`` (DN)
    in the high state with probability ``share``, over ``n`` frames of white noise ``sigma``
    (and, with ``shot_k`` > 0, the shot noise of a step of dark electrons: variance
    ``shot_k x step`` in its high frames), by the rule of ``flickering``."""
    states = rng.random((steps.size, n)) < share
    high = steps[:, None] * states
    noise = np.sqrt(sigma**2 + shot_k * high) if shot_k else sigma
    values = high + noise * rng.standard_normal((steps.size, n))
    seen, step, high = two_state(values, threshold)
    return float(seen.mean()), np.log(np.maximum(step, 1e-6)), high


def _robust(x):
    """(median, IQR / 1.349) of ``x``: a normal sample's mean and sd, robust to a few far ones."""
    q1, q2, q3 = np.percentile(x, [25, 50, 75])
    return float(q2), float((q3 - q1) / 1.349)


@dataclass(frozen=True)
class Detection:
    """What one stack showed of a telegraph population: the detected fraction of its pixels
    beyond the model's (``found``), all it detected (``seen``) of ``pixels``, and its detection
    (``n`` frames, white noise ``sigma`` DN, variance ``threshold`` DN^2, dark shot noise
    ``shot_k``)."""

    found: float
    seen: float
    pixels: int
    n: int
    sigma: float
    threshold: float
    shot_k: float = 0.0

    def fraction(self, high: float, mu: float, sd: float, seed: int) -> float:
        """Detected fraction of a population of log median step ``mu`` (DN) and log spread ``sd``
        in the high state with probability ``high`` (common random numbers for ``seed``)."""
        z = np.random.default_rng(seed).standard_normal(SIMULATED)
        return _detected(np.exp(mu + sd * z), high, self.n, self.sigma, self.threshold,
                         np.random.default_rng(seed + 1), self.shot_k)[0]

    def agrees(self, density: float, high: float, mu: float, sd: float, seed: int) -> bool:
        """Whether the population would be detected here in the fraction found, within 3
        binomial sd of the count."""
        se = math.sqrt(max(self.seen * (1.0 - self.seen), 1.0 / self.pixels) / self.pixels)
        return abs(density * self.fraction(high, mu, sd, seed) - self.found) <= 3.0 * se

    def step_for(self, density: float, high: float, sd: float, seed: int) -> float | None:
        """The log median step (DN) at which a population of ``density`` is detected in the
        fraction found here; None where no step gives it."""
        lo, hi = math.log(0.1 * self.sigma), math.log(100.0 * self.sigma)
        gap = lambda mu: density * self.fraction(high, mu, sd, seed) - self.found  # noqa: E731
        if gap(lo) > 0.0 or gap(hi) < 0.0:
            return None
        return float(optimize.brentq(gap, lo, hi, xtol=1e-3))


def population(frames, synthesized, seed: int, shot_k: float = 0.0):
    """(density, share of high frames, log median step (DN), log spread, ``Detection``) of the
    telegraph pixels of a stack (N >= 3, 4, h, w; DN) beyond the model's (its ``synthesized``
    stacks), or None when it shows none.

    The flickering pixels are those whose step stands out of the noise: the detected steps
    are the larger ones. The population is the one whose detected part, simulated over the
    same frames and noise by the same rule (``_detected``) and mixed with the model's own
    detected pixels in their share, matches the measured one: a few fixed-point rounds on the
    log steps' median and spread (``_robust``) and the mean share of high frames; the density
    is the found fraction over the detected one."""
    frames = np.asarray(frames, dtype=np.float64)
    n = frames.shape[0]
    seen, step, share, median_var = two_state_pixels(frames)
    model = [two_state_pixels(s) for s in synthesized]
    base = float(np.mean([m[0].mean() for m in model])) if model else 0.0
    found = max(float(seen.mean()) - base, 0.0)
    keep = step > 0
    if found == 0.0 or keep.sum() < 2:
        return None
    # the detected pixels hold the model's own too (a heavy read-noise tail, a hot pixel's shot
    # noise): the simulated population is matched mixed with those, in their share ``w``
    logs, share = np.log(step[keep]), share[keep]
    own = [(np.log(m[1][m[1] > 0]), m[2][m[1] > 0]) for m in model]
    model_logs = np.concatenate([o[0] for o in own]) if model else np.zeros(0)
    model_share = np.concatenate([o[1] for o in own]) if model else np.zeros(0)
    w = min(base / float(seen.mean()), 0.8) if model_logs.size else 0.0
    target_mean, target_sd = _robust(logs)
    target_share = float(share.mean())
    high = float(np.clip(target_share, 0.05, 0.95))
    sigma = np.sqrt(median_var * (n - 1) / stats.chi2.median(n - 1))
    threshold = flicker_threshold(n) * median_var
    mu, sd, fraction = target_mean, target_sd, 1.0
    z = np.random.default_rng(seed).standard_normal(SIMULATED)
    for _ in range(ROUNDS):
        rng = np.random.default_rng(seed + 1)
        fraction, sim, sim_share = _detected(np.exp(mu + sd * z), high, n, sigma, threshold, rng, shot_k)
        if sim.size < 2:
            break
        mixed = sim
        if w:
            mixed = np.concatenate([sim, rng.choice(model_logs, int(round(sim.size * w / (1.0 - w))))])
        got_mean, got_sd = _robust(mixed)
        mu += target_mean - got_mean
        sd = float(np.clip(sd * target_sd / max(got_sd, 1e-3), 1e-3, 2.0))
        # the detected are nearer half and half
        got_share = (1.0 - w) * float(sim_share.mean()) + (w * float(model_share.mean()) if w else 0.0)
        high = float(np.clip(high + target_share - got_share, 0.05, 0.95))
    detection = Detection(found, float(seen.mean()), int(seen.size), n, float(sigma), float(threshold), shot_k)
    return min(found / max(fraction, 0.05), 0.1), high, mu, sd, detection


def estimate(frames, synthesized, k: float, seed: int = 41, kind: str = "bias", **_) -> dict:
    """RTS parameters at gain ``k`` from a bias stack (N >= 3, 4, h, w) in DN: the telegraph
    pixels' ``population`` beyond the model's; ``_detection`` (what the stack showed) is for
    ``combine``, which leaves it out (a profile refuses it)."""
    frames = np.asarray(frames, dtype=np.float64)
    if kind != "bias" or frames.shape[0] < 3:
        raise ValueError("RTS is measured on bias stacks of >= 3 frames")
    found = population(frames, synthesized, seed)
    if found is None:
        return {"seed": int(seed), "density": 0.0, "high": 0.5, "log_std": 0.0, "k": [float(k)], "median_dn": [0.0]}
    density, high, mu, sd, detection = found
    return {"seed": int(seed), "density": density, "high": high, "log_std": sd, "k": [float(k)],
            "median_dn": [float(math.exp(mu))], "_detection": detection}


def combine(records: list[dict]) -> dict:
    """One population over the stacks' records (one per bias stack): density, share and
    spread from the stack that found the largest fraction; a stack whose detected fraction
    contradicts them gets the step that gives it (``Detection.step_for``), the others keep
    their own."""
    clean = [{key: v for key, v in r.items() if key != "_detection"} for r in records]
    found = [i for i, r in enumerate(records) if r["density"] > 0 and r.get("_detection") is not None]
    if len(found) < 2:
        return merge_records(clean)
    ref = clean[max(found, key=lambda i: records[i]["_detection"].found)]
    density, high, sd, seed = ref["density"], ref["high"], ref["log_std"], ref["seed"]
    for i in found:
        det, mu = records[i]["_detection"], math.log(clean[i]["median_dn"][0])
        if clean[i] is not ref and not det.agrees(density, high, mu, sd, seed):
            solved = det.step_for(density, high, sd, seed)
            if solved is not None:
                clean[i]["median_dn"] = [float(math.exp(solved))]
    merged = merge_records(clean)
    return {**merged, "seed": seed, "density": density, "high": high, "log_std": sd}


def empty(params) -> bool:
    """True when no pixel is drawn (density 0): it would add nothing."""
    return float(params["density"]) == 0.0
