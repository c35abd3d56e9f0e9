"""The measured code map is the ADC's transfer: written codes stay, missing codes go to a
neighbour, and a signal keeps its DN at every level."""
from pathlib import Path

import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects.code_map import combine, estimate, next_above
from rawaug.statistics import MAX_GAP, written_codes
from rawaug.io import read_frame

DATA = Path(__file__).parent / "data"


def _apply(m, values):
    """The stage on pre-rounding ``values`` (DN): a missing code's inputs go below or above its split."""
    lut, lo = np.asarray(m["map_dn"][0]), m["lo_dn"][0]
    split = np.asarray(m["split_dn"][0])
    r = np.floor(values + 0.5)  # as the kernels round
    i = (r - lo).astype(np.int64)
    inside = (i >= 0) & (i < lut.size)
    j = np.clip(i, 0, lut.size - 1)
    mapped = np.where(values - r < split[j], lut[j], next_above(lut)[j])
    return np.where(inside, mapped, r)


def test_digital_gain_comb_is_mapped_onto_the_written_codes():
    rng = np.random.default_rng(0)
    adc = np.rint(rng.normal(300.0, 150.0, 400_000))
    frames = np.rint(adc * 1.5)  # gain 1.5 after the ADC: every third code is missing
    m = estimate(frames.reshape(1, 4, 500, 200), rng.normal(450.0, 225.0, 400_000), k=1.0)
    written = set(np.unique(frames).tolist())
    s = np.linspace(-0.5, 899.5, 900_001)[:-1]  # a signal swept over the codes 0 .. 899
    out = _apply(m, s)
    assert set(out.tolist()) <= written  # only codes the camera writes
    r = np.arange(0.0, 900.0)
    on = np.isin(r, list(written))
    assert np.array_equal(_apply(m, r)[on], r[on])  # written codes map to themselves
    assert np.abs(out - np.floor(s + 0.5)).max() <= 1  # a missing code goes to a neighbour: the signal keeps its DN
    # its inputs split between both (gain 1.5 writes 3k and 3k + 2: 3k + 1 goes half down, half up)
    assert abs(np.mean(out - s)) < 0.02


def test_no_missing_codes_in_a_smooth_histogram_or_its_sparse_tail():
    # false missing codes over 20 seeds: none (a code expecting >= 10 pixels is empty with
    # probability 4.5e-5, and the sparse tail never counts)
    false = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        v = np.rint(np.concatenate([rng.normal(0, 3, 200_000), rng.standard_cauchy(2000) * 30]))
        false += int((~written_codes(v)).sum())
        if seed == 0:
            m = estimate(v.reshape(1, 1, 1, -1), rng.normal(0, 3, v.size), k=1.0)
            assert len(m["map_dn"][0]) == 1  # nothing to map
    assert false == 0, false


def test_real_dark_frame_comb_and_its_stuck_column():
    # InfiniteISP's dark frame: codes 0, 4, 5, 8, 9, 10, ... and a column stuck near 960 DN,
    # hundreds of codes above the rest: that empty run is no comb (longer than MAX_GAP)
    frame = read_frame(DATA / "InfiniteISP_BlackImage_crop512_y0_x1408_12bits_BGGR.raw", width=512, height=512,
                       dtype="<u2", cfa="BGGR", black_level=0, white_level=4095).packed_dn().astype(np.float64)
    assert frame.max() > 100 * MAX_GAP
    m = estimate(frame[None], np.random.default_rng(2).normal(3.7, 3.0, frame.shape)[None], k=1.0)
    assert m["lo_dn"] == [0.0] and len(m["map_dn"][0]) == 9  # codes 0 .. 8: the gaps 1-3 and 6-7
    lut = np.asarray(m["map_dn"][0])
    assert set(lut.tolist()) <= {0.0, 4.0, 5.0, 8.0} and lut[[0, 4, 5, 8]].tolist() == [0.0, 4.0, 5.0, 8.0]


