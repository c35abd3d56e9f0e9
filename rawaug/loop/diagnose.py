"""Residual diagnosis on frames: measured stack against repeated syntheses of the model.

For a measured stack (N frames at gain K), the model synthesizes ``n_synth`` stacks of the
same size and count; every statistic of ``rawaug.statistics`` gets

* ``z = (measured - mean of syntheses) / spread of syntheses`` (significance), and
* ``rel_error = |measured - mean| / max(|measured|, 3 spread, resolution)`` (error figure:
  relative to the measured value, or to the synthesis noise where that is larger),

and residuals are ranked by ``|z|`` and traced to the effects that explain them. A pooled
statistic (a frame-to-frame spread of N - 1 degrees of freedom per stack, such as a flat
pair's) is judged over every stack that has it (``pool_residuals``).
"""
from __future__ import annotations

import dataclasses
import functools
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
from scipy.stats import f as f_dist
from scipy.stats import norm
from threadpoolctl import threadpool_limits

from ..augment import RawNoiseAugment, parse_model
from ..calibration.censored import black_floor, clipped_share
from ..effects.charge_trap import fit_rates as trap_rates, trap_at
from ..effects.base import EFFECTS
from ..effects.gain_nonlinearity import at_k as nonlin_at, fit_rates, linear_rates
from ..profile import NoiseProfile
from .registry import effects_for
from ..statistics import STATISTICS, flat_gain_edges, flat_log_mosaic, frame_statistics, repaired, stack_step_excess
from .illumination import illumination_shape


@dataclass
class FlatSeries:
    """Flats of one ISO at several exposures: ``doses`` (n,) are exposure times (s), or
    exposure time x relative light where the manifest gives the light (``light`` column);
    ``signal_dn`` (n, 4) each stack's channel means less ``offsets_dn`` (the ISO's bias
    offsets). A linear camera puts the means on a line through zero (``linear_rates``); the
    model synthesizes each flat at the clean level its effects need to put it there
    (``clean_level``)."""

    doses: np.ndarray
    signal_dn: np.ndarray
    offsets_dn: np.ndarray

    def __post_init__(self):
        self.doses = np.asarray(self.doses, dtype=np.float64)
        self.signal_dn = np.asarray(self.signal_dn, dtype=np.float64)
        self.offsets_dn = np.asarray(self.offsets_dn, dtype=np.float64)
        self.rates = linear_rates(self.doses, self.signal_dn)  # DN per unit dose, per channel (validates the series)
        self._rates_at = {}  # (c, q, K) -> rates the response implies (fitted once, not per synthesis)

    def nominal(self, dose: float) -> np.ndarray:
        """(4,) clean level (DN) of a linear response at ``dose``."""
        return self.rates * float(dose)

    def clean_level(self, profile: NoiseProfile, k: float, dose: float) -> np.ndarray:
        """(4,) clean level (DN) that puts the model's mean on the series at ``dose``:
        the nominal one, or, with charge traps or a gain non-linearity, the rate their
        response implies."""
        c = nonlin_at(profile.effects.get("NonLin"), k)  # (4,) per channel
        q = trap_at(profile, k)
        if not c.any() and q == 0.0:
            return self.nominal(dose)
        key = (tuple(c.tolist()), q, k)
        if key not in self._rates_at:
            self._rates_at[key] = (fit_rates(self.doses, self.signal_dn, c, k) if q == 0.0
                                   else trap_rates(self.doses, self.signal_dn, q, k, c))
        return self._rates_at[key] * float(dose)


