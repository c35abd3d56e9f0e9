"""Estimates through a clip, corrected by simulation.

A camera that stores no code under a floor (``Clip``: a black level at code 0 keeps about
half of every bias frame there) shows an estimator an effect shrunk: a tone, a dark signal
or a mean offset moves the clipped values only by the share of them above the floor. The
model clips as the camera does, so the size is found by simulation: the candidate as
estimated is planted in the model, each stack synthesized with it and estimated again, and
each of the effect's amplitudes (``AMPLITUDES`` of its module) is scaled by what the
estimator lost on the synthesis, then moved along the secant through a second synthesis
(two steps of indirect inference: the share lost depends on the size; a signed amplitude, an
offset map's cell, where the simulated estimate keeps its sign). A module whose
records hold lists of found things (tones) gives ``aligned(simulated, params)``, which
arranges the simulated estimate as ``params``. Only records at the gains
of clipped stacks are scaled; an effect without ``AMPLITUDES`` is left as estimated.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .diagnose import fitted_offsets, synthesize
from .registry import CANDIDATES

CLIPPED_SHARE = 0.01  # a stack is clipped when this share of its values sits at the floor
MAX_RATIO = 4.0  # the most a correction scales an amplitude, up or down


def share_at_floor(stack, floor_dn: float) -> float:
    """Share of a stack's values (DN) at or under the clip floor (within half a code)."""
    return float(np.mean(stack.frames_dn <= float(floor_dn) + 0.5))


def clipped(stack, profile) -> bool:
    """True when ``profile`` has a ``Clip`` and ``stack`` holds ``CLIPPED_SHARE`` of its values at its floor."""
    clip = profile.effects.get("Clip")
    return clip is not None and share_at_floor(stack, clip["floor_dn"]) >= CLIPPED_SHARE


def _elementwise(fn, first, *others, flags=True):
    """``fn(first, *others)`` on each number of like-shaped (nested) lists where ``flags`` (a
    bool, or one per record) is set and every argument is non-zero and of one sign (an offset
    map's cells may be negative); ``first`` elsewhere, and where shapes differ."""
    if isinstance(first, (list, tuple)):
        if any(not isinstance(o, (list, tuple)) or len(o) != len(first) for o in others):
            return first
        each = flags if isinstance(flags, (list, tuple)) else [flags] * len(first)
        return [_elementwise(fn, v, *(o[i] for o in others), flags=each[i]) for i, v in enumerate(first)]
    values = (first, *others)
    if not flags or not all(isinstance(x, (int, float)) for x in values) or not (
            all(x > 0.0 for x in values) or all(x < 0.0 for x in values)):
        return first
    return float(fn(first, *others))


def _ratio_step(v, s0):
    """The size that would give the estimate ``v`` if the estimator kept the share ``s0 / v``."""
    return v * np.clip(v / s0, 1.0 / MAX_RATIO, MAX_RATIO)


def _secant_step(t1, v, s0, s1):
    """From sizes ``v`` and ``t1`` that the estimator read as ``s0`` and ``s1``: the size it
    would read as ``v`` (a secant; the ratio step where the two readings coincide)."""
    if abs(s1 - s0) <= 1e-9 * abs(s1):
        return t1
    bounds = sorted((v / MAX_RATIO, v * MAX_RATIO))
    return float(np.clip(t1 + (v - s1) * (t1 - v) / (s1 - s0), *bounds))


def clip_corrected(token: str, params: dict, profile, stacks, estimate, model=None, seed: int = 0) -> dict:
    """``params`` of candidate ``token`` with its ``AMPLITUDES`` corrected for the clip of
    ``profile`` (a ``Clip`` effect) where stacks are clipped (``CLIPPED_SHARE``).
    ``estimate(stacks)`` is the loop's estimate of the candidate from a list of stacks (the
    same labels, frames replaced); the syntheses take ``seed`` + the stack's place."""
    module = CANDIDATES[token].module
    keys = [key for key in getattr(module, "AMPLITUDES", ()) if key in params]
    clip = profile.effects.get("Clip")
    if not keys or clip is None:
        return params
    clipped_k = {st.k for st in stacks if clipped(st, profile)}
    if not clipped_k:
        return params

    def read(size):
        """The candidate's estimate from syntheses of every stack by the model with it at ``size``."""
        trial = profile.with_effect(token, size)
        offsets: dict = {}  # the colour bias a stack's synthesis uses, fitted once per bias stack
        twins = []
        for i, st in enumerate(stacks):
            src = st.offsets_of if st.offsets_of is not None else st
            if id(src) not in offsets:
                offsets[id(src)] = fitted_offsets(trial, src, seed + i, model)
            frames = synthesize(trial, st, 1, seed + i, model, offsets=offsets[id(src)])[0]
            twins.append(dataclasses.replace(st, frames_dn=frames.astype(np.float64)))
        got = estimate(twins)
        align = getattr(module, "aligned", None)  # records of lists matched by what they hold (a tone by its frequency)
        return align(got, size) if got is not None and align is not None else got

    ks = params.get("k")
    flags = [float(k) in clipped_k for k in ks] if isinstance(ks, list) else True
    s0 = read(params)
    if s0 is None:
        return params
    first = {**params, **{key: _elementwise(_ratio_step, params[key], s0.get(key), flags=flags) for key in keys}}
    s1 = read(first)
    if s1 is None:
        return first
    return {**first, **{key: _elementwise(_secant_step, first[key], params[key], s0.get(key), s1.get(key), flags=flags)
                        for key in keys}}