def test_a_signal_through_the_stage_keeps_its_level():
    # the stage on a flat 200 DN signal: the mean stays within the comb's rounding of 200 DN
    rng = np.random.default_rng(3)
    frames = np.rint(np.rint(rng.normal(0, 4, 400_000)) * 1.5)
    m = estimate(frames.reshape(1, 4, 500, 200), rng.normal(0, 6, 400_000), k=1.0)
    base = NoiseProfile.load("SonyA7S2")
    profile = base.with_effect("CodeMap", m)
    fixed = {"k": 1.0, "sigma_tl": 4.0, "lambda": 0.0, "sigma_r": 0.0}
    level = 20.0 / base.span_dn
    out = {}
    for p in (base, profile):
        aug = RawNoiseAugment(p, model="G*+R", ratio=1.0, fixed=fixed, include_profile_effects=True,
                              generator=torch.Generator().manual_seed(0), rank_seeding=False)
        out[p is profile] = aug(torch.full((2, 4, 128, 128), level)).double().numpy() * base.span_dn
    assert abs(out[True].mean() - out[False].mean()) < 0.3  # DN; the old histogram map moved it by tens
    codes = np.unique(np.rint(out[True]))
    lo, n = m["lo_dn"][0], len(m["map_dn"][0])
    inside = codes[(codes >= lo) & (codes < lo + n)]  # where the comb was measured (not its sparse tail)
    assert inside.size > 10 and np.isin(inside, np.unique(frames)).all()  # the comb, at 20 DN as at 0


def _dnl(rng, mean, sd, n=400_000):
    """An ADC whose codes 4k + 3 are never written: their inputs read as 4k + 2 or 4k + 4."""
    q = np.floor(rng.normal(mean, sd, n) + 0.5)
    return np.where(q % 4 == 3, q + np.where(rng.random(n) < 0.5, -1.0, 1.0), q)


def test_a_periodic_comb_goes_on_at_every_signal_level():
    rng = np.random.default_rng(5)
    dark = estimate(_dnl(rng, 0.0, 8.0).reshape(1, 4, 500, 200), np.rint(rng.normal(0, 8, 400_000)), k=1.0)
    assert dark["period_dn"] == [4.0]
    smooth = estimate(np.rint(rng.normal(0, 8, 400_000)).reshape(1, 4, 500, 200), np.rint(rng.normal(0, 8, 400_000)), k=1.0)
    assert smooth["period_dn"] == [0.0]  # no comb, no period
    base = NoiseProfile.load("SonyA7S2")
    profile = base.with_effect("CodeMap", dark)
    aug = RawNoiseAugment(profile, model="G", ratio=1.0, fixed={"k": 1.0, "sigma_g": 4.0}, include_profile_effects=True,
                          generator=torch.Generator().manual_seed(0), rank_seeding=False)
    for level in (-300.0, 3000.0):  # far outside the 0 +- 40 DN the map was measured on
        codes = np.rint(aug(torch.full((1, 4, 64, 64), level / base.span_dn)).double().numpy() * base.span_dn)
        assert not np.any(codes % 4 == 3) and abs(codes.mean() - level) < 0.5, level  # without the period: a quarter
    # a flat stack's map joined to the bias stack's: the comb fills the codes between their ranges
    flat = estimate(_dnl(rng, 1500.0, 40.0).reshape(1, 4, 500, 200), np.rint(rng.normal(1500, 40, 400_000)), k=1.0)
    joined = combine([dark, flat])
    lut = np.asarray(joined["map_dn"][0])
    r = joined["lo_dn"][0] + np.arange(lut.size)
    assert joined["period_dn"] == [4.0] and np.all(lut[r % 4 == 3] != r[r % 4 == 3]) and np.abs(lut - r).max() == 1


