"""Re-fit the base read noise after the loop adds an effect.

Stage 1 of calibration measures the read noise of bias frames as all of their temporal
pixel noise. An effect the loop adds later (temporal column noise, a per-frame smooth
field, ...) explains part of that same variance, so the model then counts it twice: its
bias frames come out noisier than the measured ones (``temporal_std`` with z < 0). The
re-fit gives the read-noise component only what the other components leave:

    sigma_read_new^2 = sigma_read^2 - (synthesized temporal_std^2 - measured temporal_std^2)

per bias stack where that overshoot is statistically significant (never raising the read noise;
a cut below half the calibrated sigma is not made: the added effect's estimate is then off),
and moves the profile's read-noise relations by a
least-squares line through ``log(factor)`` against ``log(K)``, so that the profile a user
trains with carries the same correction. Units: DN.

The variance taken out also diluted the tails calibration fitted the Tukey lambda to (the
part taken out, column noise or a smooth field, is near-Gaussian), so the re-fitted read
noise gets the heavier lambda whose sum with that Gaussian part has the calibrated tail: the
fraction beyond 5 robust sigmas (``shape_for_variance``). A re-fit that kept lambda thinned
the tails: at a factor of 0.83, 10x fewer pixels beyond 5 sigmas than measured
(``benchmarks/bench_loop.py``), which the loop then took for impulses or telegraph pixels.
"""
from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from scipy import optimize

from ..augment import parse_model
from ..distributions import tukey_lambda_survival, tukey_lambda_variance
from ..relations import LogLinear
from ..statistics import MAD_TO_SIGMA, center_scale, frame_statistics, grid_step, repaired, sensor_row_means
from ..effects.black_step import locate_steps
from .clip_correction import clipped
from .diagnose import fitted_offsets, synthesis_fixed, synthesize

MIN_FACTOR = 0.5  # no re-fit that would cut sigma below half its calibrated value
ROW_MIN_FACTOR = 0.1  # sigma_r may fall further: a strong tone can hold most of a sensor's row variance
LAMBDA_RANGE = (-0.24, 0.1349)  # heavy-tailed Tukey lambdas (lighter ones come from coarse codes or clipping)
TAIL_Z = 5.0  # robust sigmas (1.4826 MAD): where the battery's ``tail_mass`` counts the tail
SECANT_DAMPING = 0.6  # share of a secant step in lambda the shape re-fit takes
_NODES, _WEIGHTS = np.polynomial.hermite_e.hermegauss(48)
_WEIGHTS = _WEIGHTS / _WEIGHTS.sum()


def _survival(lam: float, share: float, t: float) -> float:
    """P(X > t) for X = a T + G of unit variance, T standard Tukey ``lam``, G Gaussian, the
    read-noise part holding ``share`` of the variance (a^2 v(lam) = share, G the rest)."""
    a = math.sqrt(share / tukey_lambda_variance(lam))
    g = math.sqrt(max(1.0 - share, 0.0)) * _NODES
    return float(np.sum(_WEIGHTS * tukey_lambda_survival((t - g) / a, lam) * (t - g >= 0)
                        + _WEIGHTS * (1.0 - tukey_lambda_survival((g - t) / a, lam)) * (t - g < 0)))


def _tail(lam: float, share: float, t: float | None = None) -> float:
    """P(|X| > TAIL_Z robust sigmas) for X of ``_survival``; with ``t``, P(|X| > t) (X in units
    of its standard deviation)."""
    if t is None:
        mad = optimize.brentq(lambda m: _survival(lam, share, m) - 0.25, 1e-6, 50.0, xtol=1e-9)
        t = TAIL_Z * MAD_TO_SIGMA * mad
    return 2.0 * _survival(lam, share, t)