@dataclass
class FrameStack:
    """Measured frames of one setting, packed ``(N, 4, h, w)`` in DN (black-subtracted).

    ``kind`` is ``"bias"`` (no light, shortest exposure), ``"dark"`` (no light, exposure
    ``exposure_s`` seconds) or ``"flat"`` (uniform light of ``level_dn``: DN above the
    offsets, one number or one per channel). ``base`` may fix
    base-model parameters measured on the bias frames of the same ISO (keys of
    ``RawNoiseAugment(fixed=...)``: ``sigma_tl``, ``lambda``, ``sigma_r``); missing ones come
    from the profile at ``k``. ``offsets_dn`` (R, G1, B, G2) are the channel offsets the
    synthesis adds; default: the stack's own for bias frames, 0 for flats. A dark or flat
    stack should get those of its ISO's bias frames, so that the dark signal shows:
    ``offsets_of`` (that bias stack) gives it the offsets the bias stack's syntheses use,
    fitted with the model's effects (a clip at black raises the mean, so the measured
    means would be too high); ``offsets_dn`` fixes them instead. A flat stack of a
    ``series`` (``FlatSeries``, with its ``dose``: ``exposure_s`` unless the light was
    varied) has the series' nominal level as ``level_dn`` and is also checked for linearity
    (``flat_linearity``). ``black_code``, where known, are the raw codes the DN were measured
    from (what a stuck ADC bit acts on)."""

    frames_dn: np.ndarray
    k: float
    kind: str = "bias"
    level_dn: float | None = None
    label: str = ""
    base: dict = field(default_factory=dict)
    exposure_s: float | None = None
    offsets_dn: list | None = None
    offsets_of: "FrameStack | None" = None
    series: FlatSeries | None = None
    dose: float | None = None  # a series flat's exposure x relative light (default exposure_s)
    tap_edges: dict | None = None  # a flat's sensor's readout-tap edges (tap_gain.consensus_edges); None: its own (gain_edges)
    black_code: list | None = None  # the raw code of 0 DN per channel (R, G1, B, G2): the black level the DN were taken from

    def __post_init__(self):
        self.frames_dn = np.asarray(self.frames_dn, dtype=np.float64)
        if self.frames_dn.ndim != 4 or self.frames_dn.shape[1] != 4:
            raise ValueError(f"frames_dn must be packed (N, 4, h, w), got shape {self.frames_dn.shape}")
        if not (isinstance(self.k, (int, float)) and math.isfinite(self.k) and self.k > 0):
            raise ValueError(f"k (system gain, DN/e-) must be a positive number, got {self.k!r}")
        if self.kind not in ("bias", "dark", "flat"):
            raise ValueError(f"kind must be 'bias', 'dark' or 'flat', got {self.kind!r}")
        if self.kind == "flat" and self.level_dn is None:
            raise ValueError("a flat stack needs its clean level level_dn (DN)")
        if self.kind == "dark" and not (isinstance(self.exposure_s, (int, float)) and self.exposure_s > 0):
            raise ValueError(f"a dark stack needs its exposure_s (seconds, > 0), got {self.exposure_s!r}")
        if self.black_code is not None and (len(self.black_code) != 4 or not all(math.isfinite(float(z)) for z in self.black_code)):
            raise ValueError(f"black_code must hold 4 raw codes (R, G1, B, G2), got {self.black_code!r}")
        if self.offsets_dn is not None and len(self.offsets_dn) != 4:
            raise ValueError(f"offsets_dn must hold 4 values (R, G1, B, G2), got {self.offsets_dn!r}")
        if self.offsets_of is not None and not (isinstance(self.offsets_of, FrameStack) and self.offsets_of.kind == "bias"):
            raise ValueError(f"offsets_of must be a bias FrameStack, got {self.offsets_of!r:.80}")
        if self.dose is None and self.series is not None:
            self.dose = self.exposure_s
        if self.series is not None and not (self.kind == "flat" and isinstance(self.series, FlatSeries)
                                            and isinstance(self.dose, (int, float)) and self.dose > 0):
            raise ValueError(f"a series (FlatSeries) belongs to a flat stack with its dose (exposure_s), got kind "
                             f"{self.kind!r}, dose {self.dose!r}")
        self.label = self.label or f"{self.kind} K={self.k:.4g}"

    @property
    def statistics_level(self):
        """The level the battery's flat statistics read: for a flat of a series, the level a
        linear response gives it plus the black offsets (what its mean should be)."""
        if self.series is None:
            return self.level_dn
        return self.series.nominal(self.dose) + self.series.offsets_dn

    @property
    def statistic_names(self):
        """The battery's statistics this stack can show (None: every one that applies): the
        linearity needs a series."""
        return None if self.series is not None else [n for n in STATISTICS if n not in ("flat_linearity", "channel_linearity")]

    def statistics(self, frames) -> dict:
        """The battery's statistics of ``frames`` (measured or synthesized like this stack)."""
        return frame_statistics(frames, self.kind, self.statistics_level, self.statistic_names)

    @functools.cached_property
    def _above_black(self) -> tuple[np.ndarray, np.ndarray]:
        """(repaired frames, black): a flat's frames and what its light is measured above (its
        bias stack's mean, or its offsets)."""
        frames = repaired(self.frames_dn)
        if self.offsets_of is not None:
            return frames, repaired(self.offsets_of.frames_dn).mean(axis=0)
        offsets = (self.offsets_dn if self.offsets_dn is not None
                   else self.series.offsets_dn if self.series is not None else np.zeros(4))
        return frames, np.asarray(offsets, dtype=np.float64)[:, None, None]

    @functools.cached_property
    def gain_edges(self) -> dict | None:
        """The readout-tap edges this flat shows on its own (``flat_gain_edges``, against its
        frames' temporal noise); None but for flats."""
        if self.kind != "flat":
            return None
        frames, black = self._above_black
        return flat_gain_edges(flat_log_mosaic(frames.mean(axis=0, keepdims=True) - black[None]), stack_step_excess(frames - black))

    @functools.cached_property
    def illumination(self) -> np.ndarray | None:
        """(4, h, w) relative shape of a flat's light (``illumination_shape``; mean 1 per
        channel), of its mean frame less its bias stack's (or its offsets), the taps' gains at
        ``tap_edges`` (or its own ``gain_edges``) divided out; None but for flats."""
        if self.kind != "flat":
            return None
        frames, black = self._above_black
        return illumination_shape(frames.mean(axis=0) - black, self.tap_edges if self.tap_edges is not None else self.gain_edges)

    @functools.cached_property
    def integer(self) -> bool:
        """Whole-number codes (a real raw file): syntheses are then rounded, not dithered."""
        return bool(np.all(self.frames_dn == np.rint(self.frames_dn)))

    @functools.cached_property
    def measured(self) -> dict:
        """The battery's statistics of the measured frames (computed once: frames never change)."""
        return self.statistics(self.frames_dn)


