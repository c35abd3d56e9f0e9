"""The closed loop: undeclared effects are named and their error falls by at least half;
frames without one get nothing added; parameter tables get their regime change and floor."""
from importlib import resources
from pathlib import Path

import json
import math
import numpy as np
import pytest
from scipy import stats

from rawaug import NoiseProfile
from rawaug.cli import main
from rawaug.loop import FrameStack, frame_statistics, run_frame_loop, synthesize
from rawaug.loop.parameters import fit_structure, frame_table_loop, read_frame_table, relation_loop

BASE = NoiseProfile.load("SonyA7S2")
K = 1.0
DATA = Path(str(resources.files("rawaug") / "data" / "measured" / "PMN"))
COL = {"Col": {"seed": 5, "k": [K], "sigma_dn": [0.3], "fixed_dn": [0.5]}}
FPN = {"FPN": {"seed": 3, "k": [K], "sigma_dn": [0.8], "shading_dn": [[[0, 1, 2, 3], [1, 2, 3, 4], [2, 3, 4, 5], [3, 4, 5, 6]]]}}
HOT = {"Hot": {"seed": 9, "density": 5e-4, "log_std": 0.3, "k": [K], "median_dn": [60.0]}}


def measured_stack(effects, seed=123, n=8, size=128, label="measured", exposure_s=None):
    """A stack from the base profile plus effects the fitted model (BASE) does not have: bias
    frames, or dark frames of ``exposure_s`` seconds (offsets 0.5 DN in both)."""
    prof = BASE
    for token, params in effects.items():
        prof = prof.with_effect(token, params)
    kind = "dark" if exposure_s else "bias"
    template = FrameStack(np.full((n, 4, size, size), 0.5), K, kind=kind, exposure_s=exposure_s,
                          offsets_dn=[0.5] * 4)  # shape and settings only (non-integer: dithered)
    return FrameStack(synthesize(prof, template, 1, seed)[0].astype(np.float64), K, label=label, kind=kind,
                      exposure_s=exposure_s, offsets_dn=[0.5] * 4 if exposure_s else None)


BLE = {"BLE": {"k": [K], "sigma_dn": [0.6], "channel_sigma_dn": [0.0]}}
LINES = {"Lines": {"seed": 29, "row_density": 0.01, "col_density": 0.02, "log_std": 0.3, "negative": 0.3, "k": [K], "median_dn": [30.0]}}
CLIP = {"Clip": {"floor_dn": -2.0}}


def two_level_read_noise():
    """A read chain that settles at one of two levels: read noise 0.75 N(-2, 2) + 0.25 N(6, 2)
    (DN; variance 14, the base model's), as a quantile table: no Tukey lambda, no physical
    effect of the set; only the measured distribution reproduces it."""
    from scipy import stats

    from rawaug.effects.read_distribution import grid

    x = np.linspace(-30.0, 40.0, 200_001)
    cdf = 0.75 * stats.norm.cdf(x, -2.0, 2**0.5) + 0.25 * stats.norm.cdf(x, 6.0, 2**0.5)
    q = np.interp(stats.norm.cdf(grid()), cdf, x)
    return {"ReadDist": {"k": [K], "quantiles_dn": [[q.tolist()] * 4]}}


XTALK = {"Xtalk": {"k": [K], "tap_0_0_dn": [1.2], "tap_0_1_dn": [1.2], "tap_1_-1_dn": [-0.53]}}  # coupled readout, opposite on a diagonal
BAND = {"Band": {"k": [K], "freq_per_row": [[0.137]], "amplitude_dn": [[1.0]]}}  # interference during readout
COLBAND = {"ColBand": {"k": [K], "freq_per_col": [[0.181]], "amplitude_dn": [[1.0]]}}  # ... along a serially read row
DIAGBAND = {"DiagBand": {"k": [K], "freq_per_col": [[0.137]], "freq_per_row": [[0.291]], "amplitude_dn": [[1.0]]}}  # ... not line-locked
ROWFIX = {"RowFix": {"seed": 37, "k": [K], "fixed_dn": [1.2]}}  # row drivers' offsets
ROWCH = {"RowCh": {"k": [K], "sigma_dn": [1.2]}}  # two ADC banks, a row offset each
READMAP = {"ReadMap": {"k": [K], "channel_dn": [[0.0, 0.0, 2.0, 0.0]], "row_block_dn": [[0.0] * 8],
                       "col_block_dn": [[0.0] * 4 + [1.5] * 4]}}  # B's own amplifier; the right half read by a noisier one
SHARED = {"Shared": {"k": [K], "sigma_dn": [1.2]}}  # a 2x2 shared-pixel readout
RTS = {"RTS": {"seed": 41, "density": 0.01, "high": 0.5, "log_std": 0.3, "k": [K], "median_dn": [20.0]}}  # telegraph pixels
DEAD = {"Dead": {"seed": 53, "density": 0.003, "levels_dn": [-60.0, -60.0, 0.0, 400.0]}}  # dead: low, at black, high
DRIFT = {"RowDrift": {"k": [K], "octave_dn": [[0.0, 0.3, 0.5, 0.8, 1.0, 0.0, 0.0, 0.0]]}}  # 1/f-like row noise
CASES = {"Col": COL, "FPN": FPN, "Hot": HOT, "BLE": BLE, "Clip": CLIP, "defect lines": LINES, "mixed": {**COL, **FPN, **HOT},
         "two-level read": two_level_read_noise(), "crosstalk": XTALK, "banding": BAND, "column banding": COLBAND, "diagonal banding": DIAGBAND,
         "fixed rows": ROWFIX,
         "row per channel": ROWCH, "read-noise map": READMAP, "shared pixels": SHARED,
         "telegraph": RTS, "dead pixels": DEAD, "row drift": DRIFT}


def loop_succeeds(effects, seed):
    """The loop on a measured stack (its fixed patterns and noise from ``seed``): exactly the
    planted effects added, each cutting its evidence's error by half, the battery's rms z
    halved, nothing significant left."""
    result = run_frame_loop([measured_stack(effects, seed=seed)], BASE, n_synth=10, seed=1)
    if set(result.added) != set(effects) or result.unexplained():
        return False
    if not effects:
        return result.steps == []
    if any(step.accepted and step.error_after > 0.5 * step.error_before for step in result.steps):
        return False
    final = [s for s in result.steps if s.accepted][-1]  # the battery of the final model
    return final.battery_after["rms_z"] < 0.5 * result.steps[0].battery_before["rms_z"]


# Measured over the 20 measured-stack seeds 200-219 (test_loop_rates_over_seeds, slow;
# counted 2026-11-24 with Xtalk, Band, RowFix and RowCh among the candidates): every case of
# CASES then named and fixed in 20 of 20; the ELD-only stack got nothing added in 20 of 20.
# Counted again with ReadMap, Shared and RTS: every case, those three included, and the
# ELD-only stack within the bound (19 or 20 of 20). The default run checks the first seed of
# the cases below; the others' first seed runs with the slow rates (which count it), their
# estimators' round trips in the default run (tests/test_effects_loop.py; Col, FPN and Hot in
# "mixed"), to keep the default run near 5 minutes.
# (banding, column banding and telegraph joined the slow ones in the twenty-second session, when four new
# effects and a statistic took the default run to 6 minutes)
DEFAULT_CASES = ("mixed", "BLE", "Clip", "defect lines", "two-level read")


@pytest.mark.parametrize("effects", [e if name in DEFAULT_CASES else pytest.param(e, marks=pytest.mark.slow)
                                     for name, e in CASES.items()], ids=list(CASES))