@functools.lru_cache(maxsize=4096)
def _shape(lam: float, factor: float) -> float:
    lo, hi = LAMBDA_RANGE
    if factor < 1.0:  # the read part keeps factor^2 of the variance, a Gaussian part the rest
        target = _tail(lam, 1.0)
        f = lambda x: _tail(x, factor**2) - target  # noqa: E731
    else:  # the read part takes back variance a Gaussian part held
        target = _tail(lam, 1.0 / factor**2)
        f = lambda x: _tail(x, 1.0) - target  # noqa: E731
    if f(lo) <= 0:
        return lo
    if f(hi) >= 0:
        return hi
    return float(optimize.brentq(f, lo, hi, xtol=1e-5))


def shape_for_variance(lam: float, factor: float) -> float:
    """The Tukey lambda of a read-noise component whose variance becomes ``factor``^2 times
    its own, the difference moved to (factor < 1) or from (factor > 1) a near-Gaussian
    component, such that the frames keep their tail: the fraction of values beyond
    ``TAIL_Z`` robust sigmas. Heavy tails only (lambda in ``LAMBDA_RANGE``)."""
    if factor == 1.0 or not LAMBDA_RANGE[0] < lam < LAMBDA_RANGE[1]:
        return float(lam)
    return _shape(round(float(lam), 6), round(float(factor), 6))


def _tukey_pair(sigma_tl: float, lam: float, factor: float) -> tuple[float, float]:
    """(sigma_tl, lambda) of a Tukey read noise whose variance becomes ``factor``^2 times, its
    lambda from ``shape_for_variance``."""
    new = shape_for_variance(lam, factor)
    return sigma_tl * factor * math.sqrt(tukey_lambda_variance(lam) / tukey_lambda_variance(new)), new


def _read_noise_update(fixed: dict, factor: float) -> dict:
    """The read-noise parameters of a synthesis with ``fixed`` after its variance becomes
    ``factor``^2 times: sigma_g scaled; the Tukey pair of ``_tukey_pair``."""
    out = {"sigma_g": float(fixed["sigma_g"]) * factor} if "sigma_g" in fixed else {}
    if "sigma_tl" in fixed and "lambda" not in fixed:
        out["sigma_tl"] = float(fixed["sigma_tl"]) * factor
    elif "sigma_tl" in fixed:
        out["sigma_tl"], out["lambda"] = _tukey_pair(float(fixed["sigma_tl"]), float(fixed["lambda"]), factor)
    return out


def _read_variance(fixed: dict, tokens) -> float:
    """Variance (DN^2) of the base read-noise component of a synthesis with ``fixed``."""
    if "G*" in tokens and "sigma_tl" in fixed:
        return float(fixed["sigma_tl"]) ** 2 * tukey_lambda_variance(float(fixed["lambda"]))
    return float(fixed["sigma_g"]) ** 2


def read_noise_factors(stacks, diags, profile, model=None, z_min: float = 6.0, seed: int = 0) -> dict:
    """{bias stack label: factor on the read-noise sigma} where the model's temporal noise
    exceeds the measured one by more than ``z_min`` spreads (statistically significant; a
    small relative error is corrected too, since the correction is exact). A stack clipped
    by the model's ``Clip`` gets the factor by simulation (``_factor_through_clip``).
    ``diags``: label -> (residuals, syntheses)."""
    tokens = parse_model(model or profile.richest_model)
    factors = {}
    for i, stack in enumerate(stacks):
        if stack.kind != "bias":
            continue
        r = next((r for r in diags[stack.label][0] if r.statistic == "temporal_std"), None)
        if r is None or r.z >= -z_min:
            continue
        if clipped(stack, profile):
            f = _factor_through_clip(stack, profile, model, float(r.measured), seed + 7 * i)
            if f is not None:
                factors[stack.label] = f
            continue
        var = _read_variance(synthesis_fixed(profile, stack), tokens)
        if var <= 0:
            continue
        f2 = 1.0 - (r.synth_mean**2 - r.measured**2) / var
        if f2 < MIN_FACTOR**2:
            continue  # more than double counting: the added effect's estimate is off, not the read noise
        factors[stack.label] = float(math.sqrt(f2))
    return factors


