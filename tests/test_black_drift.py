"""BlackDrift: a black level that drifts over a sequence of frames (an AR(1) across frames),
through the real stage, its statistic and its estimator."""
import functools

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import black_drift
from rawaug.statistics import frame_mean_lag1

SHAPE = (16, 16)  # packed pixels per channel: small frames, the offsets are per frame


@functools.lru_cache(maxsize=None)
def drift_profile(sigma, rho, k):
    profile = NoiseProfile.load("SonyA7S2")
    return profile.with_effect("BlackDrift", {"k": [k], "sigma_dn": [sigma], "rho": [rho]}) if sigma else profile


def stack(n, sigma=1.0, rho=0.9, seed=0, sequence=1, k=1.0, read_dn=1.0):
    """(n, 4, h, w) bias frames in DN: Gaussian read noise of ``read_dn`` plus the drift."""
    profile = drift_profile(sigma, rho, k)
    aug = RawNoiseAugment(profile, model="G", ratio=1.0, fixed={"k": k, "sigma_g": read_dn, "sequence": sequence},
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.zeros(n, 4, *SHAPE)).numpy().astype(np.float64) * profile.span_dn


def offsets(frames):
    return frames.mean(axis=(1, 2, 3))


def test_a_sequence_has_the_stationary_spread_and_lag1_correlation():
    # 4000 frames of an AR(1) with rho 0.9: the sample variance has a relative standard error of about
    # sqrt(2 (1 + rho^2) / (1 - rho^2) / n) = 0.10, the lag-1 correlation about sqrt((1 - rho^2) / n) = 0.007
    b = offsets(stack(4000, sigma=2.0, rho=0.9, seed=3))
    assert abs(b.var() / 4.0 - 1.0) < 4 * 0.10
    r1 = np.corrcoef(b[:-1], b[1:])[0, 1]
    assert abs(r1 - 0.9) < 5 * 0.007


def test_independent_shots_have_the_spread_and_no_correlation():
    b = offsets(stack(4000, sigma=2.0, rho=0.9, seed=4, sequence=0))
    assert abs(b.var() / 4.0 - 1.0) < 4 * np.sqrt(2 / 4000)
    assert abs(np.corrcoef(b[:-1], b[1:])[0, 1]) < 4 / np.sqrt(4000)


def test_a_frame_offset_depends_on_the_frames_before_it_only():
    a, b = offsets(stack(12, seed=5)), offsets(stack(5, seed=5))
    assert np.allclose(a[:5], b, atol=1e-4)


def test_the_offset_is_one_for_all_channels():
    f = stack(8, sigma=5.0, read_dn=0.0, seed=6)
    channel = f.mean(axis=(2, 3))
    assert np.allclose(channel - channel[:, :1], 0.0, atol=1e-3)


def test_lag1_tells_a_drift_from_new_offsets_over_seeds():
    # 200 stacks of 16 frames each way; the offsets dominate the frames' read noise (1 DN over 1024 pixels)
    white = np.array([frame_mean_lag1(stack(16, sigma=1.0, rho=0.0, seed=100 + s)) for s in range(200)])
    drift = np.array([frame_mean_lag1(stack(16, sigma=1.0, rho=0.9, seed=400 + s)) for s in range(200)])
    # white: E r1 = -1/N = -0.0625 and sd about 1/sqrt(N) = 0.25 -> the mean of 200 within 4 x 0.018
    assert abs(white.mean() + 1 / 16) < 4 * 0.25 / np.sqrt(200)
    # measured: white mean -0.055 (sd 0.24), 15 % above 0.2; drift (rho 0.9) mean 0.58, 96 % above 0.2
    assert drift.mean() > white.mean() + 0.4
    assert np.mean(drift > 0.2) > 0.8 and np.mean(white > 0.2) < 0.2