def test_loop_names_each_undeclared_effect_and_halves_its_error(effects):
    assert loop_succeeds(effects, seed=200)


def test_loop_adds_nothing_without_an_undeclared_effect():
    assert loop_succeeds({}, seed=200)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(CASES) + ["none"])
def test_loop_rates_over_seeds(name):
    # 19 of 20 or better: a success rate of 0.95 passes with probability 0.74, one of 0.8
    # with probability 0.07 (binomial)
    effects = CASES.get(name, {})
    successes = sum(loop_succeeds(effects, seed) for seed in range(200, 220))
    print(f"{name}: {successes} of 20 seeds")  # shown with -rA: the count, not only the bound
    assert successes >= 19, f"{name}: {successes} of 20 seeds"


DARK = {"Dark": {"seed": 21, "k": [K], "rate_e_per_s": [4.0], "dsnu": [0.3]}}


# a colour whose pixels leak more (their layout in the 2x2 tile): B 4 times R
DARK_CHANNEL = {"Dark": {**DARK["Dark"], "channel": [0.4, 1.0, 1.6, 1.0]}}


@pytest.mark.parametrize("effects", [DARK, DARK_CHANNEL, {}], ids=["Dark", "Dark per channel", "none"])
def test_loop_finds_dark_current_in_dark_frames_only_where_there_is_some(effects):
    # bias frames cannot show dark current; dark frames of 5 s (20 e- a pixel) do
    stacks = [measured_stack(effects, seed=300, n=6, size=96, label="bias"),
              measured_stack(effects, seed=301, n=6, size=96, label="dark 5 s", exposure_s=5.0)]
    result = run_frame_loop(stacks, BASE, n_synth=8, seed=1)
    assert result.added == list(effects)
    assert not result.unexplained()
    if effects:
        rec = result.profile.effects["Dark"]
        # rate: mean excess of 6 x 4 x 96 x 96 pixels, ~1 % spread; DSNU from a 221k-pixel map
        assert abs(rec["rate_e_per_s"][0] - 4.0) < 0.2 and abs(rec["dsnu"][0] - 0.3) < 0.05, rec
        # each channel's mean of 6 x 96 x 96 pixels: its relative rate within 0.002 (measured
        # 0.401, 1.003, 1.596, 1.000 against 0.4, 1, 1.6, 1); equal rates read as such
        assert np.allclose(rec["channel"], effects["Dark"].get("channel", [1.0] * 4), atol=0.03), rec


DARK_HOT = {"DarkHot": {"seed": 63, "density": 2e-3, "median_e_per_s": 10.0, "log_std": 0.4}}


def dark_hot_named(seed):
    """Bias and dark (5 s) stacks of a camera with hot pixels of dark current: DarkHot named
    (not Hot: the bias frames have none), nothing left, its population within bounds."""
    stacks = [measured_stack(DARK_HOT, seed=seed, n=6, size=96, label="bias"),
              measured_stack(DARK_HOT, seed=seed + 1, n=6, size=96, label="dark 5 s", exposure_s=5.0)]
    result = run_frame_loop(stacks, BASE, n_synth=8, seed=1)
    if result.added != ["DarkHot"] or result.unexplained():
        return False
    rec = result.profile.effects["DarkHot"]
    n = 4 * 96 * 96  # pixels; ~74 hot ones: density within 5 binomial sd, the median's log within 5 standard errors
    return abs(rec["density"] - 2e-3) < 5 * (2e-3 / n) ** 0.5 and abs(np.log(rec["median_e_per_s"] / 10.0)) < 5 * 0.4 / 74**0.5


# effects only dark frames show: leaky columns or rows (8 e-/s more in 2 % of the sensor lines) and
# a black level that sags 0.4 DN per second of exposure (no electrons: no shot noise)
DARK_ONLY = {"DarkCol": {"seed": 73, "density": 0.02, "median_e_per_s": 8.0, "log_std": 0.3},
             "DarkRow": {"seed": 89, "density": 0.02, "median_e_per_s": 8.0, "log_std": 0.3},
             "DarkOffset": {"k": [K], "dn_per_s": [-0.4]},
             "DarkNoise": {"k": [K], "rate_dn2_per_s": [1.0]}}


def dark_only_named(token, seed):
    """Bias and dark (5 s) stacks of a camera with ``token``: it is named (not Lines or Dark:
    the bias frames do not show it, the dark frames' variance does not grow with it), nothing
    is left, and its estimate is within bounds."""
    effects = {token: DARK_ONLY[token]}
    stacks = [measured_stack(effects, seed=seed, n=6, size=96, label="bias"),
              measured_stack(effects, seed=seed + 1, n=6, size=96, label="dark 5 s", exposure_s=5.0)]
    result = run_frame_loop(stacks, BASE, n_synth=8, seed=1)
    if result.added != [token] or result.unexplained():
        return False
    rec = result.profile.effects[token]
    if token == "DarkCol":  # the pattern's leaky columns (as 100 s shows them all) within one column; their rate
        from rawaug.effects.dark_columns import bright_columns

        seeded = bright_columns(measured_stack(effects, seed=seed, n=2, size=96, exposure_s=100.0).frames_dn)[0]
        return abs(rec["density"] - seeded) <= 1 / 192 + 1e-12 and abs(np.log(rec["median_e_per_s"] / 8.0)) < 0.5
    if token == "DarkRow":  # the same along the sensor rows
        from rawaug.effects.dark_rows import bright_rows

        seeded = bright_rows(measured_stack(effects, seed=seed, n=2, size=96, exposure_s=100.0).frames_dn)[0]
        return abs(rec["density"] - seeded) <= 1 / 192 + 1e-12 and abs(np.log(rec["median_e_per_s"] / 8.0)) < 0.5
    if token == "DarkNoise":  # 5 DN^2 at 5 s over the read noise's 14.3 (17 % in std): the rate within a sixth
        return abs(rec["rate_dn2_per_s"][0] - 1.0) < 0.15
    # the mean of 6 x 4 x 96 x 96 pixels and their temporal variance: ~0.04 DN, 0.008 DN/s over 5 s
    return abs(rec["dn_per_s"][0] + 0.4) < 0.05


SPIKES = {"Spikes": {"density": 5e-4, "density_per_s": 0.0, "log_std": 0.5, "k": [K], "median_dn": [50.0]}}


def spikes_named(seed):
    """A bias stack with impulses (0.05 % of the values of every frame, at new pixels): Spikes
    named (not Hot, RTS or a heavier read-noise tail), nothing left, its density within 5
    binomial sd and its median (of the detected, ~all of them) within 5 standard errors."""
    result = run_frame_loop([measured_stack(SPIKES, seed=seed, n=8, size=96)], BASE, n_synth=8, seed=1)
    if result.added != ["Spikes"] or result.unexplained():
        return False
    rec, n = result.profile.effects["Spikes"], 8 * 4 * 96 * 96
    return abs(rec["density"] - 5e-4) < 5 * (5e-4 / n) ** 0.5 and abs(np.log(rec["median_dn"][0] / 50.0)) < 5 * 0.5 / (5e-4 * n) ** 0.5


COLRTS = {"ColRTS": {"seed": 81, "density": 0.04, "high": 0.5, "log_std": 0.2, "k": [K], "median_dn": [5.0]}}