def _temporal_std_at(stack, profile, factor: float, model, seed: int) -> float:
    """The model's ``temporal_std`` (DN) of bias stack ``stack`` with its read noise times
    ``factor``: two syntheses, the colour bias fitted again (a clip moves the mean with the noise)."""
    scaled, prof = stack, profile
    if factor != 1.0:
        [scaled], prof = apply_read_noise_factors([stack], profile, {stack.label: factor}, model)
    return _mean_over_syntheses(scaled, prof, model, seed,
                                lambda f: frame_statistics(f, "bias", names=["temporal_std"])["temporal_std"])


def _mean_over_syntheses(stack, profile, model, seed: int, statistic) -> float:
    """``statistic`` of two syntheses of ``stack`` by ``profile``, averaged, the colour bias
    fitted again first (a clip moves the mean with the noise)."""
    synth = synthesize(profile, stack, 2, seed, model, offsets=fitted_offsets(profile, stack, seed, model))
    return float(np.mean([statistic(f) for f in synth]))


def _factor_by_simulation(at, measured: float, power: float, lowest: float) -> float | None:
    """The factor f on a noise sigma whose synthesis ``at(f)`` gives the ``measured`` value of a
    statistic that falls with f: the ratio step ``(measured / at(1)) ** power`` from the model
    as it is, then the secant through the two syntheses. None where the model is not above the
    measurement or the factor would fall below ``lowest``."""
    s0 = at(1.0)
    if not s0 > measured:
        return None
    f1 = max((measured / s0) ** power, lowest)
    s1 = at(f1)
    f = f1 if abs(s1 - s0) <= 1e-9 * s0 else f1 + (measured - s1) * (f1 - 1.0) / (s1 - s0)
    return float(f) if lowest <= f < 1.0 else None


def _factor_through_clip(stack, profile, model, measured: float, seed: int) -> float | None:
    """The read-noise factor that gives a clipped bias stack's synthesis the measured
    ``temporal_std`` (DN). A clip keeps only part of a pixel's temporal variance, a part
    that depends on the noise itself (half the values at a black level at code 0 keep about
    a third of it), so the variance difference of the unclipped case cuts too little; the
    factor is found by simulation instead (``_factor_by_simulation``). None where it would
    cut below ``MIN_FACTOR``."""
    return _factor_by_simulation(lambda f: _temporal_std_at(stack, profile, f, model, seed), measured, 1.0, MIN_FACTOR)


def _shift(rel: LogLinear | None, slope: float, intercept: float, k_ref: float) -> LogLinear | None:
    """``rel`` times ``exp(slope * log K + intercept)``, every segment and the floor."""
    if rel is None:
        return None
    segments = tuple(_shift(s, slope, intercept, k_ref) for s in rel.segments)
    floor = rel.floor_dn * math.exp(slope * math.log(k_ref) + intercept)
    return dataclasses.replace(rel, slope=rel.slope + slope, intercept=rel.intercept + intercept,
                               segments=segments, floor_dn=floor)


def _scaled_stacks(stacks, profile, factors: dict, update):
    """(stacks with their base updated by ``update(fixed, factor)`` (the new parameters) at
    their gain's factor, the line (slope, intercept, K_ref) through log(factor) against
    log(K) over the bias stacks)."""
    by_k = {stack.k: factors.get(stack.label, 1.0) for stack in stacks if stack.kind == "bias"}
    out = []
    for stack in stacks:
        f = by_k.get(stack.k, 1.0)
        if f == 1.0:
            out.append(stack)
            continue
        base = dict(stack.base)
        base.update(update(synthesis_fixed(profile, stack), f))
        out.append(dataclasses.replace(stack, base=base))
    # a dark or flat stack takes its offsets from its bias stack: from the re-fitted one
    renewed = {id(old): new for old, new in zip(stacks, out) if old.kind == "bias" and new is not old}
    out = [dataclasses.replace(s, offsets_of=renewed[id(s.offsets_of)]) if id(s.offsets_of) in renewed else s for s in out]
    ks = np.array(sorted(by_k))
    logf = np.log([by_k[k] for k in ks])
    if ks.size >= 2 and np.ptp(np.log(ks)) > 0:
        slope, intercept = np.polyfit(np.log(ks), logf, 1)
    else:
        slope, intercept = 0.0, float(logf.mean())
    return out, (float(slope), float(intercept), float(np.exp(np.log(ks).mean())))