@dataclass
class Residual:
    statistic: str
    measured: float
    synth_mean: float
    synth_std: float
    z: float
    rel_error: float
    significant: bool
    effects: list
    base: str
    # a pooled statistic (``Statistic.pooled``): "stack" holds this stack's own figures; the
    # first stack that has it carries the joint residual ("over": the stacks pooled), the
    # others point to it ("into") and are not significant on their own (``pool_residuals``)
    pooled: dict = field(default_factory=dict)

    def to_dict(self):
        return asdict(self)


PILOT_STEPS = 3  # offset fits per bias synthesis (Newton steps, then secant steps: a clip or stuck bits move the mean less or more than the offset)
PILOT_STEPS_MAX = 6  # ... and up to this many while the pilot's channel means miss the stack's by PILOT_TOLERANCE (DN)
PILOT_TOLERANCE = 0.05  # or 3 times their own noise (a per-frame field moves them) or more


def channel_offsets(frames) -> list[float]:
    """Per-channel mean (DN) with defect lines repaired: the black-level error the synthesis
    copies (a 10-90 % trimmed mean, used before, is not the mean of skewed codes)."""
    return [float(v) for v in repaired(np.asarray(frames, dtype=np.float64)).mean(axis=(0, 2, 3))]


def synthesis_fixed(profile: NoiseProfile, stack: FrameStack) -> dict:
    """The fixed parameters of a synthesis matching ``stack``: K, ratio 1, the base-model
    sigmas at K (median of the profile relation, unless measured), and its channel offsets."""
    k = stack.k
    fixed = {
        "k": k,
        "ratio": 1.0,
        "sigma_g": profile.gaussian_scale.median(k),
        "color_bias_dn": (list(stack.offsets_dn) if stack.offsets_dn is not None
                          else channel_offsets(stack.frames_dn) if stack.kind == "bias" else [0.0] * 4),
    }
    if profile.tukey_scale is not None:
        fixed.update(sigma_tl=profile.tukey_scale.median(k), **{"lambda": float(profile.tukey_shape.nearest(k))})
    if profile.row_scale is not None:
        fixed["sigma_r"] = profile.row_scale.median(k)
    fixed.update(stack.base)
    if stack.kind == "dark" or (stack.kind == "flat" and stack.exposure_s and exposed(profile)):
        fixed["exposure_s"] = float(stack.exposure_s)  # a flat of t seconds holds t seconds of dark signal too
    return fixed