def telegraph_columns_named(seed):
    """A bias stack whose telegraph columns (4 % of the sensor columns, a 5 DN step in half the
    frames): ColRTS named (not Col, Lines or Band), nothing left, its density within 5
    binomial sd of the pattern's and its median step within 0.2 in log."""
    result = run_frame_loop([measured_stack(COLRTS, seed=seed, n=8, size=96)], BASE, n_synth=8, seed=1)
    if result.added != ["ColRTS"] or result.unexplained():
        return False
    rec = result.profile.effects["ColRTS"]
    return abs(rec["density"] - 0.04) < 5 * (0.04 / 192) ** 0.5 and abs(np.log(rec["median_dn"][0] / 5.0)) < 0.2


ROWRTS = {"RowRTS": {"seed": 83, "density": 0.04, "high": 0.5, "log_std": 0.2, "k": [K], "median_dn": [5.0]}}


def telegraph_rows_named(seed):
    """A bias stack whose telegraph rows (4 % of the sensor rows, a 5 DN step in half the
    frames): RowRTS named (not R, RowFix, Lines or Band), nothing left, its density within four
    rows of the pattern's (14 of 192 rows, as 40 frames with a 50 DN step show them: the
    estimate's error over 20 seeds, 300-338 even, had an sd of 1.1 rows, at most 2.8) and its
    median step within 0.2 in log."""
    from rawaug.statistics import sensor_row_means

    result = run_frame_loop([measured_stack(ROWRTS, seed=seed, n=8, size=96)], BASE, n_synth=8, seed=1)
    if result.added != ["RowRTS"] or result.unexplained():
        return False
    rec = result.profile.effects["RowRTS"]
    loud = sensor_row_means(measured_stack({"RowRTS": {**ROWRTS["RowRTS"], "median_dn": [50.0], "log_std": 0.0}},
                                           seed=seed, n=40, size=96).frames_dn)
    seeded = float(((loud - loud.mean(axis=1, keepdims=True)).std(axis=0) > 5.0).mean())
    return abs(rec["density"] - seeded) <= 4 / 192 + 1e-12 and abs(np.log(rec["median_dn"][0] / 5.0)) < 0.2


NOISY = {"Noisy": {"seed": 87, "density": 0.005, "log_std": 0.3, "k": [K], "median_dn": [12.0]}}


def noisy_named(seed):
    """A bias stack with noisy pixels (0.5 % of the pixels, 12 DN more temporal noise against
    3.4 DN of read noise): Noisy named (not RTS, Hot or a heavier read-noise tail), nothing left,
    its density within 0.35 and its median within 0.25 in log: the estimate's spread over 20
    seeds (300-319) was 0.11 and 0.07 (about 180 pixels of 8 frames, some of them lost in the
    read noise)."""
    result = run_frame_loop([measured_stack(NOISY, seed=seed, n=8, size=96)], BASE, n_synth=8, seed=1)
    if result.added != ["Noisy"] or result.unexplained():
        return False
    rec = result.profile.effects["Noisy"]
    return abs(np.log(rec["density"] / 0.005)) < 0.35 and abs(np.log(rec["median_dn"][0] / 12.0)) < 0.25


DARK_RTS = {"DarkRTS": {"seed": 99, "density": 0.005, "high": 0.5, "median_e_per_s": 20.0, "log_std": 0.3}}


def dark_telegraph_named(seed):
    """Bias and dark (5 s) stacks of a camera with dark-current telegraph pixels (0.5 % of the
    pixels, 100 e- more in half the frames): DarkRTS named (not DarkHot, Spikes or RTS: the
    bias frames show nothing, the darks two states), nothing left, its density within 0.15 and
    its median within 0.08 in log: the estimate's spread over 20 seeds (300-338, even) was
    0.043 and 0.021 about means of +0.02 and -0.02."""
    stacks = [measured_stack(DARK_RTS, seed=seed, n=6, size=96, label="bias"),
              measured_stack(DARK_RTS, seed=seed + 1, n=6, size=96, label="dark 5 s", exposure_s=5.0)]
    result = run_frame_loop(stacks, BASE, n_synth=8, seed=1)
    if result.added != ["DarkRTS"] or result.unexplained():
        return False
    rec = result.profile.effects["DarkRTS"]
    return abs(np.log(rec["density"] / 0.005)) < 0.15 and abs(np.log(rec["median_e_per_s"] / 20.0)) < 0.08


NOISY_COL = {"NoisyCol": {"seed": 105, "density": 0.03, "log_std": 0.2, "k": [K], "median_dn": [6.0]}}


def noisy_columns_named(seed):
    """A bias stack whose noisy columns (3 % of the sensor columns, 6 DN more white noise at
    each pixel against 3.4 DN of read noise): NoisyCol named (not ReadMap, Noisy or ColRTS),
    nothing left, its density within one column of the pattern's and its median within 0.15 in
    log of the pattern's (its 5 columns' median is 5.2 DN; the estimate's over 20 seeds,
    300-338 even, 5.1-5.7)."""
    from rawaug.statistics import column_pixel_noise, noisy_columns

    result = run_frame_loop([measured_stack(NOISY_COL, seed=seed, n=8, size=96)], BASE, n_synth=8, seed=1)
    if result.added != ["NoisyCol"] or result.unexplained():
        return False
    rec = result.profile.effects["NoisyCol"]
    # the pattern's columns, and their noise, where they stand far out: 10 x the noise, 40 frames
    loud = measured_stack({"NoisyCol": {**NOISY_COL["NoisyCol"], "median_dn": [60.0]}}, seed=seed, n=40, size=96).frames_dn
    where, med = noisy_columns(loud)
    seeded = float(np.median(np.sqrt((column_pixel_noise(loud)[where] - med) * 39 / stats.chi2.median(39)))) / 10.0
    return abs(rec["density"] - where.mean()) <= 1 / 192 + 1e-12 and abs(np.log(rec["median_dn"][0] / seeded)) < 0.15


TAPS = {"TapBlack": {"col_edges": [101], "row_edges": [70], "frame_h": 96, "frame_w": 96, "k": [K], "sigma_dn": [0.8]}}


def readout_taps_named(seed, spread=None):
    """A bias stack read in four quadrants, each with a black level of its own that moves by
    0.8 DN rms from frame to frame (edges at an odd sensor column and an even sensor row):
    TapBlack named (not BLE, LowFreq or FPN), nothing left, the column edge exact, the row
    edge within one row (the rows carry the model's row noise, 0.55 DN per row: in some seeds
    one row's place is a toss-up), and the offset within 0.5 in log of 0.8 DN. Over 20 seeds,
    300-338 even: 19 named (at 314 the row edge was not found), the offset's log error with an
    sd of 0.21, at most 0.42 (8 frames of 4 taps hold 21 degrees of freedom: 0.15 from them
    alone). ``spread``: a list the estimate's log is appended to."""
    result = run_frame_loop([measured_stack(TAPS, seed=seed, n=8, size=96)], BASE, n_synth=8, seed=1)
    if result.added != ["TapBlack"] or result.unexplained():
        return False
    rec = result.profile.effects["TapBlack"]
    if spread is not None:
        spread.append(float(np.log(rec["sigma_dn"][0] / 0.8)))
    return (rec["col_edges"] == [101] and len(rec["row_edges"]) == 1 and abs(rec["row_edges"][0] - 70) <= 1
            and abs(np.log(rec["sigma_dn"][0] / 0.8)) < 0.5)


CHARGE = {"ChargeShare": {"share_x": 0.03, "share_y": 0.03}}