def apply_read_noise_factors(stacks, profile, factors: dict, model=None):
    """(stacks, profile) with the read noise scaled by ``factors`` (bias stack label ->
    factor): every stack of that bias stack's gain gets the new sigmas in its ``base``, and
    the profile's read-noise relations move by the line through log(factor) against log(K)
    over all bias stacks (factor 1 where nothing was re-fitted)."""
    out, line = _scaled_stacks(stacks, profile, factors, _read_noise_update)
    profile = dataclasses.replace(profile, gaussian_scale=_shift(profile.gaussian_scale, *line))
    if profile.tukey_scale is None:
        return out, profile
    # the Tukey pair at each K of the shape table, by the line's factor there; the scale's
    # relation moves by the line through the log of its own factors at those K
    slope, intercept, k_ref = line
    ks = np.array(profile.tukey_shape.k, dtype=np.float64)
    f = np.exp(slope * np.log(ks) + intercept)
    pairs = [_tukey_pair(1.0, float(v), float(fk)) for v, fk in zip(profile.tukey_shape.values, f)]
    scale_f, lams = [a for a, _ in pairs], [b for _, b in pairs]
    if ks.size >= 2 and np.ptp(np.log(ks)) > 0:
        s_slope, s_intercept = np.polyfit(np.log(ks), np.log(scale_f), 1)
    else:
        s_slope, s_intercept = 0.0, float(np.log(scale_f).mean())
    shape = dataclasses.replace(profile.tukey_shape, values=tuple(lams))
    return out, dataclasses.replace(profile, tukey_shape=shape,
                                    tukey_scale=_shift(profile.tukey_scale, float(s_slope), float(s_intercept), k_ref))


def _tail_threshold(frames) -> tuple[float, float]:
    """(where ``tail_mass`` counts the tail in standard deviations of the counted values, the
    variance the cell spread adds: step^2 / 12, DN^2), the median over frames and channels."""
    f = np.asarray(frames, dtype=np.float64).reshape(frames.shape[0] * 4, -1)
    step = grid_step(f)
    dither = step**2 / 12.0
    ratios = [center_scale(row, step)[1] / max(math.sqrt(row.var() + dither), 1e-12) for row in f]
    return TAIL_Z * float(np.median(ratios)), dither


