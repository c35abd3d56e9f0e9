"""StuckBit: bits of the raw code stuck at 0 or 1, through the real stage, its estimator and its
profile entry."""
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.calibration.stage1 import bias_frame_noise, calibrate_iso
from rawaug.calibration.stuck_bits import stuck_masks
from rawaug.effects import stuck_bit

from base_camera import base_fixed

BASE = NoiseProfile.load("SonyA7S2")
ZERO = [512, 509, 513, 510]  # raw code of 0 DN per channel: blacks of their own, not multiples of the masks


def frames(level_dn, k, seed, n=2, size=64, stuck=None):
    """(n, 4, size, size) frames in whole DN at gain ``k`` (the base camera's read, row and shot
    noise, quantization) with the raw code's bits ``stuck`` (a StuckBit entry) or none."""
    profile = BASE.with_effect("StuckBit", stuck) if stuck else BASE
    fixed = base_fixed(BASE, k)
    aug = RawNoiseAugment(profile, model="G+P+R+U" + ("+StuckBit" if stuck else ""), ratio=1.0, fixed=fixed,
                          generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        out = aug(torch.full((n, 4, size, size), level_dn / BASE.span_dn)).numpy().astype(np.float64) * BASE.span_dn
    return np.rint(out)


@pytest.mark.parametrize("low, high", [(8, 0), (8, 2), (3, 0), (0, 16)])
def test_the_stage_writes_codes_with_the_stuck_bits_and_moves_each_by_their_value(low, high):
    entry = {"zero_code": ZERO, "low_mask": low, "high_mask": high}
    got, clean = frames(300.0, 1.0, seed=4, stuck=entry), frames(300.0, 1.0, seed=4)
    codes = got + np.asarray(ZERO, dtype=np.float64).reshape(4, 1, 1)
    codes = codes.astype(np.int64)
    assert not np.any(codes & low) and np.all(codes & high == high)
    # the same draws before the stage: each code is the unstuck one with the bits cleared / set
    assert np.array_equal(got, stuck_bit.stuck_codes(clean, ZERO, low, high))


def test_the_numpy_stage_is_the_raw_code_bitwise():
    dn = np.array([-3.0, 0.4, 7.6, 8.0, 15.2, 100.0]).reshape(1, 1, 6).repeat(4, axis=0)
    zero = [0, 1, 2, 3]
    got = stuck_bit.stuck_codes(dn, zero, 8, 0)
    for c in range(4):
        codes = np.floor(dn[c] + 0.5).astype(np.int64) + zero[c]
        assert np.array_equal(got[c], (codes & ~8) - zero[c])


SESSIONS = 10


@pytest.mark.parametrize("k", [0.375, 3.0])
def test_the_estimate_finds_the_stuck_bits_and_none_where_there_are_none(k):
    """Over 10 sessions at each gain, bias and flat stacks of a camera with bit 3 stuck at 0 and bit 1
    at 1 give exactly those bits, and a camera without stuck bits none (a false bit needs a bit that
    the syntheses set in >= 20 codes to be unset in every measured one: by chance under e^-20)."""
    entry = {"zero_code": ZERO, "low_mask": 8, "high_mask": 2}
    black = [float(z) for z in ZERO]
    for session in range(SESSIONS):
        for truth in (entry, None):
            records = []
            for i, level in enumerate((0.0, 400.0)):
                measured = frames(level, k, seed=1000 * session + i, stuck=truth)
                synth = [frames(level, k, seed=1000 * session + 100 + 10 * i + j) for j in range(2)]
                records.append(stuck_bit.estimate(measured, synth, k, black_code=black))
            got = stuck_bit.combine(records)
            if truth:
                assert (got["low_mask"], got["high_mask"]) == (8, 2), (k, session, got)
                assert got["zero_code"] == black
            else:
                assert stuck_bit.empty(got), (k, session, got)


def test_a_bit_some_stack_moves_is_not_stuck():
    records = [{"zero_code": ZERO, "low": 8 | 4096, "high": 0, "set": 7, "clear": 2 ** 24 - 1},
               {"zero_code": ZERO, "low": 8, "high": 0, "set": 7 | 4096, "clear": 2 ** 24 - 1}]
    assert stuck_bit.combine(records)["low_mask"] == 8


def test_the_estimator_needs_raw_codes():
    with pytest.raises(ValueError, match="black codes"):
        stuck_bit.estimate(np.zeros((2, 4, 8, 8)), [np.zeros((2, 4, 8, 8))], 1.0)
    with pytest.raises(ValueError, match="whole DN"):
        stuck_bit.estimate(np.full((2, 4, 8, 8), 0.5), [np.zeros((2, 4, 8, 8))], 1.0, black_code=[0, 0, 0, 0])


@pytest.mark.parametrize("params, match", [
    ({"zero_code": [512, 512, 512], "low_mask": 8}, "zero_code must hold 4"),
    ({"zero_code": [512.5, 512, 512, 512], "low_mask": 8}, "zero_code must hold 4"),
    ({"zero_code": ZERO, "low_mask": -1}, "low_mask must be a whole number"),
    ({"zero_code": ZERO, "low_mask": 8, "high_mask": 8}, "cannot be stuck at 0 and at 1"),
    ({"zero_code": ZERO, "low_mask": 8, "bits": 3}, "unknown keys"),
])
def test_bad_parameters_name_the_value(params, match):
    with pytest.raises(ValueError, match=match):
        BASE.with_effect("StuckBit", params)


def test_missing_codes_sees_a_stuck_bits_comb_and_not_one_long_empty_run():
    from rawaug.statistics import missing_codes, written_codes

    rng = np.random.default_rng(5)
    dn = np.rint(rng.normal(0.0, 30.0, (2, 4, 64, 64)))
    assert missing_codes(dn) == 0.0
    # one black code: the codes with bit 3 set, half the range, in gaps of 8 (longer than MAX_GAP)
    assert 0.45 < missing_codes(stuck_bit.stuck_codes(dn, [512] * 4, 8)) < 0.55
    # blacks of their own per channel: the channels' combs overlap, shorter gaps are left
    assert 0.1 < missing_codes(stuck_bit.stuck_codes(dn, ZERO, 8)) < 0.5
    # two populations 20 codes apart (a stuck column above the noise): one empty run, not missing codes
    two = np.concatenate([np.rint(rng.normal(0.0, 3.0, 5000)), 40.0 + np.rint(rng.normal(0.0, 1.0, 500))])
    assert written_codes(two).all()


@pytest.mark.parametrize("k", [0.375, 3.0])
def test_calibration_fits_the_read_noise_through_the_stuck_bits(k):
    # the same noise (one seed) written with bit 3 stuck at 0 and without: with the black codes,
    # calibration finds the bit and fits the read and row noise through it as it fits them
    # without it (bias: 4 frames of 4 x 128 x 128); without them the comb is fitted as noise
    stuck = {"zero_code": ZERO, "low_mask": 8, "high_mask": 0}

    def calibrated(entry, black_code):
        bias = frames(0.0, k, 1, n=4, size=128, stuck=entry)
        pairs = [tuple(frames(level, k, 10 + j, n=2, size=128, stuck=entry)) for j, level in enumerate((200.0, 800.0, 3000.0))]
        return calibrate_iso(list(bias), pairs, 800, black_code=black_code)

    clean, through, blind = calibrated(None, ZERO), calibrated(stuck, ZERO), calibrated(stuck, None)
    assert clean.extra["stuck_bits"] is None and blind.extra["stuck_bits"] is None
    assert through.extra["stuck_bits"] == {"low_mask": 8, "high_mask": 0}
    # one lost bit of information: a few percent at most (65 536 values a channel)
    assert abs(through.sigma_tl / clean.sigma_tl - 1) < 0.03 and abs(through.lam - clean.lam) < 0.02, (through, clean)
    assert abs(through.sigma_r / clean.sigma_r - 1) < 0.05 and abs(through.k / clean.k - 1) < 0.01
    # the probability plot of the comb: a scale 2.9x and 2.9x too large (lambda 0.26 and 0.89)
    assert blind.sigma_tl > 2 * clean.sigma_tl


def test_no_bit_is_found_stuck_in_codes_of_smooth_noise():
    # 200 stacks of whole codes of Gaussian noise (sd 0.6 to 40 DN) about blacks of every
    # residue: a bit moves in each (a smooth law over 2^(b + 1) codes sets it)
    rng = np.random.default_rng(5)
    for _ in range(200):
        sd, black = rng.uniform(0.6, 40.0), int(rng.integers(0, 4096))
        assert stuck_masks(np.rint(rng.normal(black, sd, 4 * 64 * 64)).astype(np.int64)) == (0, 0)


def test_the_loops_bias_fit_goes_through_the_stuck_bits_too():
    # the loop's base read noise of a bias stack (one frame: stage1.bias_frame_noise), as calibration's
    stuck = {"zero_code": ZERO, "low_mask": 8, "high_mask": 0}
    clean, _, _ = bias_frame_noise(frames(0.0, 3.0, 1, n=1, size=128)[0], black_code=ZERO)
    through, sigma_r, _ = bias_frame_noise(frames(0.0, 3.0, 1, n=1, size=128, stuck=stuck)[0], black_code=ZERO)
    clean_r = bias_frame_noise(frames(0.0, 3.0, 1, n=1, size=128)[0])[1]
    assert abs(through.sigma_tl / clean.sigma_tl - 1) < 0.03 and abs(through.lam - clean.lam) < 0.02, (through, clean)
    assert abs(sigma_r / clean_r - 1) < 0.1  # 256 sensor rows of one frame