def flat_stack(effects, level_dn, seed, bias, n=4, size=96):
    """A flat stack at ``level_dn`` (DN) from the base profile plus ``effects``, taking its
    offsets from ``bias`` (as a manifest's flats do)."""
    prof = BASE
    for token, params in effects.items():
        prof = prof.with_effect(token, params)
    template = FrameStack(np.full((n, 4, size, size), level_dn + 0.5), K, kind="flat", level_dn=level_dn,
                          offsets_dn=[0.5] * 4)
    return FrameStack(synthesize(prof, template, 1, seed)[0].astype(np.float64), K, kind="flat", level_dn=level_dn,
                      label=f"flat {level_dn:g} DN", offsets_of=bias)


def charge_sharing_named(seed):
    """A bias stack and flats at two levels of a camera whose pixels share 3 % of their charge
    with each raw neighbour: ChargeShare named (not Xtalk: the bias frames do not show it),
    nothing left, and each share within 0.01 (the lag covariances of 2 x 4 frames of 96 x 96)."""
    bias = measured_stack(CHARGE, seed=seed, n=6, size=96, label="bias")
    stacks = [bias] + [flat_stack(CHARGE, level, seed + 1 + i, bias) for i, level in enumerate((800.0, 3000.0))]
    result = run_frame_loop(stacks, BASE, n_synth=8, seed=1)
    if result.added != ["ChargeShare"] or result.unexplained():
        return False
    rec = result.profile.effects["ChargeShare"]
    return abs(rec["share_x"] - 0.03) < 0.01 and abs(rec["share_y"] - 0.03) < 0.01


SPLIT_GAIN = {"TapGain": {"col_edges": [121], "row_edges": [], "frame_h": 96, "frame_w": 96, "gain": [[0.993, 1.007]]}}


def tap_gains_named(seed):
    """A bias stack and flats at two levels of a camera read in two taps (an edge at an odd
    sensor column) whose gains differ by 1.4 %: TapGain named (not ColGain, LowFreq or
    GainGrid), nothing left, the edge exact and the log gain ratio within 0.0025 of the
    truth (5 standard errors: shot noise of 4 flats of 3000 e- over 192 rows, 0.7 of it in a
    32-line step). Over 20 seeds, 300-338 even: 20 named (2026-11-28)."""
    bias = measured_stack({}, seed=seed, n=6, size=96, label="bias")
    stacks = [bias] + [flat_stack(SPLIT_GAIN, level, seed + 1 + i, bias) for i, level in enumerate((800.0, 3000.0))]
    result = run_frame_loop(stacks, BASE, n_synth=8, seed=1)
    if result.added != ["TapGain"] or result.unexplained():
        return False
    rec = result.profile.effects["TapGain"]
    ratio = rec["gain"][0][1] / rec["gain"][0][0]
    return rec["col_edges"] == [121] and not rec["row_edges"] and abs(math.log(ratio) - math.log(1.007 / 0.993)) < 0.0025


WEAK_COLUMNS = {"LineGain": {"seed": 31, "row_density": 0.0, "col_density": 0.03, "median": 0.08, "log_std": 0.0, "negative": 1.0}}


def gain_lines_named(seed):
    """A bias stack and flats at two levels of a camera whose weak column amplifiers (3 % of the
    sensor columns) convert with 8 % less gain: LineGain named (not Lines, ColGain or GainGrid),
    nothing left, its column density that of the sensor's pattern (the dim columns of a
    noiseless render of it, all resolved at 3000 e-) and its median within 0.005 of 0.08.
    Over 20 seeds, 300-338 even: 20 named (2026-11-28)."""
    bias = measured_stack({}, seed=seed, n=6, size=96, label="bias")
    stacks = [bias] + [flat_stack(WEAK_COLUMNS, level, seed + 1 + i, bias) for i, level in enumerate((800.0, 3000.0))]
    result = run_frame_loop(stacks, BASE, n_synth=8, seed=1)
    if result.added != ["LineGain"] or result.unexplained():
        return False
    rec = result.profile.effects["LineGain"]
    template = FrameStack(np.full((1, 4, 96, 96), 1000.5), K, kind="flat", level_dn=1000.0, offsets_dn=[0.5] * 4)
    clean = BASE.with_effect("LineGain", WEAK_COLUMNS["LineGain"])
    render = synthesize(clean, template, 1, seed, model="G", offsets=[0.0] * 4)[0][0]  # read noise only: 2 DN of 1000
    cols = np.concatenate([render[c].mean(axis=0) for c in (0, 1)]) / 1000.0  # both column sets of the R/G1 rows
    weak = int((cols < 0.96).sum())
    return abs(rec["col_density"] - weak / 192) < 1e-9 and rec["row_density"] == 0.0 and abs(rec["median"] - 0.08) < 0.005


WARMING = {"Dark": {"seed": 19, "k": [K], "rate_e_per_s": [4.0], "dsnu": [0.0]}, "DarkDrift": {"sigma": 0.15, "rho": 0.5}}


def dark_drift_named(seed):
    """A bias stack and two dark stacks (5 s, 8 frames each) of a camera with a dark current of
    4 e-/s whose factor walks from frame to frame (sigma 0.15, rho 0.5): Dark and DarkDrift
    named (not BlackDrift: the bias frames do not move), nothing left, and the drift's sigma
    within a factor 2 (16 frames of rho 0.5 hold about 5 independent factors: 2.3 standard
    errors of the log). Over 20 seeds, 300-338 even: 19 (2026-11-28; seed 312 named, its
    sigma 0.32 with rho at its limit 1 - 1/8)."""
    bias = measured_stack({}, seed=seed, n=6, size=96, label="bias")
    darks = [measured_stack(WARMING, seed=seed + 1 + i, n=8, size=96, label=f"dark 5 s #{i}", exposure_s=5.0) for i in range(2)]
    result = run_frame_loop([bias, *darks], BASE, n_synth=8, seed=1)
    if sorted(result.added) != ["Dark", "DarkDrift"] or result.unexplained():
        return False
    return abs(math.log(result.profile.effects["DarkDrift"]["sigma"] / 0.15)) < math.log(2.0)


DNL_CODES = {"DNL": {"period": 8, "threshold_dn": [0.0, 0.0, 0.0, 0.0, -0.4, 0.4, 0.0, 0.0]}}


def dnl_named(seed):
    """A bias stack of whole codes (6 frames of 4 x 96 x 96, read noise of the base model at
    K 1) from an ADC whose every code 8k + 4 is 1.8 codes wide: DNL named (not CodeMap: no
    code is missing), nothing left, the period 8 and the levels within 0.05 DN. Over 20
    seeds, 300-338 even: 20 (2026-11-28)."""
    stack = measured_stack(DNL_CODES, seed=seed, n=6, size=96, label="bias")
    stack = FrameStack(np.rint(stack.frames_dn), K, label="bias")  # the camera's whole codes (float32 error off)
    result = run_frame_loop([stack], BASE, n_synth=8, seed=1)
    if result.added != ["DNL"] or result.unexplained():
        return False
    rec = result.profile.effects["DNL"]
    return rec["period"] == 8 and np.allclose(rec["threshold_dn"], DNL_CODES["DNL"]["threshold_dn"], atol=0.05)