def test_calibration_counts_a_comb_not_the_gap_between_two_populations():
    # a dark frame whose leaky columns (3 % of the pixels, ~120 DN) lie above the 99th percentile's
    # reach: the empty run between them and the noise is no missing code; a digital gain's comb is
    from rawaug.calibration.stage1 import missing_code_fraction

    rng = np.random.default_rng(5)
    noise = np.rint(rng.normal(100.0, 3.0, 97_000))
    leaky = np.rint(3.0 * rng.poisson(40.0, 3_000) + rng.normal(100.0, 3.0, 3_000))  # K = 3, and the read noise
    assert missing_code_fraction(np.concatenate([noise, leaky])) == 0.0
    comb = np.rint(np.rint(rng.normal(100.0, 20.0, 100_000)) * 1.5)  # a gain of 1.5 after the ADC
    assert abs(missing_code_fraction(comb) - 1 / 3) < 0.02


def test_a_missing_codes_inputs_split_between_both_neighbours():
    # an ADC that never writes 4k + 3 reads those inputs as 4k + 2 or 4k + 4, half each: codes
    # 2 and 0 mod 4 each hold 3/8 of the pixels. Sending them all to one neighbour (the map
    # before) made that 1/4 and 1/2 and moved the mean by a quarter DN. Spread of a share of
    # 4 x 64 x 64 pixels: 0.004; bound 0.02
    rng = np.random.default_rng(11)
    m = estimate(_dnl(rng, 0.0, 8.0).reshape(1, 4, 500, 200), np.rint(rng.normal(0, 8, 400_000)), k=1.0)
    profile = NoiseProfile.load("SonyA7S2").with_effect("CodeMap", m)
    aug = RawNoiseAugment(profile, model="G", ratio=1.0, fixed={"k": 1.0, "sigma_g": 8.0}, include_profile_effects=True,
                          generator=torch.Generator().manual_seed(0), rank_seeding=False)
    for level in (0.0, 1000.0):  # inside the measured map and far beyond it (the period)
        codes = np.rint(aug(torch.full((1, 4, 64, 64), level / profile.span_dn)).double().numpy() * profile.span_dn)
        shares = [np.mean(codes % 4 == phase) for phase in range(4)]
        assert shares[3] == 0.0
        assert abs(shares[2] - 0.375) < 0.02 and abs(shares[0] - 0.375) < 0.02, (level, shares)
        assert abs(codes.mean() - level) < 0.5


def _wb_stack(rng, n=400_000):
    """A stack (1, 4, 500, 200) whose red and blue channels were multiplied by 1.25 after the
    ADC (codes rounded first: one code in five is never written there); the greens untouched."""
    v = np.rint(rng.normal(0.0, 8.0, n)).reshape(1, 4, 500, 200)
    v[:, [0, 2]] = np.rint(1.25 * v[:, [0, 2]])
    return v


def test_a_comb_in_some_channels_gets_a_map_per_channel(samplers):
    # white-balance gain after the ADC on R and B: one map each for them, none for the greens;
    # through the stage (either kernel) R and B miss the codes the camera never writes, inside
    # the measured range and, by the comb's period, far beyond it; the greens keep every code
    rng = np.random.default_rng(13)
    frames = _wb_stack(rng)
    m = estimate(frames, np.rint(rng.normal(0.0, 9.0, (2, 1, 4, 500, 200))), k=1.0)
    assert m["channel"] == [0, 1, 2, 3]
    assert len(m["map_dn"][1]) == 1 and len(m["map_dn"][3]) == 1  # G1, G2: rounded only
    assert m["period_dn"][0] == m["period_dn"][2] == 10.0  # 1.25 x n rounded half to even: 2 codes of 10 missing
    joined = combine([m, estimate(_wb_stack(rng) + 400.0 * np.array([1.25, 1, 1.25, 1])[:, None, None],
                                  np.rint(rng.normal(400.0, 9.0, (2, 1, 4, 500, 200))), k=1.0)])
    assert joined["channel"] == [0, 1, 2, 3] and joined["k"] == [1.0] * 4
    profile = NoiseProfile.load("SonyA7S2").with_effect("CodeMap", m)
    aug = RawNoiseAugment(profile, model="G", ratio=1.0, fixed={"k": 1.0, "sigma_g": 6.0}, include_profile_effects=True,
                          generator=torch.Generator().manual_seed(0), rank_seeding=False)
    written = np.unique(frames[:, 0])
    for level in (0.0, 2000.0):
        codes = np.rint(aug(torch.full((1, 4, 48, 64), level / profile.span_dn)).double().numpy()[0] * profile.span_dn)
        for c in (0, 2):  # the comb: 1.25 n rounded writes these codes of each ten
            assert np.all(np.isin(codes[c] % 10, written[(written >= 0) & (written < 10)])), (level, c)
        for c in (1, 3):
            assert np.all(np.isin(np.arange(level - 10, level + 10), codes[c])), (level, c)
        assert abs(codes.mean() - level) < 0.5