def exposed(profile: NoiseProfile) -> bool:
    """True when an effect of the profile grows with the exposure time (``NoiseEffect.exposure``)."""
    return any(getattr(EFFECTS.get(token), "exposure", False) for token in profile.effects)


def dark_signal(profile: NoiseProfile, stack: FrameStack, tokens, fixed, seed: int) -> np.ndarray:
    """(4,) mean dark signal (DN) the model adds to a flat of ``fixed["exposure_s"]``: a frame
    synthesized at 0 DN with that exposure less one with none (the same draws). A flat's
    measured level holds it already, so its synthesis starts that much lower."""
    n, _, h, w = stack.frames_dn.shape
    means = []
    for t in (fixed["exposure_s"], 0.0):
        aug = RawNoiseAugment(profile, model="+".join(tokens), ratio=1.0, fixed={**fixed, "exposure_s": t, "sensor": 0},
                              generator=torch.Generator().manual_seed(int(seed) + 5_555_555), rank_seeding=False)
        with torch.no_grad():
            means.append(aug(torch.zeros(1, 4, h, w)).numpy().astype(np.float64).mean(axis=(0, 2, 3)) * profile.span_dn)
    return means[0] - means[1]


def sensor_realization(profile: NoiseProfile, index: int) -> NoiseProfile:
    """The profile with every fixed pattern re-drawn (index 0: the profile's own patterns).
    A profile describes a population of sensors; a measured stack is one of them, so the
    spread of the syntheses must include the pattern-to-pattern spread, not only frame noise."""
    if index == 0 or not any(isinstance(p, dict) and "seed" in p for p in profile.effects.values()):
        return profile
    data = profile.to_dict()
    for params in data["effects"].values():
        if isinstance(params, dict) and "seed" in params:
            params["seed"] = (int(params["seed"]) + 1_000_003 * index) % (2**31)
    return NoiseProfile.from_dict(data)


def _tokens(profile: NoiseProfile, stack: FrameStack, model: str | None) -> list[str]:
    tokens = [t for t in parse_model(model or profile.richest_model) if not (t == "U" and stack.integer)]
    return tokens + (["C"] if "C" not in tokens else [])


def clean_level(profile: NoiseProfile, stack: FrameStack):
    """Clean level (DN) a synthesis of ``stack`` starts from: 0 for bias and dark frames; a
    flat's ``level_dn``, or, in a series, the level the model's response needs."""
    if stack.kind != "flat":
        return 0.0
    if stack.series is not None:
        return stack.series.clean_level(profile, stack.k, stack.dose)
    return stack.level_dn


def _one(profile, stack, tokens, fixed, generator, dark_dn=None) -> np.ndarray:
    """One synthesized stack like ``stack``, DN (a flat from ``dark_dn`` (4,) lower: the dark
    signal its exposure adds, ``dark_signal``)."""
    n, _, h, w = stack.frames_dn.shape
    level = np.broadcast_to(np.asarray(clean_level(profile, stack), dtype=np.float64), (4,))[:, None, None]
    if stack.illumination is not None:  # a flat as it was taken: under its light's measured shape
        level = level * stack.illumination
    if dark_dn is not None:
        level = level - np.asarray(dark_dn, dtype=np.float64)[:, None, None]
    clean = torch.from_numpy(level / profile.span_dn).float().expand(n, 4, h, w).contiguous()
    aug = RawNoiseAugment(profile, model="+".join(tokens), ratio=1.0, fixed={**fixed, "sensor": 0, "sequence": 1},
                          generator=generator, rank_seeding=False)  # one sensor, frames in the order taken
    with torch.no_grad():
        frames = aug(clean) * profile.span_dn
    return (torch.round(frames) if stack.integer else frames).numpy()