# each check: seed -> the effect named, nothing left and its estimate within bounds
NAMED = {"DarkHot": dark_hot_named, "DarkCol": lambda seed: dark_only_named("DarkCol", seed),
         "DarkRow": lambda seed: dark_only_named("DarkRow", seed),
         "DarkOffset": lambda seed: dark_only_named("DarkOffset", seed),
         "DarkNoise": lambda seed: dark_only_named("DarkNoise", seed), "Spikes": spikes_named, "ColRTS": telegraph_columns_named, "RowRTS": telegraph_rows_named,
         "Noisy": noisy_named, "DarkRTS": dark_telegraph_named, "NoisyCol": noisy_columns_named,
         "TapBlack": readout_taps_named, "ChargeShare": charge_sharing_named, "TapGain": tap_gains_named,
         "LineGain": gain_lines_named, "DarkDrift": dark_drift_named, "DNL": dnl_named}


# DarkRow is DarkCol's code along the other axis: in the default run its round trip is checked
# (tests/test_effects_loop.py), its naming with the slow rates below; so are DarkDrift's and
# DNL's and DarkNoise's (tests/test_dark_drift.py, tests/test_adc_dnl.py, tests/test_dark_noise.py), and those of the effects after them
# (round trips in tests/test_effects_loop.py and tests/test_charge_sharing.py; RowRTS's
# estimator is ColRTS's), to keep the default run near 5 minutes
SLOW_NAMED = ("DarkRow", "DarkDrift", "DNL", "DarkNoise", "DarkRTS", "NoisyCol", "LineGain", "TapBlack", "TapGain", "ChargeShare", "RowRTS")


@pytest.mark.parametrize("token", [pytest.param(t, marks=pytest.mark.slow) if t in SLOW_NAMED else t for t in NAMED])
def test_loop_names_the_effect_and_estimates_it(token):
    assert NAMED[token](300)


@pytest.mark.slow
@pytest.mark.parametrize("token", list(NAMED))
def test_named_effects_rate_over_seeds(token):
    successes = sum(NAMED[token](seed) for seed in range(300, 340, 2))
    print(f"{token}: {successes} of 20 seeds")  # shown with -rA: the count, not only the bound
    assert successes >= 19, f"{token}: {successes} of 20 seeds"


def test_the_written_profile_carries_offsets_fitted_with_a_clip():
    # planted: offsets 0.5 DN and a clip at -2 DN, which raises the measured mean by ~0.6 DN;
    # the offsets are fitted with the added clip, so the profile gets 0.5 back, not the mean
    stack = measured_stack(CLIP, seed=201)
    assert stack.frames_dn.mean() > 1.0
    result = run_frame_loop([stack], BASE, n_synth=10, seed=1)
    assert result.added == ["Clip"]
    fitted = np.asarray(result.colour_bias[K])
    assert np.all(np.abs(fitted - 0.5) < 0.1), fitted  # pilot noise: ~0.03 DN per channel
    np.testing.assert_allclose(result.profile.color_bias.nearest(K), fitted)


def test_dark_frames_take_the_offsets_fitted_with_a_clip():
    # a camera that clips at -2 DN and has no dark current: its dark frames hold nothing the
    # bias frames do not. Synthesized with the bias frames' measured means as offsets (0.6 DN
    # too high: the clip raised them), the dark stack kept mean_dn (z ~ -42) and clip_low
    # (z ~ 16) unexplained at seeds 300 and 310; with the offsets fitted with the clip, nothing
    bias = measured_stack(CLIP, seed=300, n=6, size=96, label="bias")
    dark = measured_stack(CLIP, seed=301, n=6, size=96, label="dark 5 s", exposure_s=5.0)
    dark = FrameStack(dark.frames_dn, K, kind="dark", exposure_s=5.0, label="dark 5 s", offsets_of=bias)
    result = run_frame_loop([bias, dark], BASE, n_synth=8, seed=1)
    assert result.added == ["Clip"]
    assert not result.unexplained(), result.unexplained()
    with pytest.raises(ValueError, match="offsets_of must be a bias FrameStack"):
        FrameStack(dark.frames_dn, K, kind="dark", exposure_s=5.0, offsets_of=dark)


def test_a_read_noise_refit_moves_the_dark_stack_to_the_refitted_bias_stack():
    from rawaug.loop.refit import apply_read_noise_factors

    bias = measured_stack({}, seed=5, n=2, size=32, label="bias")
    dark = FrameStack(bias.frames_dn, K, kind="dark", exposure_s=1.0, label="dark", offsets_of=bias)
    (new_bias, new_dark), _ = apply_read_noise_factors([bias, dark], BASE, {"bias": 0.8})
    assert new_bias is not bias and new_dark.offsets_of is new_bias
    assert new_dark.offsets_of.base["sigma_g"] == new_bias.base["sigma_g"] != bias.base.get("sigma_g")


def test_the_row_noise_refit_reads_the_rows_within_readout_taps():
    """A black level per top and bottom half, new in every frame, is the taps' variance, not
    row noise: within the taps the rows vary as a camera's without taps do (the re-fit that
    follows TapBlack compares those), while over the whole frame the step dominates."""
    from rawaug.loop.refit import _row_variance

    taps = {"TapBlack": {"col_edges": [], "row_edges": [64], "frame_h": 64, "frame_w": 64, "k": [K], "sigma_dn": [3.0]}}
    stepped = measured_stack(taps, seed=41, n=8, size=64).frames_dn
    plain = measured_stack({}, seed=42, n=8, size=64).frames_dn
    assert _row_variance(stepped) > 3 * _row_variance(plain)
    # two independent variance estimates of 8 frames x 126 degrees of freedom: log ratio sd sqrt(2 / 1008 x 2)
    ratio = _row_variance(stepped, [64]) / _row_variance(plain, [64])
    assert abs(math.log(ratio)) < 5 * math.sqrt(4 / 1008), ratio


def test_taking_an_effect_out_undoes_the_refit_it_was_judged_with():
    """Backward elimination takes an added effect out with the base stage's re-fit it was
    judged with undone: the row and read noise come back to what they were, stacks and profile."""
    from rawaug.distributions import tukey_lambda_variance
    from rawaug.loop.frames_loop import Step, _without
    from rawaug.loop.refit import apply_read_noise_factors, apply_row_noise_factors, shape_for_variance
    from rawaug.loop.diagnose import synthesis_fixed

    bias = measured_stack({}, seed=5, n=2, size=32, label="bias")
    stacks, prof = [bias], BASE.with_effect("Band", BAND["Band"])
    stacks, prof = apply_row_noise_factors(stacks, prof, {"bias": 0.6})
    stacks, prof = apply_read_noise_factors(stacks, prof.with_effect("Xtalk", XTALK["Xtalk"]), {"bias": 0.9})
    refits = [{"after": "Band", "what": "row noise", "factors": {"bias": 0.6}, "kept": True},
              {"after": "Xtalk", "what": "read noise", "factors": {"bias": 0.9}, "kept": True}]
    step = Step("Band", BAND["Band"], True, {}, "bias", 1.0, 0.1, 0.0, {}, {})
    reduced, out = _without(step, prof, stacks, refits, None)
    assert set(reduced.effects) == {"Xtalk"}
    for k in (0.5, K, 4.0):  # row noise as calibrated, read noise still re-fitted after Xtalk
        assert reduced.row_scale.median(k) == pytest.approx(BASE.row_scale.median(k), rel=1e-12)
        lam, new = float(BASE.tukey_shape.nearest(k)), float(reduced.tukey_shape.nearest(k))
        assert new == pytest.approx(shape_for_variance(lam, 0.9), abs=1e-9)
        variance = lambda p, x: p.tukey_scale.median(k) ** 2 * tukey_lambda_variance(x)  # noqa: E731
        # the scale relation is a line through the factors at the table's K, which the lambdas make differ a little
        assert variance(reduced, new) == pytest.approx(0.81 * variance(BASE, lam), rel=0.05)
    fixed, calibrated = synthesis_fixed(reduced, out[0]), synthesis_fixed(BASE, bias)
    assert fixed["sigma_r"] == pytest.approx(calibrated["sigma_r"], rel=1e-12)
    assert fixed["lambda"] == pytest.approx(shape_for_variance(calibrated["lambda"], 0.9), abs=1e-9)
    assert fixed["sigma_tl"] ** 2 * tukey_lambda_variance(fixed["lambda"]) == pytest.approx(
        0.81 * calibrated["sigma_tl"] ** 2 * tukey_lambda_variance(calibrated["lambda"]), rel=1e-9)
    with pytest.raises(KeyError, match="has no effect 'Band'"):
        reduced.without_effect("Band")