def read_shape_updates(stacks, diags, profile, model=None, z_min: float = 6.0, history: dict | None = None) -> dict:
    """{bias stack label: Tukey lambda} where the model's tail (``tail_mass``: the fraction
    beyond 5 robust sigmas of each frame and channel) exceeds the measured one by more than
    ``z_min`` spreads: the lighter lambda whose tail, with the base read noise holding its
    share of the pixel variance (``_tail``), is the measured fraction of the model's.

    Calibration fits lambda to the pooled bias frames: where the channels or regions read
    with noise of different levels (what ``ReadMap`` adds), their mixture has heavier tails
    than any of them, and the tail-keeping variance re-fit makes them heavier still; the
    battery's tail is read per frame and channel. Only lighter than a lambda whose tail is
    too heavy: a tail the model lacks is left to the effects that make one (impulses,
    telegraph pixels, hot pixels).

    ``history`` (label -> the lambdas tried with the model's tail there, updated here) makes
    the later steps of a re-fit a search: a damped secant in log(tail) through the last two
    (other effects' tails, telegraph pixels say, make the analytic step fall short), and,
    once a step has made the tail significantly too light, regula falsi between the last
    lambda too heavy and the first too light."""
    if "G*" not in parse_model(model or profile.richest_model) or profile.tukey_scale is None:
        return {}
    history = history if history is not None else {}
    out = {}
    for stack in stacks:
        if stack.kind != "bias":
            continue
        res = {r.statistic: r for r in diags[stack.label][0]}
        tail, pixel = res.get("tail_mass"), res.get("pixel_std")
        if tail is None or pixel is None or not tail.synth_mean > 0 or not pixel.synth_mean > 0 or not tail.measured > 0:
            continue
        fixed = synthesis_fixed(profile, stack)
        lam = float(fixed["lambda"])
        if not math.isfinite(tukey_lambda_variance(lam)):
            continue  # lambda <= -1/2: no variance to keep
        tried = history.setdefault(stack.label, {"heavy": None, "light": None})
        if tail.z < -z_min:  # too heavy here
            previous, tried["heavy"] = tried["heavy"], (lam, float(tail.synth_mean))
        elif tail.z > z_min and tried["heavy"] is not None:  # a step went too far: too light here
            previous, tried["light"] = None, (lam, float(tail.synth_mean))
        else:
            continue
        hi = LAMBDA_RANGE[1]
        log_target = math.log(tail.measured)
        if tried["light"] is not None:  # bracketed: regula falsi in log(tail)
            (a, ta), (b, tb) = tried["heavy"], tried["light"]
            new = a + (b - a) * (math.log(ta) - log_target) / (math.log(ta) - math.log(tb)) if ta > tb else 0.5 * (a + b)
        elif previous is not None and previous[0] < lam and 0 < tail.synth_mean < previous[1]:
            slope = (lam - previous[0]) / (math.log(tail.synth_mean) - math.log(previous[1]))  # lambda per log(tail), < 0
            # damped: towards the Gaussian the tail falls faster than a line in log(tail) says
            new = min(lam + SECANT_DAMPING * slope * (log_target - math.log(tail.synth_mean)), hi)
        else:
            # the tail where the statistic counts it, in each channel's own sigmas: TAIL_Z x its
            # robust scale over its standard deviation, the median over frames and channels (a
            # noisier channel would inflate a pooled one); whole codes count spread over their
            # cells (``outside_fraction``), which adds a cell's variance to the pixels'
            t, dither = _tail_threshold(stack.frames_dn)
            share = min(_read_variance(fixed, ("G*",)) / (pixel.synth_mean**2 + dither), 1.0)
            # the read noise's part of the model's tail (its prediction, at most the whole) is
            # scaled to what the measured tail leaves after the rest (telegraph pixels, hot
            # pixels), at most tenfold down per step
            pred = _tail(lam, share, t)
            read = min(pred, float(tail.synth_mean))
            target = pred * max(tail.measured - (tail.synth_mean - read), 0.1 * read) / read
            g = lambda x: _tail(x, share, t) - target  # noqa: E731  (falls as lambda rises towards the Gaussian's)
            new = hi if g(hi) >= 0 else float(optimize.brentq(g, lam, hi, xtol=1e-4))
        out[stack.label] = float(new)
    return out


def apply_read_shapes(stacks, profile, lambdas: dict):
    """(stacks, profile) with the Tukey lambda of each bias stack of ``lambdas`` (label ->
    lambda) and of every stack of its gain, the variance kept (sigma_TL scaled); the profile's
    shape table takes the new lambda at the record nearest that gain, and its scale relation
    moves by the line through the log of the scale factors against log(K) (factor 1 at the
    gains left alone)."""
    by_k = {}
    for stack in stacks:
        if stack.kind == "bias" and stack.label in lambdas:
            fixed = synthesis_fixed(profile, stack)
            old, new = float(fixed["lambda"]), float(lambdas[stack.label])
            by_k[stack.k] = (new, math.sqrt(tukey_lambda_variance(old) / tukey_lambda_variance(new)))
    out = []
    for stack in stacks:
        if stack.k not in by_k:
            out.append(stack)
            continue
        fixed = synthesis_fixed(profile, stack)
        lam, f = by_k[stack.k]
        out.append(dataclasses.replace(stack, base={**stack.base, "lambda": lam, "sigma_tl": float(fixed["sigma_tl"]) * f}))
    renewed = {id(old): new for old, new in zip(stacks, out) if old.kind == "bias" and new is not old}
    out = [dataclasses.replace(s, offsets_of=renewed[id(s.offsets_of)]) if id(s.offsets_of) in renewed else s for s in out]
    if not by_k:
        return out, profile
    table = profile.tukey_shape
    values = list(table.values)
    for k, (lam, _) in by_k.items():
        values[int(np.argmin(np.abs(np.log(np.asarray(table.k, dtype=np.float64)) - math.log(k))))] = lam
    ks = np.array(sorted({s.k for s in stacks if s.kind == "bias"}))
    logf = np.log([by_k[k][1] if k in by_k else 1.0 for k in ks])
    if ks.size >= 2 and np.ptp(np.log(ks)) > 0:
        slope, intercept = np.polyfit(np.log(ks), logf, 1)
    else:
        slope, intercept = 0.0, float(logf.mean())
    return out, dataclasses.replace(profile, tukey_shape=dataclasses.replace(table, values=tuple(values)),
                                    tukey_scale=_shift(profile.tukey_scale, float(slope), float(intercept),
                                                       float(np.exp(np.log(ks).mean()))))