@pytest.mark.parametrize("rho", [0.0, 0.5, 0.85])
def test_estimate_measures_a_planted_drift_back_over_seeds(rho):
    # 20 cameras, each 4 bias stacks of 16 frames at two gains; syntheses without the drift as the model's
    base = [stack(16, sigma=0.0, seed=9000 + i) for i in range(4)]
    got = []
    for s in range(20):
        records = [black_drift.estimate(stack(16, sigma=2.0 if k == 1.0 else 1.0, rho=rho, k=k, seed=1000 * s + j), base,
                                        k, kind="bias") for j, k in enumerate((1.0, 1.0, 3.0, 3.0))]
        got.append(black_drift.combine(records))
    # measured medians: rho 0.08 / 0.56 / 0.87 (0 is biased up: rho is kept >= 0), sigma 2.1-2.2 and 0.89-0.92
    rhos = np.array([g["rho"][0] for g in got])
    sigmas = np.array([g["sigma_dn"] for g in got])  # (20, 2): K 1 then K 3
    assert np.all(np.array([g["k"] for g in got]) == [1.0, 3.0])
    assert abs(np.median(rhos) - rho) < 0.15
    assert abs(np.median(sigmas[:, 0]) / 2.0 - 1.0) < 0.25 and abs(np.median(sigmas[:, 1]) - 1.0) < 0.25


def session(rng, series):
    """Records of 4 gains x (8 + 4) frames: ``series(n, gain index)`` gives a stack's frame means."""
    return [{"k": [float(k)], "series": list(series(n, k))} for k in range(1, 5) for n in (8, 4)]


def test_the_drift_test_over_sessions():
    # new offsets in every frame (each gain its own spread): the likelihood ratio is half the time 0
    # and else chi-square(1), so above 9 in 0.13 % of sessions; 1000 sessions: at most 6 (Poisson 1.3,
    # 4 sd). Measured: 1 of 1000. A random walk of 1 unit per frame: measured 85 % of 500 detected.
    rng = np.random.default_rng(7)
    white = [black_drift.drift_lr(session(rng, lambda n, k: rng.normal(size=n) * k)) for _ in range(1000)]
    walk = [black_drift.drift_lr(session(rng, lambda n, k: np.cumsum(rng.normal(size=n)))) for _ in range(500)]
    assert sum(v > black_drift.DRIFT_LR for v in white) <= 6
    assert np.mean(np.array(walk) > black_drift.DRIFT_LR) > 0.75


def test_without_a_drift_shown_the_estimate_adds_nothing():
    # new offsets in every frame are BLE's: BlackDrift comes back with rho 0, which the loop does not try
    base = [stack(8, sigma=0.0, seed=9000 + i) for i in range(2)]
    records = [black_drift.estimate(stack(8, sigma=2.0, rho=0.0, seed=70 + j), base, 1.0, kind="bias") for j in range(2)]
    got = black_drift.combine(records)
    assert got["rho"] == [0.0] and black_drift.empty(got)


def test_rho_is_limited_to_the_longest_stack():
    # a random walk (rho 1) has no stationary spread: rho stops at 1 - 1/N
    rng = np.random.default_rng(0)
    walk = np.cumsum(rng.normal(size=(4, 8)), axis=1)
    records = []
    for w in walk:
        frames = np.broadcast_to(w[:, None, None, None], (8, 4, 4, 4)).copy()
        records.append(black_drift.estimate(frames, [np.zeros_like(frames)], 1.0, kind="bias"))
    assert black_drift.drift_lr(records) > black_drift.DRIFT_LR
    got = black_drift.combine(records)
    assert got["rho"][0] == pytest.approx(1 - 1 / 8) and got["sigma_dn"][0] > 0


def test_flats_and_one_frame_cannot_show_it():
    frames = stack(4)
    with pytest.raises(ValueError, match="bias and dark stacks"):
        black_drift.estimate(frames, [frames], 1.0, kind="flat")
    with pytest.raises(ValueError, match="bias and dark stacks"):
        black_drift.estimate(frames[:1], [frames[:1]], 1.0, kind="bias")


@pytest.mark.parametrize("params, match", [
    ({"k": [1.0], "sigma_dn": [1.0], "rho": [1.0]}, r"rho must be in \[0, 1\)"),
    ({"k": [1.0], "sigma_dn": [-1.0], "rho": [0.5]}, "sigma_dn"),
    ({"k": [1.0], "sigma_dn": [1.0]}, "rho"),
])
def test_bad_entries_are_refused(params, match):
    with pytest.raises(ValueError, match=match):
        NoiseProfile.load("SonyA7S2").with_effect("BlackDrift", params)