def test_a_defect_line_counts_once_as_a_defect_line():
    clean = measured_stack({}, seed=7, n=2).frames_dn
    defects = clean.copy()
    # a hot column (with its noise: a stuck pixel counts as a dead one, also in a pair)
    defects[:, 0, :, 50] = np.where(np.arange(clean.shape[2]) % 2 == 0, 3000.0 + clean[:, 0, :, 50], clean[:, 0, :, 50])
    defects[:, 2, 40, :] = -clean.mean()  # dead row (code 0)
    a, b = frame_statistics(clean), frame_statistics(defects)
    assert a["defect_lines"] == 0.0 and b["defect_lines"] > 0.0
    # every other statistic reads the repaired frames: the defects do not show there
    for name in ("pixel_std", "tail_mass", "hot_fraction", "ppcc_r2", "row_excess", "col_excess", "psd2d_lowfreq",
                 "col_lowfreq", "row_lowfreq", "mean_dn", "clip_low", "fixed_std"):
        assert abs(b[name] - a[name]) <= 0.05 * abs(a[name]) + 1e-3, (name, a[name], b[name])


def test_statistics_reject_bad_input():
    with pytest.raises(ValueError, match=r"\(N, 4, h, w\)"):
        frame_statistics(np.zeros((4, 16, 16)))
    with pytest.raises(ValueError, match="kind"):
        frame_statistics(np.zeros((2, 4, 16, 16)), kind="sky")
    with pytest.raises(ValueError, match="positive"):
        FrameStack(np.zeros((2, 4, 16, 16)), k=-1.0)


def test_relation_loop_finds_a_planted_jump_and_floor():
    rng = np.random.default_rng(0)
    k = np.geomspace(0.05, 20, 24)
    line = np.where(k < 2.0, 3.0 * k**0.9, 1.2 * k**0.9)
    sigma = np.sqrt(line**2 + 0.7**2) * np.exp(0.02 * rng.standard_normal(k.size))
    fit, steps = relation_loop(k, sigma)
    assert {s["structure"] for s in steps} == {"jump", "floor"}
    assert 1.5 < fit.break_k < 2.5 and abs(fit.relation.floor_dn - 0.7) < 0.1
    assert steps[-1]["error_after"] < 0.5 * steps[0]["error_before"]
    # a clean single line gets no structure
    _, none = relation_loop(k, 2.0 * k**0.8 * np.exp(0.02 * rng.standard_normal(k.size)))
    assert none == []


def test_relation_loop_finds_two_regime_changes_in_20_of_20_seeds():
    # a conversion-gain switch at K 0.2 (read noise x 0.6), then digital push above K 5 (slope 1)
    k = np.geomspace(0.05, 20, 20)
    analog = np.where(k < 0.2, 1.5 * (k / 0.2) ** 0.5, 0.9 * (k / 0.2) ** 0.5)
    true = np.where(k < 5.0, analog, 0.9 * 25**0.5 * (k / 5.0))
    found = 0
    for seed in range(20):
        sigma = true * np.exp(0.03 * np.random.default_rng(seed).standard_normal(k.size))
        fit, steps = relation_loop(k, sigma)
        breaks = sorted(fit.breaks_k)  # within one K step (x 1.37) of the truth
        found += (len(breaks) == 2 and 0.12 < breaks[0] < 0.3 and 3.0 < breaks[1] < 7.0
                  and steps[-1]["error_after"] < 0.5 * steps[0]["error_before"])
    assert found == 20, found


@pytest.mark.slow
def test_relation_loop_false_structure_rate_on_pure_lines():
    # measured: 0 / 1 / 3 / 3 of 100 pure power laws (5 % scatter in sigma and in K) at 8 / 12 /
    # 24 / 40 ISOs get a structure; 8 or more of 100 at a true rate of 3 % has probability 0.01
    for n in (8, 12, 24, 40):
        added = 0
        for seed in range(100):
            rng = np.random.default_rng(seed)
            k = np.geomspace(0.05, 20, n) * np.exp(0.05 * rng.standard_normal(n))
            added += bool(relation_loop(k, 2.0 * k**0.8 * np.exp(0.05 * rng.standard_normal(n)))[1])
        assert added < 8, (n, added)


def test_relation_fit_rejects_bad_values():
    with pytest.raises(ValueError, match="positive"):
        fit_structure([1.0, 2.0, 3.0], [1.0, -1.0, 2.0])


def test_sony_table_regime_change_and_floor(tmp_path):
    out, rep = tmp_path / "p.yaml", tmp_path / "rep"
    assert main(["loop", str(DATA / "PMN_noise_params_extracted.json"), "--camera", "SonyA7S2", "--cfa", "RGGB",
                  "--out", str(out), "--report", str(rep)]) == 0
    report = json.loads((rep / "report.json").read_text())
    tl = [s for s in report["steps"] if s["relation"] == "sigma_tl"]
    assert {s["structure"] for s in tl} == {"jump", "floor"} and tl[0]["structure"] == "jump"
    assert 1.53 < tl[0]["break_k"] < 1.92  # between ISO 1600 and ISO 2000
    assert any(1.53 < b < 1.92 for b in tl[-1]["breaks_k"])
    assert tl[-1]["error_after"] < 0.5 * tl[0]["error_before"]
    prof = NoiseProfile.load(out)
    assert len(prof.tukey_scale.segments) == len(tl[-1]["breaks_k"]) + 1 and prof.tukey_scale.floor_dn > 0
    assert (rep / "report.md").read_text().startswith("# rawaug loop")