def test_a_comb_in_every_channel_stays_one_map():
    rng = np.random.default_rng(17)
    v = np.rint(1.5 * np.rint(rng.normal(0.0, 8.0, 400_000))).reshape(1, 4, 500, 200)
    m = estimate(v, np.rint(rng.normal(0.0, 12.0, (2, 1, 4, 500, 200))), k=1.0)
    assert "channel" not in m and len(m["k"]) == 1 and m["period_dn"] == [6.0]  # 1.5 n rounded half to even


def test_channel_records_are_checked():
    import pytest

    base = NoiseProfile.load("SonyA7S2")
    one = {"lo_dn": [0.0], "map_dn": [[0.0]]}
    with pytest.raises(ValueError, match=r"must be \[-1\]"):
        base.with_effect("CodeMap", {"k": [1.0, 1.0], "lo_dn": [0.0, 0.0], "map_dn": [[0.0], [0.0]], "channel": [0, 2]})
    with pytest.raises(ValueError, match="one packed channel per record"):
        base.with_effect("CodeMap", {"k": [1.0], **one, "channel": [4]})


def test_a_non_integer_digital_gain_writes_equally_wide_codes(samplers):
    # a digital gain of 1.25 after the ADC writes 8 codes in 10, each 1.25 DN of input wide; the
    # map measured from a dark stack reproduces each code's share of a 10 DN wide noise at 0 DN
    # and at 1000 DN (beyond the measured range, by the period) within 5 sd of the two counts.
    # Sending each missing code's inputs to its neighbours (before) made those 1.5 DN wide and
    # the others 1, 20 % off a count of ~3000 (~20 sd)
    rng = np.random.default_rng(19)
    frames = np.rint(1.25 * np.rint(rng.normal(0.0, 8.0, 400_000) / 1.0)).reshape(1, 4, 500, 200)
    m = estimate(frames, np.rint(rng.normal(0.0, 10.0, 400_000)), k=1.0)
    assert m["period_dn"] == [10.0]
    profile = NoiseProfile.load("SonyA7S2").with_effect("CodeMap", m)
    aug = RawNoiseAugment(profile, model="G", ratio=1.0, fixed={"k": 1.0, "sigma_g": 10.0}, include_profile_effects=True,
                          generator=torch.Generator().manual_seed(0), rank_seeding=False)
    for level in (0.0, 1000.0):
        out = np.rint(aug(torch.full((1, 4, 128, 128), level / profile.span_dn)).double().numpy() * profile.span_dn).ravel()
        truth = level + np.rint(1.25 * np.rint(rng.normal(0.0, 10.0, out.size) / 1.25))  # the camera at that level
        for code in np.arange(level - 8, level + 9):
            a, b = np.sum(out == code), np.sum(truth == code)
            assert abs(a - b) <= 5 * np.sqrt(a + b + 1), (level, code, a, b)


