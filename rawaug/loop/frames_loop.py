"""The closed loop on frames: diagnose, add the missing effect that explains most, repeat.

Each step collects the candidate effects (not in the profile, not yet rejected) that some
significant residual points to; estimates each on every stack it applies to (one record per
gain K); re-diagnoses with it, all candidates against the same syntheses' seeds. A candidate
is acceptable if the error of its evidence statistic fell by at least 20 % and no more
residuals are significant than before (a candidate that replaces a base stage's
distribution, such as the measured read-noise distribution, is judged on the mean error of
all its statistics that were significant); of the acceptable ones, the one that lowers the
battery's mean relative error most is added (greedy model selection: one statistic often
points to several effects -- a fixed column pattern also raises the per-pixel fixed-pattern
spread -- and only trying them tells which one the data hold). A rejected candidate is tried
again once another effect has been added (its estimate depends on the model); the loop ends
when no significant residual points to an effect untried in the current model. Physical
candidates are tried first; a measured fallback joins them only in a round where none of
them halves the error of its own evidence and of the fallback's (``EXPLAIN_FACTOR``). A pooled
statistic (``pool_residuals``: one degree of freedom per flat pair) is one residual over all
the stacks that have it: screened and confirmed on all of them.

Then backward elimination: an effect added early may be redundant once a later one explains
its residual too (a row drift under a smooth per-frame field that a later ``LowFreq``
reproduces in full). Each added effect that a later one shares a statistic with, or every
one while the final model overshoots any statistic (hot pixels added for the high first rows
that a later ``LineMap`` reproduces raise the fixed pattern), is taken out in turn, with the
base stage's re-fit it was judged with undone. One whose removal leaves no residual
significant that is not significant with it is removed -- or, while the model overshoots,
one whose removal leaves the battery no worse -- measured fallbacks before physical effects, and the effects added after it are estimated
again, until every effect left is needed.

After each added effect the base read noise is re-fitted where the model's bias frames now
come out noisier than the measured ones (``refit``): calibration had given the read noise
all of the temporal noise, part of which the added effect now explains. A candidate whose
module says it takes over a base stage's variance (``SHARES_READ_NOISE``: correlated read
noise; ``SHARES_ROW_NOISE``: banding, fixed rows, per-channel rows) is judged with that
stage re-fitted already, or its added variance alone would get it rejected.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import torch

from ..effects.k_records import merge_records
from ..profile import NoiseProfile
from ..relations import KTable
from ..statistics import repaired
from .clip_correction import clip_corrected
from .diagnose import (FrameStack, Residual, battery_error, diagnose, fitted_offsets, map_on_threads, pool_residuals,
                       synthesis_fixed)
from .refit import (apply_read_noise_factors, apply_read_shapes, apply_row_noise_factors, read_noise_factors,
                    read_shape_updates, row_noise_factors, row_noise_restore)
from .registry import CANDIDATES
from .signatures import pooled_signature, step_signature

ACCEPT_FACTOR = 0.8  # an added effect must cut its evidence's error by at least 20 %
CONFIRM_FACTOR = 3  # a residual that would call for an effect is confirmed on 3x the syntheses, with fresh seeds
BATTERY_GROWTH = 1.25  # ... and may not raise the battery's mean relative error by more than a quarter
EXPLAIN_FACTOR = 0.5  # a physical effect explains its evidence where it halves its error; else fallbacks are tried beside it
SHAPE_STEPS = 4  # read-noise shape re-fits after an added effect, each from the tails of the last ones' syntheses


@dataclass
class Step:
    effect: str
    params: dict
    accepted: bool
    evidence: dict  # the triggering residual (before)
    stack: str
    error_before: float  # rel_error of the evidence statistic
    error_after: float
    z_after: float
    battery_before: dict
    battery_after: dict
    note: str = ""
    round: int = 0  # loop round (several candidates may be tried in one round)
    kind: str = "physical"  # or "measured": a fallback that reproduces what no physical effect explains
    evidence_after: dict = field(default_factory=dict)  # the evidence statistic with the effect added
    signature: dict = field(default_factory=dict)  # the curve behind the evidence (``signatures``), added steps only

    def to_dict(self):
        return self.__dict__.copy()


@dataclass
class LoopResult:
    profile: NoiseProfile
    steps: list = field(default_factory=list)
    initial: dict = field(default_factory=dict)  # stack label -> residuals
    final: dict = field(default_factory=dict)
    refits: list = field(default_factory=list)  # read-noise re-fits after added effects
    colour_bias: dict = field(default_factory=dict)  # K -> offsets (DN) fitted with the added effects
    unconfirmed: list = field(default_factory=list)  # residuals of the final model a larger synthesis sample did not confirm
    removed: list = field(default_factory=list)  # effects taken out at the end as redundant (backward elimination)
    resized: list = field(default_factory=list)  # effects sized again through a clip in the re-fitted base

    @property
    def added(self) -> list[str]:
        return [s.effect for s in self.steps if s.accepted]

    @property
    def explained_physically(self) -> list[str]:
        return [s.effect for s in self.steps if s.accepted and s.kind == "physical"]

    @property
    def reproduced_by_measurement(self) -> list[str]:
        return [s.effect for s in self.steps if s.accepted and s.kind == "measured"]

    def unexplained(self) -> list[tuple[str, Residual]]:
        """Significant residuals left at the end (none of the candidate effects fixed them),
        but those a larger synthesis sample did not confirm (``unconfirmed``)."""
        chance = {(u["stack"], u["statistic"]) for u in self.unconfirmed}
        return [(label, r) for label, res in self.final.items() for r in res if r.significant and (label, r.statistic) not in chance]


RESTORE_TOLERANCE = 1.05  # a battery's mean error moves by a few % between seeds of the syntheses
BOUND_CHUNK = 6  # stacks a trial's battery is diagnosed in at a time, once it can be beaten


class _Beaten(Exception):
    """A trial's battery stopped part-way: its mean error can no longer beat the best
    acceptable candidate's (``partial``: the sum of its residuals' errors so far; ``done``,
    ``total``: the stacks diagnosed, of)."""

    def __init__(self, partial: float, done: int, total: int):
        super().__init__(partial, done, total)
        self.partial, self.done, self.total = partial, done, total


def _battery(diags) -> dict:
    every = [r for res, _ in diags.values() for r in res]
    return battery_error(every)


def _without(step, profile, stacks, refits, model):
    """(profile, stacks) without an added effect: the re-fit of the base stage it was judged
    with (``_shares_noise``) undone, by the inverse factors (and the read noise's shape
    restored to its lambdas before the trial's shape re-fit)."""
    reduced = profile.without_effect(step.effect)
    for refit in refits:
        if refit.get("after") == step.effect and refit.get("what") and refit.get("kept"):
            if refit.get("lambdas_before"):  # the shape re-fit it was judged with, undone first
                stacks, reduced = apply_read_shapes(stacks, reduced, refit["lambdas_before"])
            inverse = {label: 1.0 / f for label, f in refit["factors"].items()}
            stacks, reduced = (apply_read_noise_factors(stacks, reduced, inverse, model) if refit["what"] == "read noise"
                               else apply_row_noise_factors(stacks, reduced, inverse))
    return reduced, stacks


def _shape_search(stacks, prof, diags, diagnose_fn, model, z_min):
    """The read noise's shape re-fitted where the model's tail overshoots (``read_shape_updates``):
    up to SHAPE_STEPS steps of its search, each diagnosed by ``diagnose_fn(profile, stacks,
    step)`` ({label: (residuals, syntheses)} of at least the bias stacks); it stops at a step
    that does not improve the battery, unless that step made a tail too light (the next one is
    then bracketed). Of the states tried, the start included, the one of least mean relative
    error among those no worse than the start in it and in the count of significant
    residuals. Returns (stacks, profile, diags, step or None: the last step taken, [lambdas of
    each step taken])."""
    states = [(stacks, prof, diags, None, [])]
    history: dict = {}
    for step in range(SHAPE_STEPS):
        s, p, d, _, taken = states[-1]
        lambdas = read_shape_updates(s, d, p, model, z_min=z_min, history=history)
        if not lambdas:
            break
        s2, p2 = apply_read_shapes(s, p, lambdas)
        d2 = diagnose_fn(p2, s2, step)
        states.append((s2, p2, d2, step, taken + [lambdas]))
        better = (_battery(d2)["mean_rel_error"] < _battery(d)["mean_rel_error"]
                  and _battery(d2)["n_significant"] <= _battery(d)["n_significant"])
        too_light = any(r.statistic == "tail_mass" and r.z > z_min for label in lambdas for r in d2[label][0])
        if not (better or too_light):
            break
    start = _battery(diags)
    fine = [st for st in states if _battery(st[2])["mean_rel_error"] <= start["mean_rel_error"]
            and _battery(st[2])["n_significant"] <= start["n_significant"]]
    return min(fine, key=lambda st: (_battery(st[2])["mean_rel_error"], _battery(st[2])["n_significant"]))


def _significant(diags) -> set:
    """(stack label, statistic) of every significant residual."""
    return {(label, r.statistic) for label, (res, _) in diags.items() for r in res if r.significant}


def _options(diags, tried, present, skip=frozenset()):
    """Untried effects that significant residuals point to: (token, stack label, strongest
    residual), most significant first; residuals ``(label, statistic)`` in ``skip`` left out."""
    best: dict = {}
    for label, (residuals, _) in diags.items():
        for r in residuals:
            if (label, r.statistic) in skip:
                continue
            # a candidate adds something that raises the statistics it is shown by: a statistic
            # the model overshoots (z < 0) calls for a refit, not for one more effect -- unless
            # the candidate replaces a base stage's shape (TWO_SIDED: a measured distribution) or is an offset of either sign (SIGNED)
            if not r.significant:
                continue
            for token in r.effects:
                if token in tried or token in present or (r.z <= 0 and not _signed(token)):
                    continue
                if token not in best or abs(r.z) > abs(best[token][2].z):
                    best[token] = (token, label, r)
    return sorted(best.values(), key=lambda o: -abs(o[2].z))


def _explained(option, trials) -> bool:
    """True where an acceptable physical trial that halves its own evidence's error also
    halves the error of ``option``'s evidence (or leaves it not significant): that fallback is
    kept out. A fixed column pattern that repeats every 8 columns: ``ColGain`` halves
    ``col_excess`` but leaves ``grid_excess``, which ``GainGrid`` reproduces."""
    _, label, evidence = option
    for step, _, new_diags, *_ in trials:
        if not (step.accepted and step.error_after <= EXPLAIN_FACTOR * step.error_before) or label not in (new_diags or {}):
            continue
        after = next((r for r in new_diags[label][0] if r.statistic == evidence.statistic), None)
        if after is None or not after.significant or after.rel_error <= EXPLAIN_FACTOR * evidence.rel_error:
            return True
    return False


def _signature(evidence: dict, label, by_label, before, after) -> dict:
    """The curve behind a step's evidence (``step_signature``) on its stack, or for a pooled
    residual on every stack it was pooled over (``pooled_signature``)."""
    over = (evidence.get("pooled") or {}).get("over") or [label]
    parts = [(by_label[lb].frames_dn, before[lb][1], after[lb][1]) for lb in over]
    return step_signature(evidence["statistic"], *parts[0]) if len(parts) == 1 else pooled_signature(evidence["statistic"], parts)


def _two_sided(token) -> bool:
    return bool(getattr(CANDIDATES[token].module, "TWO_SIDED", False))


def _signed(token) -> bool:
    """True for a candidate that can lower the statistics it is shown by (a measured
    distribution; ``SIGNED``: an offset of either sign)."""
    return _two_sided(token) or bool(getattr(CANDIDATES[token].module, "SIGNED", False))


def _evidence_error(token, evidence, before, after) -> tuple[float, float]:
    """(before, after) error of what a candidate is judged on: the relative error of the
    residual that suggested it; for a two-sided candidate (it replaces a distribution's
    shape, which several statistics see) the mean relative error of its statistics that
    were significant on that stack."""
    if not _two_sided(token):
        return evidence.rel_error, next(r.rel_error for r in after if r.statistic == evidence.statistic)
    names = {r.statistic for r in before if r.significant and r.statistic in CANDIDATES[token].statistics}
    mean = lambda res: float(np.mean([r.rel_error for r in res if r.statistic in names]))  # noqa: E731
    return mean(before), mean(after)


def _shares_noise(token, profile=None) -> str:
    """The base stage whose variance a candidate takes over ("read noise": ``SHARES_READ_NOISE``
    in its module; "row noise": ``SHARES_ROW_NOISE``), which calibration gave all of it; the
    candidate is then judged with that stage re-fitted. A fixed pattern's spread is read noise
    too where ``profile`` clips at its floor (``SHARES_READ_NOISE_UNDER_CLIP``): the censored fit
    reads the upper half of each frame's values, which the pattern widens. "" for the others."""
    module = CANDIDATES[token].module
    if getattr(module, "SHARES_READ_NOISE", False) or (
            getattr(module, "SHARES_READ_NOISE_UNDER_CLIP", False) and profile is not None and "Clip" in profile.effects):
        return "read noise"
    return "row noise" if getattr(module, "SHARES_ROW_NOISE", False) else ""


def _adds_nothing(token, params) -> bool:
    """True when a candidate's estimate would leave the model as it is (its module's ``empty``:
    no tone found, no pixel drawn, no spread): trying it costs a diagnosis and, for a candidate
    judged with a base stage re-fitted, could credit it with the re-fit alone."""
    empty = getattr(CANDIDATES[token].module, "empty", None)
    return bool(empty is not None and empty(params))


def _measured(token) -> bool:
    return bool(getattr(CANDIDATES[token].module, "MEASURED", False))


def black_level(stack) -> list | None:
    """The channel black levels (DN) under a dark or flat stack: its given offsets, else the
    channel means of its ISO's bias frames (defect lines repaired); None for a bias stack."""
    if stack.offsets_dn is not None:
        return [float(o) for o in stack.offsets_dn]
    if stack.offsets_of is None:
        return None
    return [float(m) for m in repaired(stack.offsets_of.frames_dn).mean(axis=(0, 2, 3))]


def _estimate(token, stacks, diags, seed, profile=None, model=None):
    """The candidate's parameters from the stacks (one record per gain), None where no stack
    can show it; with the ``profile`` it joins, its size corrected through the profile's clip
    (``clip_corrected``)."""
    cand = CANDIDATES[token]

    def one(stack):
        try:
            # estimated from what the statistics see: the frames with their defect lines
            # repaired, but for an effect that makes defect lines
            frames = stack.frames_dn if getattr(cand.module, "RAW_FRAMES", False) else repaired(stack.frames_dn)
            return cand.estimate(frames, list(diags[stack.label][1]), stack.k, level_dn=stack.level_dn,
                                 exposure_s=stack.exposure_s, seed=seed, series=stack.series, kind=stack.kind,
                                 black_dn=black_level(stack) if cand.wants("black_dn") else None,
                                 black_code=stack.black_code)
        except ValueError:
            return None  # this stack cannot show the effect (too few frames, not a flat)

    # the stacks' estimates on the threads (each from its own stack and seed: the same records, in order)
    records = [rec for rec in map_on_threads(one, stacks, torch.get_num_threads()) if rec is not None]
    if not records:
        return None
    if hasattr(cand.module, "combine"):
        params = cand.module.combine(records)
    elif all("k" in r for r in records):
        params = merge_records(records)
    else:  # one stack's record would stand for the camera's (the first stack is the dimmest)
        raise TypeError(f"effect {token!r}: its estimates carry no gain 'k' and its module "
                        f"{cand.module.__name__} has no combine(records); give it one")
    if profile is None or _adds_nothing(token, params):
        return params
    return clip_corrected(token, params, profile, stacks, lambda part: _estimate(token, part, diags, seed), model, seed)


def diagnose_stacks(prof, labels: list, which: list, step_seed: int, *, model=None, n_synth: int = 12,
                    z_min: float = 6.0, rel_min: float = 0.1) -> dict:
    """{label: (residuals, syntheses)} of the stacks ``which`` against ``prof``.

    A stack's seed is ``step_seed`` plus its place in ``labels`` (every stack of the loop), and
    the offsets a dark or flat takes from its bias stack are fitted with that bias stack's seed
    (once, for every stack that takes them, whether or not the bias stack is in ``which``), so
    a subset gives each of its stacks the result the whole battery would (a trial's
    screening). Stacks run on parallel threads (NumPy's partitions and FFTs release the GIL);
    the outcome does not depend on them."""
    which = list(which)
    prof = NoiseProfile.load(prof)
    sources = list({id(s.offsets_of): s.offsets_of for s in which if s.offsets_of is not None}.values())
    pilot = lambda src: fitted_offsets(prof, src, step_seed + labels.index(src.label), model)  # noqa: E731

    def job(stack, workers=1):
        src = stack.offsets_of if stack.offsets_of is not None else stack
        return diagnose(stack, prof, model=model, n_synth=n_synth, seed=step_seed + labels.index(stack.label), z_min=z_min,
                        rel_min=rel_min, offsets=offsets.get(id(src)), workers=workers)

    threads = torch.get_num_threads()
    offsets = dict(zip([id(src) for src in sources], map_on_threads(pilot, sources, threads)))
    if len(which) < 2:  # one stack: its syntheses' statistics on the threads instead
        results = [job(s, threads) for s in which]
    else:
        results = map_on_threads(job, which, threads)
    return pool_residuals({s.label: r for s, r in zip(which, results)}, z_min, rel_min)


def run_frame_loop(stacks: list[FrameStack], profile, *, model: str | None = None, n_synth: int = 12, seed: int = 0,
                   z_min: float = 6.0, rel_min: float = 0.1, max_steps: int = 8, log=None, given=()) -> LoopResult:
    """Fit the missing effects of ``profile`` to measured ``stacks``.

    Parameters
    ----------
    stacks : measured frame stacks (labels must be unique).
    profile : the fitted base model (``NoiseProfile``, built-in name or path).
    model : the base-model components used for the syntheses (default: the profile's richest).
    n_synth : syntheses per diagnosis (the spread behind every ``z``).
    z_min, rel_min : a residual is significant when ``|z| > z_min`` and its relative error
        exceeds ``rel_min`` (statistically and practically significant).
    given : effects of ``profile`` that calibration put there (the frames' code floor,
        ``Clip``): the base read noise is re-fitted with them first, as after an added effect.
    """
    if not stacks:
        raise ValueError("run_frame_loop needs at least one FrameStack")
    labels = [s.label for s in stacks]
    if len(set(labels)) != len(labels):
        raise ValueError(f"stack labels must be unique, got {labels}")
    current = NoiseProfile.load(profile)
    say = log or (lambda *_: None)
    def diagnose_all(prof, step_seed, which=None):
        return diagnose_stacks(prof, labels, which or stacks, step_seed, model=model, n_synth=n_synth, z_min=z_min,
                               rel_min=rel_min)

    by_label = {st.label: st for st in stacks}
    checks: dict = {}  # stack label -> its residuals on CONFIRM_FACTOR x n_synth syntheses of the current model

    def unconfirmed(label, evidence, cache, check_seed, where, outcome):
        # the spread of n_synth syntheses is itself uncertain (a standard deviation of 8 values
        # is off by a quarter, and now and then by half): a significant residual counts only if
        # it still is, with its sign, against CONFIRM_FACTOR x the syntheses with fresh seeds
        # (``cache``: label -> those diagnoses of the current model). One that is not is
        # recorded, once per model, as unconfirmed.
        # a pooled residual is confirmed on every stack it was pooled over
        over = evidence.pooled.get("over") or [label]
        key = (label, tuple(over))
        if key not in cache:
            again = {lb: diagnose(by_label[lb], current, model=model, n_synth=CONFIRM_FACTOR * n_synth,
                                  seed=check_seed + (0 if lb == label else 1 + labels.index(lb)), z_min=z_min, rel_min=rel_min,
                                  workers=torch.get_num_threads())
                     for lb in over}
            cache[key] = pool_residuals(again, z_min, rel_min)[label][0]
        check = next(r for r in cache[key] if r.statistic == evidence.statistic)
        if check.significant and check.z * evidence.z > 0:
            return False
        if not any(u["stack"] == label and u["statistic"] == evidence.statistic for u in result.unconfirmed):
            result.unconfirmed.append({"stack": label, "statistic": evidence.statistic, "z": evidence.z,
                                       "z_confirm": check.z, "n_synth_confirm": CONFIRM_FACTOR * n_synth})
            say(f"{where}: {evidence.statistic} ({label}, z={evidence.z:.1f}) not confirmed on "
                f"{CONFIRM_FACTOR * n_synth} syntheses (z={check.z:.1f}): {outcome}")
        return True

    def confirmed_options(step_no):
        # a residual is only acted on if it is confirmed (``unconfirmed``)
        skip = set()
        while True:
            options = _options(diags, tried, set(current.effects), skip)
            left_out = {(label, evidence.statistic) for _, label, evidence in options
                        if unconfirmed(label, evidence, checks, seed + 7_000_000 + 1000 * step_no, f"step {step_no}",
                                       "not acted on")}
            if not left_out:
                return options
            skip |= left_out

    def judged(trial, shared, step_no, which=None, known=None, refit_z=None, bound=None):
        # (diagnoses, stacks, profile, factors) of a trial model on ``which`` (default all
        # stacks); a base stage the candidate shares (``shared``) is re-fitted from the bias
        # stacks. ``known``: {"model": ..., "refitted": ...} diagnoses made already (the
        # screening's: the same seeds give the same results), filled in as it goes.
        # ``refit_z``: the row re-fit's threshold in spreads (default ``z_min``; a candidate's own ``REFIT_Z``).
        # ``bound``: the battery's sum of residual errors that cannot win: the whole battery is
        # then diagnosed BOUND_CHUNK stacks at a time and stopped (``_Beaten``) once the errors
        # of its residuals so far (pooled ones left out: pooling may lower them) pass it.
        step_seed = seed + 1000 * step_no
        which = list(which or stacks)
        known = known if known is not None else {}

        def run(prof, part, key, bound=None):
            done = known.setdefault(key, {})
            missing = [st for st in part if st.label not in done]
            chunk = len(missing) if bound is None else BOUND_CHUNK
            for i in range(0, len(missing), max(chunk, 1)):
                done.update(diagnose_all(prof, step_seed, missing[i:i + chunk]))
                if bound is None or i + chunk >= len(missing):
                    continue
                partial = sum(r.rel_error for st in part if st.label in done for r in done[st.label][0] if not r.pooled)
                if partial > bound:
                    raise _Beaten(partial, sum(st.label in done for st in part), len(part))
            return pool_residuals({st.label: done[st.label] for st in part}, z_min, rel_min)

        if not shared:
            return run(trial, which, "model", bound), stacks, trial, {}
        # the re-fit reads the bias stacks only: the others are diagnosed once, with it or without
        got = run(trial, [st for st in stacks if st.kind == "bias"], "model")
        factors = (read_noise_factors(stacks, got, trial, model, z_min=z_min, seed=step_seed) if shared == "read noise"
                   else row_noise_factors(stacks, got, trial, z_min=refit_z or z_min, model=model, seed=step_seed))
        if not factors:
            return run(trial, which, "model", bound), stacks, trial, factors
        refit_stacks, refitted = (apply_read_noise_factors(stacks, trial, factors, model) if shared == "read noise"
                                  else apply_row_noise_factors(stacks, trial, factors))
        key = "refitted"
        if shared == "read noise":  # its tails too: calibration's lambda held those of the part it takes over
            bias = [st for st in refit_stacks if st.kind == "bias"]
            shaped_stacks, shaped, _, step, taken = _shape_search(
                refit_stacks, refitted, run(refitted, bias, key),
                lambda p, part, i: run(p, [st for st in part if st.kind == "bias"], f"shaped {i}"), model, z_min)
            if taken:  # what taking the candidate out restores (``_without``)
                known["lambdas_before"] = {st.label: float(synthesis_fixed(refitted, st)["lambda"])
                                           for st in bias if any(st.label in lambdas for lambdas in taken)}
                refit_stacks, refitted, key = shaped_stacks, shaped, f"shaped {step}"
        labels_in = {st.label for st in which}
        return run(refitted, [st for st in refit_stacks if st.label in labels_in], key, bound), refit_stacks, refitted, factors

    def refit_base(after, step_no, diags_without, given=False):
        # the base read noise re-fitted after the effect ``after`` joined the model (``given``: it came
        # with the calibrated profile; ``diags_without``: the diagnoses before it, None: no row restore):
        # its variance where the model's bias frames came out noisier (the effect shares their temporal
        # noise), then its shape where the model's tails are the heavier; the two are kept or dropped
        # together, as one re-fit of the read noise
        nonlocal current, diags, stacks, diags_seed, by_label
        step_seed = seed + 1000 * step_no + 500
        factors = read_noise_factors(stacks, diags, current, model, z_min=z_min, seed=step_seed)
        new_stacks, refitted, new_diags = stacks, current, diags
        if factors:
            new_stacks, refitted = apply_read_noise_factors(stacks, current, factors, model)
            new_diags = diagnose_all(refitted, step_seed, new_stacks)
        # the shape's search reads the bias stacks (where tail_mass is read); the state it keeps
        # gets the rest of the battery, with the seeds the whole battery would give it
        bias_of = lambda part: [st for st in part if st.kind == "bias"]  # noqa: E731
        shape_stacks, shape_prof, shape_diags, shape_step, shaped = _shape_search(
            new_stacks, refitted, {st.label: new_diags[st.label] for st in bias_of(new_stacks)},
            lambda p, part, i: diagnose_all(p, step_seed + 100 + i, bias_of(part)), model, z_min)
        if shape_step is not None:
            step_seed += 100 + shape_step
            new_stacks, refitted = shape_stacks, shape_prof
            rest = [st for st in new_stacks if st.kind != "bias"]
            merged = {**shape_diags, **(diagnose_all(refitted, step_seed, rest) if rest else {})}
            new_diags = pool_residuals({st.label: merged[st.label] for st in new_stacks}, z_min, rel_min)  # in the stacks' order, as a whole battery
        if factors or shaped:
            before_b, after_b = _battery(diags), _battery(new_diags)
            kept = (after_b["mean_rel_error"] <= before_b["mean_rel_error"]
                    and after_b["n_significant"] <= before_b["n_significant"])
            result.refits.append({"after": after, "round": step_no, "factors": factors, "lambdas": shaped, "given": given,
                                  "kept": kept, "battery_before": before_b, "battery_after": after_b})
            say(f"step {step_no}: read noise re-fitted after {after} ("
                + ", ".join([f"{label} x{f:.3f}" for label, f in factors.items()]
                            + [f"{label} lambda {lam:.3f}" for lambdas in shaped for label, lam in lambdas.items()])
                + f"): battery {before_b['mean_rel_error']:.3f} -> {after_b['mean_rel_error']:.3f}: "
                + ("kept" if kept else "dropped"))
            if kept:
                current, diags, stacks, diags_seed = refitted, new_diags, new_stacks, step_seed
                by_label = {st.label: st for st in stacks}
        # the row noise given back where the added effect took the rows' variance away (a code
        # map re-quantizes the row offsets calibration measured on quantized frames); kept if it
        # helps, and undone with the effect
        restore = row_noise_restore(stacks, diags_without, diags, current, z_min=z_min) if diags_without is not None else None
        if restore:
            new_stacks, refitted = apply_row_noise_factors(stacks, current, restore)
            new_diags = diagnose_all(refitted, step_seed + 50, new_stacks)
            before_b, after_b = _battery(diags), _battery(new_diags)
            # no worse, or fewer significant residuals at a battery within its seed-to-seed noise
            kept = ((after_b["mean_rel_error"] <= before_b["mean_rel_error"]
                     and after_b["n_significant"] <= before_b["n_significant"])
                    or (after_b["n_significant"] < before_b["n_significant"]
                        and after_b["mean_rel_error"] <= RESTORE_TOLERANCE * before_b["mean_rel_error"]))
            result.refits.append({"after": after, "round": step_no, "factors": restore, "kept": kept,
                                  "what": "row noise", "battery_before": before_b, "battery_after": after_b})
            say(f"step {step_no}: row noise given back after {after} ("
                + ", ".join(f"{label} x{f:.3f}" for label, f in restore.items())
                + f"): battery {before_b['mean_rel_error']:.3f} -> {after_b['mean_rel_error']:.3f}: "
                + ("kept" if kept else "dropped"))
            if kept:
                current, diags, stacks, diags_seed = refitted, new_diags, new_stacks, step_seed + 50
                by_label = {st.label: st for st in stacks}

    def estimate_seed(step_no):  # the seed of a step's estimates (the forward trials' and their second sizing)
        return int(np.random.default_rng(seed + step_no).integers(1, 2**31))

    def resize_through_clip(step, step_no, diags_without):
        # an effect sized through the clip (``clip_corrected``) by simulation in the base as it
        # was before the re-fit it was judged with: sized again in the re-fitted base (what the
        # clip hides of it depends on the noise around it), kept if the battery is no worse
        nonlocal current, diags
        module = CANDIDATES[step.effect].module
        refitted = any(r.get("after") == step.effect and r.get("round") == step_no and r.get("kept") and r.get("factors")
                       for r in result.refits)
        if "Clip" not in current.effects or not getattr(module, "AMPLITUDES", ()) or not refitted:
            return
        base = current.without_effect(step.effect)
        params = _estimate(step.effect, stacks, diags_without, estimate_seed(step_no), base, model)
        if params is None or _adds_nothing(step.effect, params):
            return
        trial = base.with_effect(step.effect, params)
        trial_diags = diagnose_all(trial, diags_seed, stacks)
        old_b, new_b = _battery(diags), _battery(trial_diags)
        fits = new_b["n_significant"] <= old_b["n_significant"] and new_b["mean_rel_error"] <= old_b["mean_rel_error"]
        say(f"step {step_no}: {step.effect} sized again through the clip in the re-fitted base: battery "
            f"{old_b['mean_rel_error']:.3f} -> {new_b['mean_rel_error']:.3f}: " + ("kept" if fits else "dropped"))
        result.resized.append({"effect": step.effect, "round": step_no, "kept": fits,
                               "battery_before": old_b, "battery_after": new_b})
        if fits:
            step.params, current, diags = params, trial, trial_diags
            step.battery_after = new_b

    diags, diags_seed = diagnose_all(current, seed), seed
    result = LoopResult(current, initial={k: v[0] for k, v in diags.items()})
    for token in given:  # effects the calibrated profile brought (the frames' code floor): the base re-fitted with them
        refit_base(token, 0, None, given=True)
    tried: set[str] = set()
    for step_no in range(1, max_steps + 1):
        options = confirmed_options(step_no)
        if not options:
            break
        before_b = _battery(diags)
        trials = []
        physical = [o for o in options if not _measured(o[0])]
        # measured fallbacks only where no physical effect explains the residual they were called
        # for (halves its error): a physical effect that halves its own evidence may leave theirs
        for fallbacks, batch in enumerate((physical, [o for o in options if _measured(o[0])])):
            if fallbacks:
                batch = [o for o in batch if not _explained(o, trials)]
            for token, label, evidence in batch:
                params = _estimate(token, stacks, diags, estimate_seed(step_no), current, model)
                if params is None:
                    tried.add(token)
                    say(f"step {step_no}: {token} suggested by {evidence.statistic} but no stack can estimate it")
                    continue
                if _adds_nothing(token, params):  # no trial: the model would stay as it is
                    tried.add(token)
                    say(f"step {step_no}: {token} suggested by {evidence.statistic}, but its estimate adds nothing")
                    continue
                trial = current.with_effect(token, params)
                shared = _shares_noise(token, current)  # judged with its variance taken out of the base stage it shares

                # its evidence first, on the stack it comes from (and the bias stacks a re-fit
                # reads): most candidates fail there, and the whole battery is not run for them
                known: dict = {}  # the screening's diagnoses, reused by the whole battery's
                refit_z = getattr(CANDIDATES[token].module, "REFIT_Z", None)
                # (a pooled residual: on every stack it was pooled over)
                screen = judged(trial, shared, step_no, [by_label[lb] for lb in evidence.pooled.get("over") or [label]],
                                known, refit_z)[0]
                err_before, err_after = _evidence_error(token, evidence, diags[label][0], screen[label][0])
                if err_after > ACCEPT_FACTOR * err_before:
                    after = next(r for r in screen[label][0] if r.statistic == evidence.statistic)
                    trials.append((Step(token, params, False, evidence.to_dict(), label, err_before, err_after, after.z,
                                        before_b, {}, round=step_no, kind="measured" if _measured(token) else "physical",
                                        evidence_after=after.to_dict(), note="screened"), trial, None, stacks, {}, {}))
                    continue
                # once a candidate is acceptable, a battery that cannot beat the best one's is stopped
                best = [t[0].battery_after["mean_rel_error"] for t in trials if t[0].accepted]
                bound = min(best) * sum(len(res) for res, _ in diags.values()) if best else None
                try:
                    new_diags, trial_stacks, trial, factors = judged(trial, shared, step_no, known=known, refit_z=refit_z,
                                                                     bound=bound)
                except _Beaten as beaten:
                    after = next(r for r in screen[label][0] if r.statistic == evidence.statistic)
                    trials.append((Step(token, params, False, evidence.to_dict(), label, err_before, err_after, after.z,
                                        before_b, {}, round=step_no, kind="measured" if _measured(token) else "physical",
                                        evidence_after=after.to_dict(),
                                        note=f"beaten after {beaten.done} of {beaten.total} stacks"), trial, None, stacks, {}, {}))
                    continue
                if factors:
                    say(f"step {step_no}: {token} judged with the {shared} re-fitted ("
                        + ", ".join(f"{label} x{f:.3f}" for label, f in factors.items()) + ")")
                after = next(r for r in new_diags[label][0] if r.statistic == evidence.statistic)
                after_b = _battery(new_diags)
                err_before, err_after = _evidence_error(token, evidence, diags[label][0], new_diags[label][0])
                # acceptable if its evidence improved by a fifth or more, nothing new became
                # significant and the battery as a whole did not get much worse (a component
                # that fixes one statistic by spoiling many already significant ones is no fix)
                ok = (err_after <= ACCEPT_FACTOR * err_before and after_b["n_significant"] <= before_b["n_significant"]
                      and after_b["mean_rel_error"] <= BATTERY_GROWTH * before_b["mean_rel_error"])
                step = Step(token, params, ok, evidence.to_dict(), label, err_before, err_after, after.z, before_b,
                            after_b, round=step_no, kind="measured" if _measured(token) else "physical",
                            evidence_after=after.to_dict())
                trials.append((step, trial, new_diags, trial_stacks, factors, known.get("lambdas_before", {})))
        acceptable = [t for t in trials if t[0].accepted]
        # a last resort (a measured map of thousands of numbers) only where nothing else is acceptable
        preferred = [t for t in acceptable if not getattr(CANDIDATES[t[0].effect].module, "LAST_RESORT", False)] or acceptable
        chosen = min(preferred, key=lambda t: (t[0].battery_after["mean_rel_error"], t[0].battery_after["n_significant"])) if acceptable else None
        for step, *_ in trials:
            if step is not (chosen[0] if chosen else None):
                if step.accepted:
                    step.accepted, step.note = False, f"acceptable, but {chosen[0].effect} explains more"
                elif step.note.startswith("beaten"):  # not judged whole: it may be tried again
                    step.note = (f"not judged whole: {chosen[0].effect} explains more (its battery's mean error passed "
                                 f"the best's, {step.note[len('beaten '):]})")
                else:
                    tried.add(step.effect)
                    step.note = ("rejected (its evidence did not improve by a fifth on its stack; the battery was not run)"
                                 if step.note == "screened" else "rejected")
            else:
                tried.add(step.effect)
                step.note = "added" + (f" (best of {len(trials)} tried)" if len(trials) > 1 else "")
            result.steps.append(step)
            ev = step.evidence
            battery = (f", battery {step.battery_before['mean_rel_error']:.3f} -> {step.battery_after['mean_rel_error']:.3f}"
                       if step.battery_after else "")
            say(f"step {step_no}: {step.effect} ({ev['statistic']} z={ev['z']:.1f}): error {step.error_before:.3f} -> "
                f"{step.error_after:.3f}{battery}: {step.note}")
        if chosen is None:
            continue
        chosen[0].signature = _signature(chosen[0].evidence, chosen[0].stack, by_label, diags, chosen[2])
        diags_without = diags
        current, diags, diags_seed = chosen[1], chosen[2], seed + 1000 * step_no
        if chosen[3] is not stacks:  # the base stage it was judged with, re-fitted
            stacks = chosen[3]
            by_label = {st.label: st for st in stacks}
            result.refits.append({"after": chosen[0].effect, "round": step_no, "factors": chosen[4], "kept": True,
                                  **({"lambdas_before": chosen[5]} if chosen[5] else {}),
                                  "what": _shares_noise(chosen[0].effect, current),
                                  "battery_before": chosen[0].battery_before, "battery_after": chosen[0].battery_after})
        tried = {t for t in tried if t in current.effects}  # estimates depend on the model: retry the rejected
        checks.clear()
        result.unconfirmed.clear()  # confirmations belong to a model
        refit_base(chosen[0].effect, step_no, diags_without)
        resize_through_clip(chosen[0], step_no, diags_without)
    while True:  # backward elimination
        kept = [s for s in result.steps if s.accepted]
        if len(kept) < 2:
            break
        # an effect can only have been made redundant by one added after it (the last one added
        # was needed beside all the others): one that a statistic of its own also points to, or,
        # while the model overshoots any statistic, every one (a later effect explained its
        # residual through a statistic the two do not share, and it adds on top: hot pixels
        # added for high first rows that a later ``LineMap`` reproduces raise the fixed pattern)
        stats = lambda step: set(CANDIDATES[step.effect].statistics)  # noqa: E731
        overshot = {r.statistic for res, _ in diags.values() for r in res if r.significant and r.z < 0}
        candidates = [s for i, s in enumerate(kept[:-1])
                      if overshot or any(stats(s) & stats(later) for later in kept[i + 1:])]
        if not candidates:
            break
        full, full_b = _significant(diags), _battery(diags)
        removable = []
        for step in candidates:
            reduced, reduced_stacks = _without(step, current, stacks, result.refits, model)
            reduced_diags = diagnose_all(reduced, diags_seed, reduced_stacks)  # the full model's syntheses' seeds
            reduced_b = _battery(reduced_diags)
            # redundant: nothing becomes significant without it; or, while the model overshoots,
            # a battery no worse without it (as many significant residuals at most, and a mean
            # error no higher): the overshoot it ends is worth the residual it leaves at the
            # threshold
            no_worse = (overshot and reduced_b["n_significant"] <= full_b["n_significant"]
                        and reduced_b["mean_rel_error"] <= full_b["mean_rel_error"])
            if _significant(reduced_diags) <= full or no_worse:
                removable.append((step, reduced, reduced_diags, reduced_stacks,
                                  "redundant" if _significant(reduced_diags) <= full else "overshoots"))
            else:
                say(f"end: {step.effect} kept: without it " + ", ".join(
                    f"{stat} ({label})" for label, stat in sorted(_significant(reduced_diags) - full)) + " significant")
        if not removable:
            break
        step, reduced, reduced_diags, reduced_stacks, why = min(
            removable, key=lambda r: (r[0].kind != "measured", _battery(r[2])["mean_rel_error"]))
        before_b, after_b = _battery(diags), _battery(reduced_diags)
        others = [s.effect for s in kept if s is not step]
        step.accepted, step.note = False, (f"added, then removed: {'redundant' if why == 'redundant' else 'the model overshoots with it'}"
                                           " beside " + ", ".join(others))
        result.removed.append({"effect": step.effect, "round": step.round, "beside": others, "why": why,
                               "battery_before": before_b, "battery_after": after_b})
        say(f"end: {step.effect} removed: " + ("no residual is significant without it" if why == "redundant"
                                               else "the model overshoots with it, and the battery is no worse without it")
            + f" beside {', '.join(others)} (battery {before_b['mean_rel_error']:.3f} -> {after_b['mean_rel_error']:.3f})")
        current, diags, stacks = reduced, reduced_diags, reduced_stacks
        by_label = {st.label: st for st in stacks}
        for refit in result.refits:  # undone by _without
            if refit.get("after") == step.effect and refit.get("what") and refit.get("kept"):
                refit["kept"], refit["undone"] = False, f"{step.effect} removed"
        # an effect added after it was estimated beside it: estimated again on the model without it
        for later in [s for s in result.steps if s.accepted and s.round > step.round and not _shares_noise(s.effect, current)]:
            without = current.without_effect(later.effect)
            without_diags = diagnose_all(without, diags_seed, stacks)
            params = _estimate(later.effect, stacks, without_diags,
                               int(np.random.default_rng(seed + 90_000 + later.round).integers(1, 2**31)), without, model)
            if params is None or _adds_nothing(later.effect, params):
                continue
            trial = without.with_effect(later.effect, params)
            trial_diags = diagnose_all(trial, diags_seed, stacks)
            old_b, new_b = _battery(diags), _battery(trial_diags)
            # the estimate made in the right model, unless it spoils the battery (the forward rule)
            fits = (new_b["n_significant"] <= old_b["n_significant"]
                    and new_b["mean_rel_error"] <= BATTERY_GROWTH * old_b["mean_rel_error"])
            say(f"end: {later.effect} estimated again without {step.effect}: battery {old_b['mean_rel_error']:.3f} -> "
                f"{new_b['mean_rel_error']:.3f}: " + ("kept" if fits else "dropped"))
            if fits:
                later.params, current, diags = params, trial, trial_diags
                later.note = f"estimated again once {step.effect} was removed"
            # its evidence restated in the final model, as the forward loop picks it: the
            # strongest residual pointing to it without it
            label, before_r = next(((lb, r) for t, lb, r in _options(without_diags, set(), set(without.effects)) if t == later.effect),
                                   (later.stack, next(r for r in without_diags[later.stack][0] if r.statistic == later.evidence["statistic"])))
            stat = before_r.statistic
            after_r = next(r for r in diags[label][0] if r.statistic == stat)
            later.error_before, later.error_after = _evidence_error(later.effect, before_r, without_diags[label][0], diags[label][0])
            later.z_after, later.evidence_after = after_r.z, after_r.to_dict()
            later.stack, later.evidence = label, before_r.to_dict()
            later.battery_before, later.battery_after = _battery(without_diags), _battery(diags)
            later.signature = _signature(later.evidence, label, by_label, without_diags, diags)
    # what is left is judged as a residual that calls for an effect is: against a larger,
    # independent sample of syntheses (an effect removed at the end can leave a statistic at
    # the threshold whose spread 8 syntheses underestimated)
    final_checks: dict = {}
    for label, (residuals, _) in diags.items():
        for r in residuals:
            if r.significant and not any(u["stack"] == label and u["statistic"] == r.statistic for u in result.unconfirmed):
                unconfirmed(label, r, final_checks, seed + 8_000_000, "end", "not unexplained")
    result.profile, result.colour_bias = _with_fitted_colour_bias(current, stacks, model, seed)
    if result.colour_bias:
        say("colour bias fitted with the added effects: " + "; ".join(
            f"K {k:g}: " + ", ".join(f"{v:.3f}" for v in row) + " DN" for k, row in result.colour_bias.items()))
    result.final = {k: v[0] for k, v in diags.items()}
    return result


def _with_fitted_colour_bias(profile, stacks, model, seed):
    """(profile, {K: offsets}) with the colour bias of every bias stack's gain replaced by
    the offsets its syntheses use (``fitted_offsets``: fitted with the added effects, so that
    a model with a clip or a code map has the measured mean); unchanged without effects."""
    by_k: dict = {}
    for stack in stacks:
        if stack.kind == "bias" and profile.effects:
            by_k.setdefault(float(stack.k), []).append(fitted_offsets(profile, stack, seed, model))
    if not by_k:
        return profile, {}
    fitted = {k: tuple(float(v) for v in np.mean(rows, axis=0)) for k, rows in sorted(by_k.items())}
    old = [(k, v) for k, v in zip(profile.color_bias.k, profile.color_bias.values)
           if not any(abs(k - fk) <= 1e-9 * fk for fk in fitted)]
    records = sorted(old + list(fitted.items()), key=lambda r: r[0])
    table = KTable(tuple(r[0] for r in records), tuple(tuple(r[1]) for r in records))
    return dataclasses.replace(profile, color_bias=table), fitted