def fitted_offsets(profile: NoiseProfile, stack: FrameStack, seed: int = 0, model: str | None = None) -> list[float]:
    """The colour bias (DN per channel) a synthesis of ``stack`` uses. For a bias stack of a
    model with effects (and no offsets of its own) it is fitted with them, as calibration
    would fit them jointly: a clip, a code map or hot pixels move the mean, and the offsets
    are whatever puts the model's channel means at the stack's (pilot syntheses with their
    own seeds; a clip makes the mean move less than the offset, by the share of the noise
    under it: each step divides by that, ``mean_slope``). A stack with ``offsets_of`` takes
    that bias stack's."""
    if stack.offsets_of is not None:
        return fitted_offsets(profile, stack.offsets_of, seed, model)
    fixed = synthesis_fixed(profile, stack)
    offsets = [float(o) for o in fixed["color_bias_dn"]]
    if stack.kind != "bias" or not profile.effects or stack.offsets_dn is not None:
        return offsets  # given offsets are kept
    target = np.asarray(channel_offsets(stack.frames_dn))
    tokens = _tokens(profile, stack, model)
    before = None  # (offsets, means, their noise) of the step before: the secant's slope
    for step in range(PILOT_STEPS_MAX):
        if step >= PILOT_STEPS and np.all(np.abs(before[1] - target) < np.maximum(PILOT_TOLERANCE, 3.0 * before[2])):
            break
        fixed["color_bias_dn"] = offsets
        pilot = _one(profile, stack, tokens, fixed, torch.Generator().manual_seed(int(seed) + 7_777_777 + step))
        frame_means = repaired(pilot.astype(np.float64)).mean(axis=(2, 3))  # (N, 4)
        means = frame_means.mean(axis=0)
        noise = frame_means.std(axis=0, ddof=1) / np.sqrt(len(frame_means)) if len(frame_means) > 1 else np.zeros(4)
        slopes = [mean_slope(pilot[:, c]) for c in range(4)]
        if before is not None:  # the slope the steps measured (stuck bits: up to 2x), where they moved the mean beyond its noise
            slopes = [float(np.clip((m - m0) / (o - o0), 0.1, 10.0)) if abs(o - o0) > 0.05 and abs(m - m0) > 5.0 * np.hypot(e, e0) else sl
                      for sl, o, o0, m, m0, e, e0 in zip(slopes, offsets, before[0], means, before[1], noise, before[2])]
        before = (offsets, means, noise)
        offsets = [float(o - (m - t) / sl) for o, m, t, sl in zip(offsets, means, target, slopes)]
    return offsets


def mean_slope(values) -> float:
    """How far the mean of synthesized ``values`` moves per DN of offset: 1, but under a clip
    from below (a pile-up at the lowest value, ``censored.black_floor``), where the values on
    it do not move: 1 less the share of the noise below it (``censored.clipped_share``; at
    least 0.1)."""
    floor = black_floor(values)
    return 1.0 if floor is None else max(1.0 - clipped_share(values, floor), 0.1)


def synthesize(profile: NoiseProfile, stack: FrameStack, n_synth: int, seed: int, model: str | None = None,
               offsets: list | None = None) -> np.ndarray:
    """``n_synth`` stacks like ``stack`` from the model (base ``model`` + colour bias +
    every effect in the profile), each from its own realization of the fixed patterns
    (``sensor_realization``): array (n_synth, N, 4, h, w) in DN, float32. Integer measured
    codes get rounded syntheses (the ADC rounds) instead of the ``U`` dither. ``offsets``:
    the colour bias to use, already fitted (default: ``fitted_offsets`` with ``seed``)."""
    tokens = _tokens(profile, stack, model)
    fixed = synthesis_fixed(profile, stack)
    fixed["color_bias_dn"] = list(offsets) if offsets is not None else fitted_offsets(profile, stack, seed, model)
    generator = torch.Generator().manual_seed(int(seed))
    dark_dn = dark_signal(profile, stack, tokens, fixed, seed) if stack.kind == "flat" and "exposure_s" in fixed else None
    n, _, h, w = stack.frames_dn.shape
    out = np.empty((n_synth, n, 4, h, w), dtype=np.float32)
    for i in range(n_synth):
        out[i] = _one(sensor_realization(profile, i), stack, tokens, fixed, generator, dark_dn)
    return out