@pytest.mark.parametrize("iso,k,found", [(100, 0.1366021, ["BLE", "BlackDrift"]), (6400, 8.7425333, ["BLE"])])
def test_imx686_per_frame_black_level_error_and_drift(iso, k, found):
    # real per-frame fits: at ISO 100 the frame means are alike from one frame to the next (lag-1
    # autocorrelation 0.64, z 9.4 against BLE), at ISO 6400 not (0.18, z 3). The same in each of
    # 10 synthesis seeds (measured: 10 of 10 each).
    table = read_frame_table(DATA / f"IMX686_iso{iso}_per_frame_bias_fits.csv")
    for seed in range(10):
        result = frame_table_loop(table, 3472 // 2, 4624 // 2, k, seed=seed)
        assert [s["effect"] for s in result["steps"] if s["accepted"]] == found
        assert all(s["error_after"] < 0.5 * s["error_before"] for s in result["steps"])
        assert not any(r["significant"] and r["statistic"].startswith("frame_mean") for r in result["after"])
    if "BlackDrift" in found:
        drift = result["effects"]["BlackDrift"]
        assert 0.5 < drift["rho"][0] < 0.85 and drift["sigma_dn"][0] > 0
        assert result["effects"]["BLE"]["sigma_dn"] == [0.0]  # the drift is the common part
    else:
        assert result["effects"]["BLE"]["sigma_dn"][0] > 0


def test_cli_frame_table_writes_the_effects_found_into_the_profile(tmp_path):
    table = DATA / "IMX686_iso100_per_frame_bias_fits.csv"
    out = tmp_path / "imx686.yaml"
    code = main(["loop", str(table), "--k", "0.1366021", "--frame-size", "3472", "4624", "--profile", "SonyA7S2",
                 "--out", str(out), "--report", str(tmp_path / "report")])
    assert code == 0
    effects = NoiseProfile.load(out).effects
    assert set(effects) == {"BLE", "BlackDrift"} and 0.5 < effects["BlackDrift"]["rho"][0] < 0.85
    assert "BlackDrift" in (tmp_path / "report" / "report.md").read_text()


def test_cli_frame_table_needs_gain(tmp_path, capsys):
    code = main(["loop", str(DATA / "IMX686_iso100_per_frame_bias_fits.csv"), "--report", str(tmp_path)])
    assert code == 2 and "--k" in capsys.readouterr().err


@pytest.mark.parametrize("lam", [0.05, -0.05, -0.1])
def test_read_noise_refit_keeps_the_tail(lam):
    """A re-fit that gives a near-Gaussian effect part of the read noise's variance moves the
    Tukey lambda so that the sum keeps the calibrated tail (values beyond 5 robust sigmas);
    keeping lambda thins it. By sampling: 4M values, the counts' Poisson bounds (4 sd)."""
    from scipy import stats

    from rawaug.distributions import tukey_lambda_variance
    from rawaug.loop.refit import shape_for_variance

    rng, n, f = np.random.default_rng(11), 4_000_000, 0.85

    def beyond(x):
        med = np.median(x)
        return int(np.sum(np.abs(x - med) > 5 * 1.4826 * np.median(np.abs(x - med))))

    def read(x, share):
        return np.sqrt(share / tukey_lambda_variance(x)) * stats.tukeylambda.rvs(x, size=n, random_state=rng)

    calibrated = beyond(read(lam, 1.0))
    gauss = lambda: rng.normal(0.0, np.sqrt(1 - f**2), n)  # noqa: E731
    new = shape_for_variance(lam, f)
    refitted, kept = beyond(read(new, f**2) + gauss()), beyond(read(lam, f**2) + gauss())
    bound = 4 * np.sqrt(calibrated + refitted)
    assert abs(refitted - calibrated) < bound, (lam, new, calibrated, refitted)
    assert calibrated - kept > 4 * np.sqrt(calibrated + kept), (calibrated, kept)  # what the re-fit corrects
    assert shape_for_variance(new, 1 / f) == pytest.approx(lam, abs=2e-3)  # undone by the inverse factor


def test_a_subset_of_stacks_is_diagnosed_as_in_the_whole_battery():
    """A trial is screened on its evidence stack alone: each stack's syntheses are seeded by
    its place among all stacks, and a dark takes its bias stack's fitted offsets, so the subset
    gives that stack the residuals the whole battery would (bit for bit), without the bias stack."""
    import dataclasses

    from rawaug.loop.frames_loop import diagnose_stacks

    bias = measured_stack({}, seed=3, n=3, size=32, label="bias")
    other = measured_stack({}, seed=4, n=3, size=32, label="other bias")
    dark = dataclasses.replace(measured_stack({}, seed=5, n=3, size=32, label="dark", exposure_s=2.0),
                               offsets_dn=None, offsets_of=bias)
    stacks = [other, bias, dark]
    prof = BASE.with_effect(*next(iter(CLIP.items())))  # an effect: the bias offsets are fitted with it
    labels = [s.label for s in stacks]
    whole = diagnose_stacks(prof, labels, stacks, 77, n_synth=3)
    for stack in (dark, bias):  # the dark alone: its bias stack's offsets fitted as in the whole battery
        part = diagnose_stacks(prof, labels, [stack], 77, n_synth=3)
        assert [r.to_dict() for r in part[stack.label][0]] == [r.to_dict() for r in whole[stack.label][0]]
        assert np.array_equal(part[stack.label][1], whole[stack.label][1])
    shifted = diagnose_stacks(prof, ["x"] + labels, [dark], 77, n_synth=3)  # another place: other syntheses
    assert not np.array_equal(shifted["dark"][1], whole["dark"][1])


def test_a_histogram_curve_is_compared_by_its_tails():
    """The curve behind a tail statistic: a sparse tail (2 values expected per bin, 30 bins,
    as impulses leave) measured once, against the model that has it and one that has none.
    Compared by cumulative tails, the model with the tail is the closer one in every one of
    200 draws; bin by bin, in 161 of them (Poisson noise made it the farther one in the rest)."""
    from rawaug.loop.signatures import distance

    n, rng = 100_000, np.random.default_rng(5)
    core = np.array([0.1, 0.4, 0.4, 0.1]) * n
    expected = np.concatenate([core, np.full(30, 2.0)])
    without = np.concatenate([core, np.zeros(30)])
    closer = {"tails": 0, "bins": 0}
    for _ in range(200):
        measured = rng.poisson(expected).astype(np.float64)
        sig = {"kind": "pixel_histogram", "log_y": True, "floor": 1 / n, "measured": measured / n,
               "before": without / n, "after": expected / n}
        closer["tails"] += distance(sig, "after") < distance(sig, "before")
        closer["bins"] += distance({**sig, "kind": "code_histogram"}, "after") < distance({**sig, "kind": "code_histogram"}, "before")
    assert closer["tails"] == 200, closer
    assert closer["bins"] < 200, closer  # what the bin-by-bin comparison (codes keep it) would have said


def test_illumination_shape_recovers_the_light_and_leaves_uniform_flats_alone():
    """A flat is synthesized under its light's measured shape: a smooth light is recovered to
    the noise of a 28-term fit; under uniform light the James-Stein shrinkage takes out what
    the fit holds of the noise (40 seeds)."""
    from rawaug.loop.illumination import TERMS, illumination_shape

    h, w = 96, 128
    fit_noise = math.sqrt((TERMS - 1) / (h * w)) * 0.01  # rms of an unshrunk fit's noise at 1 % pixel noise
    y, x = np.mgrid[0:h, 0:w] / np.array([h - 1, w - 1])[:, None, None] - 0.5
    light = (1.0 - 0.5 * (x**2 + y**2)) * (1.05 - 0.1 * (x + 0.5))  # vignetting and a lamp's gradient (degree 3)
    shape = illumination_shape(1000.0 * light[None] * (1.0 + 0.01 * np.random.default_rng(1).normal(size=(4, h, w))))
    truth = light / light.mean()
    assert np.sqrt(np.mean((shape - truth) ** 2)) < 1.5 * fit_noise and np.abs(shape - truth).max() < 6 * fit_noise
    assert shape.mean(axis=(1, 2)) == pytest.approx(np.ones(4))
    uniform = [np.sqrt(np.mean((illumination_shape(1000.0 * (1.0 + 0.01 * np.random.default_rng(s).normal(size=(4, h, w))))
                                - 1.0) ** 2)) for s in range(40)]
    # the shrunk fit keeps a fraction of the noise an unshrunk one would (0.14 on average, 0.40 at most, measured)
    assert np.mean(uniform) < 0.3 * fit_noise and max(uniform) < fit_noise, (np.mean(uniform) / fit_noise, max(uniform) / fit_noise)
    assert np.array_equal(illumination_shape(np.ones((4, 8, 8))), np.ones((4, 8, 8)))  # too few pixels: no shape
    with pytest.raises(ValueError, match=r"mean frame \(4, h, w\)"):
        illumination_shape(np.ones((3, 32, 32)))


def test_read_shape_refit_lightens_a_tail_the_model_overshoots_and_never_adds_one():
    """Where the model's read noise has heavier tails than the frames (tail_mass z < -6), the
    re-fit takes a lighter Tukey lambda at the same variance; a model whose tails are lighter
    than the frames' is left alone (a missing tail is for an effect to explain)."""
    from rawaug.distributions import tukey_lambda_variance as var
    from rawaug.loop.diagnose import diagnose, synthesis_fixed
    from rawaug.loop.refit import apply_read_shapes, read_shape_updates

    def base(lam):  # read noise of 2 DN rms whatever the shape
        return {"lambda": lam, "sigma_tl": 2.0 / math.sqrt(var(lam))}

    template = FrameStack(np.zeros((8, 4, 96, 96)), K, base=base(0.05))
    frames = np.rint(synthesize(BASE, template, 1, 5)[0].astype(np.float64))  # whole codes: a raw file's
    heavy = FrameStack(frames, K, base=base(-0.15), label="bias")
    res, _ = diagnose(heavy, BASE, n_synth=8, seed=1)
    assert next(r for r in res if r.statistic == "tail_mass").z < -6
    lam = read_shape_updates([heavy], {"bias": (res, None)}, BASE)["bias"]
    assert 0.0 < lam < 0.11, lam  # the truth: 0.05
    (fitted,), prof = apply_read_shapes([heavy], BASE, {"bias": lam})
    fixed = synthesis_fixed(prof, fitted)
    assert fixed["lambda"] == lam and fixed["sigma_tl"] ** 2 * var(lam) == pytest.approx(4.0)
    assert prof.tukey_shape.nearest(K) == lam
    res, _ = diagnose(fitted, prof, n_synth=8, seed=1)
    assert not next(r for r in res if r.statistic == "tail_mass").significant
    light = FrameStack(frames, K, base=base(0.13), label="bias")  # lighter than the frames: no re-fit
    res, _ = diagnose(light, BASE, n_synth=8, seed=1)
    assert next(r for r in res if r.statistic == "tail_mass").z > 0
    assert read_shape_updates([light], {"bias": (res, None)}, BASE) == {}


@pytest.mark.slow  # 15 s: a whole loop run twice (twenty-second session: the default run near 5 minutes)
def test_a_battery_that_cannot_win_is_stopped_without_changing_the_outcome(monkeypatch):
    # three stacks of a camera with three undeclared effects: once one candidate is acceptable,
    # the others' batteries are diagnosed a stack at a time and stopped when their residual
    # errors so far pass the best's whole battery; what is added, and its parameters, are those
    # of the loop that judges every battery whole
    from rawaug.loop import frames_loop

    stacks = [measured_stack({**COL, **FPN, **HOT}, seed=seed, n=6, size=64, label=f"bias {seed}") for seed in (410, 411, 412)]
    monkeypatch.setattr(frames_loop, "BOUND_CHUNK", 10**6)  # never part-way: every battery whole
    whole = run_frame_loop(stacks, BASE, n_synth=6, seed=1)
    monkeypatch.setattr(frames_loop, "BOUND_CHUNK", 1)
    bounded = run_frame_loop(stacks, BASE, n_synth=6, seed=1)
    assert bounded.added == whole.added and bounded.profile.to_dict() == whole.profile.to_dict()
    stopped = [s for s in bounded.steps if s.note.startswith("not judged whole")]
    assert stopped, [s.note for s in bounded.steps]
    assert all(not s.battery_after for s in stopped)  # the part-way battery is not reported as a whole one
    assert not [s for s in whole.steps if s.note.startswith("not judged whole")]


def test_a_flat_is_synthesized_with_its_exposure_dark_signal_and_its_measured_level():
    """A flat of t seconds holds t seconds of dark signal: its synthesis carries the model's dark
    effects (their patterns too) and starts from the measured level less their mean, so the
    synthesized mean is the measured one."""
    k, t, level = 1.0, 2.0, 400.0
    dark = {"seed": 19, "k": [k], "rate_e_per_s": [10.0], "dsnu": [0.5]}
    camera = NoiseProfile.load("SonyA7S2").with_effect("Dark", dark)
    bias = FrameStack(np.zeros((4, 4, 64, 64)), k, offsets_dn=[0.0] * 4)
    flat = FrameStack(np.full((2, 4, 64, 64), level), k, kind="flat", level_dn=level, exposure_s=t, offsets_of=bias)
    synth = synthesize(camera, flat, 4, seed=3).astype(np.float64)
    # the mean of 131072 values per synthesis, each of variance ~ k (level) + read noise: 5 standard errors
    assert abs(synth.mean() - level) < 5 * math.sqrt((k * level + 20.0) / synth[0].size)
    # the dark current's DSNU (a log-normal map of mean 20 e-, relative spread 0.5) is in the mean map
    plain = synthesize(NoiseProfile.load("SonyA7S2"), flat, 4, seed=3).astype(np.float64)
    excess = synth.mean(axis=1).var(axis=(1, 2, 3)).mean() - plain.mean(axis=1).var(axis=(1, 2, 3)).mean()
    expected = (k * 10.0 * t * 0.5) ** 2  # the DSNU map's variance, 100 DN^2, plus its shot noise over 2 frames (10)
    assert 0.7 * expected < excess < 1.3 * expected + k * 10.0 * t


def test_a_fallback_is_kept_out_only_where_a_physical_effect_explains_its_evidence():
    # the rule behind fallbacks beside physical effects (frames_loop._explained): a fixed column
    # gain that repeats every 8 columns is halved on col_excess by ColGain, whose random gains
    # leave grid_excess; GainGrid is then tried in the same round, not after ColGain is in
    from rawaug.loop.diagnose import Residual
    from rawaug.loop.frames_loop import EXPLAIN_FACTOR, Step, _explained

    def res(statistic, rel, significant=True):
        return Residual(statistic, 1.0, 1.0 - rel, 0.01, 100.0 * rel, rel, significant, [], "")

    def trial(error_after, grid_rel, grid_significant=True, accepted=True):
        step = Step("ColGain", {}, accepted, {}, "flat", 1.0, error_after, 0.0, {}, {})
        return (step, None, {"flat": ([res("col_excess", error_after), res("grid_excess", grid_rel, grid_significant)], None)},
                None, {}, {})

    option = ("GainGrid", "flat", res("grid_excess", 0.9))
    assert not _explained(option, [trial(0.38, 0.9)])  # halves its own evidence, leaves the fallback's
    assert _explained(option, [trial(0.38, 0.9 * EXPLAIN_FACTOR)])  # halves both
    assert _explained(option, [trial(0.38, 0.9, grid_significant=False)])  # the fallback's evidence no longer significant
    assert not _explained(option, [trial(0.6, 0.1)])  # does not halve its own: fallbacks tried beside it
    assert not _explained(option, [trial(0.38, 0.1, accepted=False)])  # not acceptable
    assert not _explained(("GainGrid", "other", res("grid_excess", 0.9)), [trial(0.38, 0.1)])  # another stack's
    assert _explained(option, [trial(0.6, 0.1), trial(0.38, 0.2)])  # any explaining trial