def _row_variance(frames, row_edges=(), detrend: bool = False, destep: bool = False) -> float:
    """Variance over sensor rows of the sensor-row means (each frame's channels centred),
    mean over frames, DN^2: what calibration reads sigma_r from (plus read noise / row length).
    Within the bands of readout taps cut by ``row_edges`` (sensor rows: ``TapBlack``'s), each
    frame's band mean taken out: their per-frame steps are the taps' own, and a handful of
    taps and frames would make the syntheses' spread too wide to see the row noise under them.
    With ``detrend`` (a profile with ``BlackRamp``) each frame's straight line down the rows is
    taken out first, for the same reason: the ramps' slopes are the ramps' own. With ``destep``
    (a profile with ``BlackStep``) each frame's step (``black_step.locate_steps``) is taken out:
    the steps' rows and sizes are the steps' own (at random rows, a few frames' steps alone
    spread the syntheses' row variance by a third at 1.5 DN)."""
    f = np.asarray(repaired(np.asarray(frames, dtype=np.float64)))
    m = sensor_row_means(f - f.mean(axis=(2, 3), keepdims=True))
    if destep and m.shape[0] >= 3:
        _, at, size, _ = locate_steps(f)
        s = (np.arange(m.shape[1])[None, :] >= at[:, None]).astype(np.float64)
        m = m - size[:, None] * (s - s.mean(axis=1, keepdims=True))
    if detrend:
        i = np.arange(m.shape[1]) - 0.5 * (m.shape[1] - 1)
        m = m - np.outer(m @ i / float(i @ i), i)
    band = np.searchsorted(np.asarray(row_edges, dtype=np.int64), np.arange(m.shape[1]), side="right")
    bands = int(band.max()) + 1  # one band without taps: the plain variance (ddof 1)
    means = np.stack([m[:, band == t].mean(axis=1) for t in range(bands)], axis=1)  # (N, bands)
    r = m - means[:, band]
    return float((r * r).sum(axis=1).mean() / max(m.shape[1] - bands - int(detrend) - int(destep), 1))


def _tap_rows(profile) -> tuple[list, bool, bool]:
    """(the row edges of the profile's readout taps (``TapBlack``), or none; whether its black
    ramps down the rows (``BlackRamp``) are taken out; whether its black steps (``BlackStep``)
    are): how ``_row_variance`` reads its rows."""
    taps = profile.effects.get("TapBlack")
    ramps = profile.effects.get("BlackRamp")
    return (list(taps["row_edges"]) if isinstance(taps, dict) else [],
            isinstance(ramps, dict) and any(float(x) > 0 for x in ramps.get("row_dn", [])),
            "BlackStep" in profile.effects)


def _row_variance_at(stack, profile, factor: float, model, seed: int, edges) -> float:
    """The model's ``_row_variance`` (DN^2) of bias stack ``stack`` with its row noise times
    ``factor``: two syntheses, the colour bias fitted again (a clip moves the mean with the noise)."""
    scaled, prof = stack, profile
    if factor != 1.0:
        [scaled], prof = apply_row_noise_factors([stack], profile, {stack.label: factor})
    return _mean_over_syntheses(scaled, prof, model, seed, lambda f: _row_variance(f, *edges))