def map_on_threads(fn, items, workers: int) -> list:
    """``[fn(item) for item in items]``, in order, on up to ``workers`` threads (NumPy's
    partitions and FFTs and the numba kernels release the GIL), each with one BLAS thread:
    OpenBLAS's own threads on top slowed the statistics' small products (``period_excess``)
    10 to 40-fold."""
    items = list(items)
    workers = min(int(workers), len(items))
    if workers < 2:
        return [fn(item) for item in items]
    with threadpool_limits(limits=1, user_api="blas"), \
            ThreadPoolExecutor(max_workers=workers, thread_name_prefix="rawaug-loop") as pool:
        return list(pool.map(fn, items))


def compare(stack: FrameStack, synthesized, z_min: float = 6.0, rel_min: float = 0.1, workers: int = 1) -> list[Residual]:
    """Residuals of every applicable statistic, ranked by ``|z|`` (largest first). ``workers``:
    threads the syntheses' statistics are spread over (the same values: each is a pure
    function of its synthesis, its caches per thread)."""
    measured = stack.measured
    synth = map_on_threads(stack.statistics, synthesized, workers)
    out = []
    for name, m in measured.items():
        values = np.array([s[name] for s in synth])
        mean, std = float(values.mean()), float(values.std(ddof=1)) if len(values) > 1 else 0.0
        res = STATISTICS[name].resolution(stack.frames_dn, abs(mean))  # null: the model count
        z = (m - mean) / math.sqrt(std**2 + res**2)
        rel = abs(m - mean) / max(abs(m), 3.0 * std, res)
        r = Residual(name, m, mean, std, float(z), float(rel), bool(abs(z) > z_min and rel > rel_min), effects_for(name),
                     STATISTICS[name].base)
        if STATISTICS[name].pooled:  # its degrees of freedom counted, as when pooled over stacks (``pool_residuals``)
            own = {"measured": m, "synth_mean": mean, "synth_std": std, "z": float(z), "rel_error": float(rel),
                   "resolution": res, "dof": stack.frames_dn.shape[0] - 1, "n_synth": len(values)}
            r = dataclasses.replace(_joint(name, [own], z_min, rel_min), pooled={"stack": own, "over": [stack.label]})
        out.append(r)
    return sorted(out, key=lambda r: -abs(r.z))


def _ratio_z(ratio: float, dof: float, dof_model: float) -> float:
    """A ratio of variances (measured over model, ``dof`` and ``dof_model`` degrees of freedom:
    an F variate) as a standard normal z, its tail probability's quantile on either side."""
    z = norm.isf(f_dist.sf(ratio, dof, dof_model)) if ratio >= 1.0 else norm.ppf(f_dist.cdf(ratio, dof, dof_model))
    return float(np.clip(z, -40.0, 40.0))


def _joint(name: str, parts: list[dict], z_min: float, rel_min: float) -> Residual:
    """The residual of a pooled statistic over stacks (``parts``: each stack's own figures).
    A spread of N frames has N - 1 degrees of freedom; the measured variances are pooled,
    and so are the model's (mean square of its syntheses' values). The resolution (a flat's
    light, stable to 0.1 %: its square, ``floor``) is a variance the light may add or not:
    the measured variance is tested (an F ratio: the summed degrees of freedom over those of
    the syntheses) against the model's plus the floor above it and against the model's alone
    below it, z = 0 between. Pooling resolves the spread's variance better, not the light: a
    deviation of the pooled spread from the model's under the resolution is not significant."""
    dof = np.array([p["dof"] for p in parts], dtype=np.float64)
    d = float(dof.sum())
    n = np.array([p["n_synth"] for p in parts], dtype=np.float64)
    measured = float(np.sum(dof * np.square([p["measured"] for p in parts])) / d)
    # the syntheses' mean square, from their mean and spread (ddof 1)
    squares = np.square([p["synth_mean"] for p in parts]) + np.square([p["synth_std"] for p in parts]) * (n - 1) / n
    model = float(np.sum(dof * squares) / d)
    floor = float(np.sum(dof * np.square([p["resolution"] for p in parts])) / d)
    d_model = float(np.sum(dof * n))  # the model's variance is itself estimated, from the syntheses

    def z_over(base):  # Satterthwaite: a known floor on top of the estimated variance
        d_eff = d_model * (base / model) ** 2 if model > 0 else math.inf
        return _ratio_z(measured / max(base, 1e-300), d, min(d_eff, 1e12))

    if measured > model + floor:
        z = max(z_over(model + floor), 0.0)
    elif measured < model:
        z = min(z_over(model), 0.0)
    else:
        z = 0.0
    m, mean = math.sqrt(measured), math.sqrt(model)
    spread = math.sqrt((model + floor) / (2.0 * d))  # of the pooled spread, under the model
    rel = abs(m - mean) / max(m, 3.0 * spread, math.sqrt(floor))
    resolved = abs(m - mean) > math.sqrt(floor)
    return Residual(name, m, mean, spread, z, float(rel), bool(abs(z) > z_min and rel > rel_min and resolved),
                    effects_for(name), STATISTICS[name].base)