def test_a_short_map_joins_the_period_it_is_consistent_with():
    # a digital gain of 1.25: a bias stack of 3 DN noise spans too few codes to show the period
    # (none of its own), a flat stack shows it; joined, the gain has the period, and a bias map
    # of another comb (codes 4k + 3 missing) keeps the two from being joined as one
    rng = np.random.default_rng(23)
    bias = estimate(np.rint(1.25 * np.rint(rng.normal(0.0, 2.5, 400_000))).reshape(1, 4, 500, 200),
                    np.rint(rng.normal(0.0, 3.0, 400_000)), k=1.0)
    flat = estimate(np.rint(1.25 * np.rint(rng.normal(800.0, 30.0, 400_000))).reshape(1, 4, 500, 200),
                    np.rint(rng.normal(1000.0, 37.0, 400_000)), k=1.0)
    assert bias["period_dn"] == [0.0] and flat["period_dn"] == [10.0]
    assert combine([bias, flat])["period_dn"] == [10.0]
    other = estimate(_dnl(rng, 0.0, 3.0).reshape(1, 4, 500, 200), np.rint(rng.normal(0, 3, 400_000)), k=1.0)
    assert combine([other, flat])["period_dn"] == [0.0]


def test_a_comb_seen_only_above_a_level_is_not_carried_below_it(samplers):
    # a dual conversion gain: readings above 800 DN come through a low-gain path in steps of
    # 4 DN; a bias stack (3 DN of noise about 0) shows every code, a flat about 790 DN every
    # code below 800 and the comb above. Joined, the comb's map starts at 800 DN and stops
    # there: at 0 DN the stage writes every code (before, the comb went on below and a bias
    # synthesis missed 3 codes in 4), and so it does at 780 DN; at 3000 DN only multiples of 4
    rng = np.random.default_rng(29)
    bias = estimate(np.rint(rng.normal(0.0, 3.0, 400_000)).reshape(1, 4, 500, 200),
                    np.rint(rng.normal(0.0, 3.0, 400_000)), k=1.0)

    def flat(mean):
        x = rng.normal(mean, 40.0, 400_000)
        return estimate(np.where(x > 800.0, 4.0 * np.rint(x / 4.0), np.rint(x)).reshape(1, 4, 500, 200),
                        np.rint(rng.normal(mean, 40.0, 400_000)), k=1.0)

    high = flat(1000.0)
    assert high["period_dn"] == [4.0]
    joined = combine([bias, high])
    assert joined["comb_from_dn"] == [bias["clear_dn"][0][0][1] + 1.0] and "comb_to_dn" not in joined
    assert joined["lo_dn"][0] > joined["comb_from_dn"][0]  # the bound lies below the map: the kernels' extension stops
    both = combine([bias, flat(790.0), high])
    assert both["lo_dn"] == [800.0] and both["comb_from_dn"] == [800.0]  # the straddling flat's codes below 800 are clear
    for m in (joined, both):
        profile = NoiseProfile.load("SonyA7S2").with_effect("CodeMap", m)
        aug = RawNoiseAugment(profile, model="G", ratio=1.0, fixed={"k": 1.0, "sigma_g": 3.0}, include_profile_effects=True,
                              generator=torch.Generator().manual_seed(0), rank_seeding=False)
        for level in (0.0, 780.0) if m is both else (0.0,):
            low = np.rint(aug(torch.full((1, 4, 32, 32), level / profile.span_dn)).double().numpy() * profile.span_dn)
            assert np.all(np.isin(np.arange(level - 4.0, level + 5.0), low)), level  # every code
        out = np.rint(aug(torch.full((1, 4, 32, 32), 3000.0 / profile.span_dn)).double().numpy() * profile.span_dn)
        assert np.all(out % 4 == 0) and abs(out.mean() - 3000.0) < 0.5
    with pytest.raises(ValueError, match=r"comb_from_dn\[0\] must be null \(no bound\) or a whole DN at or below"):
        NoiseProfile.load("SonyA7S2").with_effect("CodeMap", {**joined, "comb_from_dn": [joined["lo_dn"][0] + 1.0]})