def row_noise_factors(stacks, diags, profile, z_min: float = 6.0, model=None, seed: int = 0) -> dict:
    """{bias stack label: factor on the row-noise sigma_r} where the model's sensor-row
    means vary more than the measured ones by more than ``z_min`` spreads of the syntheses:
    an added effect (a banding tone) now explains row variance calibration gave sigma_r.
    sigma_r_new^2 = sigma_r^2 - (synthesized - measured variance); no cut below ROW_MIN_FACTOR.
    A stack clipped by the model's ``Clip`` keeps only part of its row variance (a third with
    half the values at the floor), so there the factor comes by simulation, as for the read
    noise (``_factor_by_simulation``)."""
    factors = {}
    edges = _tap_rows(profile)
    for i, stack in enumerate(stacks):
        if stack.kind != "bias":
            continue
        synth = [_row_variance(s, *edges) for s in diags[stack.label][1]]
        if len(synth) < 2:
            continue
        measured, model_var, spread = _row_variance(stack.frames_dn, *edges), float(np.mean(synth)), float(np.std(synth, ddof=1))
        if model_var - measured <= z_min * spread:
            continue
        sigma_r = float(synthesis_fixed(profile, stack).get("sigma_r", 0.0))
        if sigma_r <= 0:
            continue
        if clipped(stack, profile):
            f = _factor_by_simulation(lambda g: _row_variance_at(stack, profile, g, model, seed + 7 * i, edges),
                                      measured, 0.5, ROW_MIN_FACTOR)
            if f is not None:
                factors[stack.label] = f
            continue
        f2 = 1.0 - (model_var - measured) / sigma_r**2
        if f2 < ROW_MIN_FACTOR**2:
            continue
        factors[stack.label] = float(math.sqrt(f2))
    return factors


def row_noise_restore(stacks, before: dict, after: dict, profile, z_min: float = 6.0) -> dict:
    """{bias stack label: factor > 1 on sigma_r} where an added effect took row variance away
    from the model: its sensor-row means now vary less than the measured ones by more than
    ``z_min`` spreads of the syntheses, and before it (``before``: the diagnoses of the model
    without it) they did not. A code map is such an effect: sigma_r was calibrated on the
    rows of quantized frames, and re-quantized the row offsets shrink again (by g^2 = after
    over before in variance), so sigma_r^2 grows by (measured - after) / g^2."""
    factors = {}
    edges = _tap_rows(profile)
    for stack in stacks:
        if stack.kind != "bias" or stack.label not in before or stack.label not in after:
            continue
        old = [_row_variance(s, *edges) for s in before[stack.label][1]]
        new = [_row_variance(s, *edges) for s in after[stack.label][1]]
        if len(old) < 2 or len(new) < 2:
            continue
        measured = _row_variance(stack.frames_dn, *edges)
        model, spread = float(np.mean(new)), float(np.std(new, ddof=1))
        if measured - model <= z_min * spread or measured - float(np.mean(old)) > z_min * float(np.std(old, ddof=1)):
            continue
        sigma_r = float(synthesis_fixed(profile, stack).get("sigma_r", 0.0))
        if sigma_r <= 0:
            continue
        g2 = min(model / float(np.mean(old)), 1.0)
        factors[stack.label] = float(math.sqrt(1.0 + (measured - model) / g2 / sigma_r**2))
    return factors


def apply_row_noise_factors(stacks, profile, factors: dict):
    """(stacks, profile) with sigma_r scaled by ``factors`` (bias stack label -> factor), as
    ``apply_read_noise_factors`` does for the read noise: every stack of that gain, and the
    profile's row-noise relation by the line through log(factor) against log(K)."""
    out, line = _scaled_stacks(stacks, profile, factors,
                               lambda fixed, f: {"sigma_r": float(fixed["sigma_r"]) * f} if "sigma_r" in fixed else {})
    return out, dataclasses.replace(profile, row_scale=_shift(profile.row_scale, *line))