def pool_residuals(diags: dict, z_min: float = 6.0, rel_min: float = 0.1) -> dict:
    """``diags`` ({label: (residuals, syntheses)}) with every pooled statistic judged over all
    the stacks that have it: the first of them (in ``diags``' order) carries the joint
    residual (``_joint``), the others keep their own figures, not significant. A flat pair
    holds one degree of freedom of a frame-to-frame spread, twenty pairs twenty. Pure
    (new residuals) and idempotent: each stack's own figures stay in ``pooled["stack"]``."""
    carriers: dict = {}
    for label, (residuals, _) in diags.items():
        for r in residuals:
            if r.pooled:
                carriers.setdefault(r.statistic, []).append(label)
    if not carriers:
        return diags
    own = {(label, r.statistic): r.pooled["stack"] for label, (res, _) in diags.items() for r in res if r.pooled}
    joint = {name: _joint(name, [own[(lb, name)] for lb in labels], z_min, rel_min) for name, labels in carriers.items()}
    out = {}
    for label, (residuals, synthesized) in diags.items():
        new = []
        for r in residuals:
            if r.pooled:
                labels, stack = carriers[r.statistic], own[(label, r.statistic)]
                if label == labels[0]:
                    r = dataclasses.replace(joint[r.statistic], pooled={"stack": stack, "over": list(labels)})
                else:
                    r = dataclasses.replace(r, measured=stack["measured"], synth_mean=stack["synth_mean"],
                                            synth_std=stack["synth_std"], z=stack["z"], rel_error=stack["rel_error"],
                                            significant=False, pooled={"stack": stack, "into": labels[0]})
            new.append(r)
        out[label] = (sorted(new, key=lambda r: -abs(r.z)), synthesized)
    return out


def diagnose(stack: FrameStack, profile, *, model: str | None = None, n_synth: int = 12, seed: int = 0,
             z_min: float = 6.0, rel_min: float = 0.1, offsets: list | None = None, workers: int = 1):
    """Synthesize ``n_synth`` stacks like ``stack`` and rank the residuals (``offsets``: the
    colour bias, if already fitted; see ``synthesize``; ``workers``: threads for the
    syntheses' statistics, see ``compare``).

    Returns ``(residuals, synthesized)``; ``synthesized`` (n_synth, N, 4, h, w) DN is the
    baseline the estimators subtract."""
    if n_synth < 3:
        raise ValueError(f"n_synth must be >= 3 to estimate the spread of the syntheses, got {n_synth}")
    profile = NoiseProfile.load(profile)
    synthesized = synthesize(profile, stack, n_synth, seed, model, offsets)
    return compare(stack, synthesized, z_min, rel_min, workers), synthesized


def battery_error(residuals: list[Residual]) -> dict:
    """Summary over the battery: mean relative error, rms z, count of significant residuals."""
    rel = [r.rel_error for r in residuals]
    zs = [r.z for r in residuals]
    return {"mean_rel_error": float(np.mean(rel)), "rms_z": float(np.sqrt(np.mean(np.square(zs)))),
            "n_significant": int(sum(r.significant for r in residuals))}
