"""The fused engine's contract: one seed -> the same noise on every backend, validated
fixed parameters, defined gradients, torch.compile, and (on CUDA) no host sync, few
launches, CUDA-graph capture."""
import math
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.engine import backend
from rawaug.engine.backend import synthesize_op

triton = pytest.importorskip("triton")
CUDA = torch.cuda.is_available()

LOOP_EFFECTS = {
    "Col": {"seed": 7, "k": [1.0, 3.0], "sigma_dn": [0.5, 0.9], "fixed_dn": [0.7, 1.1]},
    "FPN": {"seed": 11, "k": [1.0, 3.0], "sigma_dn": [0.4, 0.6], "shading_dn": [[[0.0, 1.0], [2.0, -1.0]], [[1.0, 0.5], [0.0, 3.0]]],
            "frame_h": 48, "frame_w": 64},  # larger than the test inputs: a window per sample
    "Hot": {"seed": 13, "density": 0.01, "log_std": 0.5, "k": [1.0], "median_dn": [50.0], "tile_density": 0.02},  # hot 2x2 tiles too
    "DarkHot": {"seed": 61, "density": 0.03, "median_e_per_s": 5.0, "log_std": 0.5},  # before the Poisson draw
    "DarkRTS": {"seed": 97, "density": 0.05, "high": 0.4, "median_e_per_s": 6.0, "log_std": 0.4},  # ... in some frames
    "DarkCol": {"seed": 71, "density": 0.08, "median_e_per_s": 4.0, "log_std": 0.4},  # ... keyed by the sensor column
    "DarkRow": {"seed": 83, "density": 0.08, "median_e_per_s": 4.0, "log_std": 0.4},  # ... keyed by the sensor row
    "DarkOffset": {"k": [1.0, 3.0], "dn_per_s": [-0.6, 0.4]},  # signed, either gain
    "FrameGain": {"sigma": 0.02},
    "FrameNoise": {"k": [1.0, 3.0], "log_std": [0.3, 0.1]},
    "ColRTS": {"seed": 79, "density": 0.1, "high": 0.4, "log_std": 0.3, "k": [1.0, 3.0], "median_dn": [5.0, 9.0]},
    "RowRTS": {"seed": 109, "density": 0.1, "high": 0.6, "log_std": 0.3, "k": [1.0, 3.0], "median_dn": [4.0, 7.0]},
    "Spikes": {"density": 0.01, "density_per_s": 0.005, "log_std": 0.5, "negative": 0.25, "k": [1.0, 3.0], "median_dn": [40.0, 90.0]},
    "Clip": {"floor_dn": -3.0},
    "BLE": {"k": [1.0], "sigma_dn": [0.5], "channel_sigma_dn": [0.2]},
    "TapBlack": {"col_edges": [21, 60, 95], "row_edges": [30], "frame_h": 40, "frame_w": 64, "k": [1.0, 3.0],
                 "sigma_dn": [0.6, 1.1]},  # an odd sensor column; larger than the test inputs' 24 rows: a window per sample
    "BlackDrift": {"k": [1.0, 3.0], "sigma_dn": [0.7, 1.5], "rho": [0.8, 0.8]},
    "PRNU": {"seed": 17, "sigma": 0.02},
    "ChargeShare": {"share_x": 0.04, "share_y": 0.02, "share_d1": 0.03, "share_d2": 0.01},  # neighbours' shot draws (sides and diagonals), through this pixel's gains
    "ColGain": {"seed": 67, "sigma": 0.01, "frame": 0.004},
    "RowGain": {"seed": 71, "fixed": 0.01, "frame": 0.02},
    "LineGain": {"seed": 37, "row_density": 0.08, "col_density": 0.1, "median": 0.2, "log_std": 0.5, "negative": 0.5},
    "TapGain": {"col_edges": [33, 80], "row_edges": [17], "frame_h": 30, "frame_w": 48,
                "gain": [[0.98, 1.01, 1.03], [0.99, 1.02, 0.97]]},  # an odd sensor column; a window per sample on smaller inputs
    "Dark": {"seed": 19, "k": [1.0], "rate_e_per_s": [3.0], "dsnu": [0.2], "col_dsnu": [0.3], "row_dsnu": [0.25], "channel": [0.5, 1.0, 1.5, 1.0]},
    "DarkDrift": {"sigma": 0.3, "rho": 0.0},  # a factor per sample on every dark signal above
    "FixedMap": {"k": [1.0, 3.0], "map_dn": [[[0.0, 1.0, -2.0, 0.5, 3.0], [1.5, -1.0, 0.0, 2.0, -0.5], [0.2, 0.4, -0.6, 0.8, 1.0]],
                                          [[1.0, 0.0, 2.0, -0.5, 0.0], [0.0, 1.0, 0.0, -2.0, 0.5], [2.2, -0.4, 0.6, 0.0, 1.0]]],
                 "frame_h": 30, "frame_w": 50},  # a measured map: 3 x 5 grids beside FPN's and Glow's (a padded table), a window per sample
    "DarkNoise": {"k": [1.0], "rate_dn2_per_s": [2.0]},  # white noise growing with the exposure
    "Glow": {"k": [1.0, 3.0], "rate_e_per_s": [[[0.0, 1.0, 4.0, 9.0], [0.5, 2.0, 6.0, 20.0], [0.0, 0.0, 1.0, 3.0]],
                                               [[1.0, 1.0, 2.0, 5.0], [0.0, 2.0, 3.0, 10.0], [0.0, 1.0, 1.0, 2.0]]],
             "frame_h": 30, "frame_w": 50},  # a 3 x 4 grid beside FPN's 2 x 2 (a padded table), a window per sample
    "NonLin": {"k": [1.0, 3.0], "compression_per_dn": [3e-6, [-2e-6, 1e-6, -1e-6, 4e-6]]},  # one compression at one gain, per channel at the other
    "Trap": {"k": [1.0, 3.0], "trap_e": [12.0, 4.0]},  # traps of 12 and 4 electrons: a toe at low light
    "GainNoise": {"k": [1.0, 3.0], "sigma_rel": [0.03, 0.01]},  # a relative draw per pixel and frame on the signal
    "StuckBit": {"zero_code": [512, 509, 513, 510], "low_mask": 8, "high_mask": 2},  # bit 3 at 0, bit 1 at 1, blacks of their own
    "BankOffset": {"k": [1.0, 3.0], "col_period": 3, "col_dn": [[1.0, 0.0, -1.0], [0.5, 0.2, -0.7]], "row_period": 4,
                   "row_dn": [[0.3, -0.3, 0.1, -0.1], [0.0, 0.2, 0.0, -0.2]]},  # three column banks, four row banks
    "PixelGain": {"seed": 43, "density": 0.05, "median": 0.3, "log_std": 0.5, "negative": 0.6},  # dim and bright pixels
    "LowFreq": {"grid": [3, 4], "k": [1.0], "sigma_dn": [0.8], "frame_h": 12, "frame_w": 20},  # smaller: more cells
    "FixedField": {"seed": 29, "grid": [5, 7], "k": [1.0, 3.0], "sigma_dn": [0.6, 1.1], "frame_h": 12, "frame_w": 20},  # a sensor's own grid
    "Lines": {"seed": 23, "row_density": 0.05, "col_density": 0.08, "log_std": 0.5, "negative": 0.3, "k": [1.0, 3.0],
              "median_dn": [20.0, 40.0], "partial": 0.5, "to_end": 0.6, "cut_lo": 0.2, "cut_hi": 0.8},  # some over a part
    "RowFix": {"seed": 31, "k": [1.0, 3.0], "fixed_dn": [0.8, 1.4]},
    "RowCh": {"k": [1.0, 3.0], "sigma_dn": [0.7, 1.3]},
    "RowTail": {"k": [1.0, 3.0], "h": [0.15, 0.05]},  # heavy-tailed row draws
    "Band": {"k": [1.0, 3.0], "freq_per_row": [[0.0713, 0.31], [0.45]], "amplitude_dn": [[1.2, 0.4], [0.9]]},
    "ColBand": {"k": [1.0, 3.0], "freq_per_col": [[0.093], [0.5, 0.21]], "amplitude_dn": [[1.1], [0.7, 0.3]]},  # Nyquist too
    "DiagBand": {"k": [1.0, 3.0], "freq_per_col": [[0.11], [0.3, 0.05]], "freq_per_row": [[0.23], [-0.17, 0.41]],
                 "amplitude_dn": [[0.9], [0.5, 0.4]], "fixed_dn": [[0.6], [0.0, 0.3]]},
    "Xtalk": {"k": [1.0, 3.0], "tap_0_0_dn": [0.7, 1.0], "tap_0_1_dn": [0.5, -0.8], "tap_1_-1_dn": [0.3, 0.0],
              "tap_2_0_dn": [0.6, 0.4]},
    "ReadMap": {"k": [1.0, 3.0], "channel_dn": [[0.0, 2.0, 0.0, 0.5], [1.0, 0.0, 0.0, 0.0]],
                "row_block_dn": [[0.0] * 4 + [1.5] * 4, [0.3] * 8], "col_block_dn": [[0.0, 0.7] * 4, [0.0] * 7 + [2.0]],
                "frame_h": 40, "frame_w": 64, "col_block_edges": [0.19, 0.5, 0.77],
                "cell_dn": [[[0.0] * 8, [0.0, 0.0, 1.2] + [0.0] * 5] + [[0.0] * 8] * 6, [[0.4] * 8] * 8]},  # larger than the test inputs' 24 rows: a window per sample; measured column edges
    "Shared": {"k": [1.0, 3.0], "sigma_dn": [0.9, 1.6]},
    "Noisy": {"seed": 89, "density": 0.05, "log_std": 0.4, "k": [1.0, 3.0], "median_dn": [4.0, 7.0]},  # a new normal per frame
    "NoisyCol": {"seed": 103, "density": 0.1, "log_std": 0.3, "k": [1.0, 3.0], "median_dn": [3.0, 5.0]},  # ... keyed by the sensor column
    "RTS": {"seed": 43, "density": 0.05, "high": 0.3, "log_std": 0.4, "k": [1.0, 3.0], "median_dn": [15.0, 30.0]},
    "Dead": {"seed": 47, "density": 0.02, "levels_dn": [-3.0, 0.0, 2.5, 40.0, 400.0],
             "col_density": 0.1, "row_density": 0.1, "partial": 0.6, "to_end": 0.5, "cut_lo": 0.1, "cut_hi": 0.7},  # dead lines, some over a part
    "RowDrift": {"k": [1.0, 3.0], "octave_dn": [[0.0, 0.4, 0.0, 0.9, 1.3, 0.5, 0.2, 0.1], [0.2] * 8]},
    "ColDrift": {"k": [1.0, 3.0], "octave_dn": [[0.3, 0.0, 0.8, 0.0, 1.1, 0.6, 0.0, 0.2], [0.1] * 8]},  # flag word 1
    "RowRepeat": {"density": 0.1},  # flag word 1: rows read as the same colour's row above
    "BankNoise": {"k": [1.0, 3.0], "col_period": 3, "sigma_dn": [[1.5, 0.0, 0.4], [2.0, 0.5, 0.0]]},  # flag word 1
    "RowMap": {"k": [1.0, 3.0], "row_block_dn": [[0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5], [1.0] * 8], "frame_h": 40},  # flag word 1: a window per sample
    "DarkCluster": {"seed": 61, "density": 0.02, "size": 3, "median_e_per_s": 30.0, "log_std": 0.4},  # flag word 1: patches of hot pixels
    "RowBurst": {"density": 0.05, "k": [1.0, 3.0], "sigma_dn": [3.0, 5.0]},  # flag word 1: rows with extra noise in single frames
    "RowSpikes": {"density": 0.05, "log_std": 0.4, "negative": 0.3, "k": [1.0, 3.0], "median_dn": [20.0, 35.0]},  # flag word 1: rows offset in single frames
    "ColBurst": {"density": 0.05, "k": [1.0, 3.0], "sigma_dn": [3.0, 5.0]},  # flag word 1: columns with extra noise in single frames
    "FullWell": {"seed": 71, "well_e": 3000.0, "spread": 0.05},  # flag word 1: bright pixels clipped at their wells
    "ColGroup": {"width": 6, "start": 2, "k": [1.0, 3.0], "sigma_dn": [1.0, 2.0]},  # flag word 1: groups of columns offset per frame
    "BlackRamp": {"k": [1.0, 3.0], "row_dn": [0.05, 0.1], "col_dn": [0.03, 0.0]},  # flag word 1: a black ramp per frame
    "RowPair": {"k": [1.0, 3.0], "sigma_dn": [1.0, 2.0]},  # flag word 1: a row offset per Bayer row pair and frame
    "DarkRowNoise": {"k": [1.0, 3.0], "rate_dn2_per_s": [0.5, 1.0]},  # flag word 1: row noise growing with the exposure
    "RowTap": {"col_edges": [30, 61], "frame_h": 24, "frame_w": 40, "k": [1.0, 3.0], "sigma_dn": [1.0, 2.0]},  # flag word 1: row noise per column tap
    "ColTap": {"col_edges": [25, 52], "frame_h": 24, "frame_w": 40, "k": [1.0, 3.0],
               "sigma_dn": [[1.0, 0.0, 2.0], [0.5, 3.0, 0.0]]},  # flag word 1: column noise per column tap
    "DNL": {"period": 5, "threshold_dn": [0.0, 0.3, -0.2, 0.25, -0.35]},  # codes 0.4 to 1.45 wide, then the code map
    "CodeMap": {"k": [1.0], "lo_dn": [-5.0], "map_dn": [[-5.0, -5.0, -3.0, -2.0, -2.0, 0.0, 1.0, 1.0, 3.0, 4.0, 4.0]],
                "split_dn": [[0.5, 0.1, 0.5, 0.5, -0.2, 0.5, 0.5, 0.1, 0.5, 0.5, -0.2]],
                "period_dn": [3], "comb_from_dn": [-30.0]},  # its shifts (0, -1, 0) go on beyond the map, down to
                # -30 DN (below, codes rounded only); a missing code's inputs split between both neighbours
    "LineMap": {"k": [1.0, 3.0], "row_dn": (np.sin(np.arange(2 * 4 * 30).reshape(2, 4, 30) * 0.37) * 2.0).tolist(),
                "col_dn": (np.cos(np.arange(2 * 4 * 50).reshape(2, 4, 50) * 0.29) * 1.5).tolist(),
                "frame_h": 30, "frame_w": 50},  # a window of 24 x 40 inputs, repeated on 48 x 64 ones
    "GainGrid": {"period": [3, 2], "gain": [[[1.0, 1.0], [1.0, 0.5], [1.0, 1.2]], [[1.0] * 2] * 3, [[0.9, 1.1]] * 3,
                                             [[1.0, 1.0], [0.0, 1.0], [1.0, 1.0]]],
                 "frame_h": 30, "frame_w": 50, "conversion": 0.4},  # a phase per sample on the test inputs; a gain of 0 (a masked pixel); 0.4 of the log gain after shot noise
    "Masked": {"top": 3, "bottom": 2, "left": 1, "right": 4, "frame_h": 24, "frame_w": 40},  # flag word 1: the test inputs' size
    "BlackStep": {"k": [1.0, 3.0], "share": [0.7, 1.0], "mean_dn": [2.0, -1.0], "sd_dn": [0.5, 1.0]},  # flag word 1: a step per frame from a drawn row
    "FrameRow": {"k": [1.0, 3.0], "share": [0.3, 0.2], "weak": [0.5, 1.0], "strong": [4.0, 3.0]},  # no stage: R's sigma_r at one of two levels per sample
    "ReadDist": {"k": [1.0, 3.0], "quantiles_dn": (np.linspace(-6, 6, 257)[None, None] ** 3 / 20
                                                  * np.array([1.0, 2.0])[:, None, None] * np.ones((1, 4, 1))).tolist()},
}


def every_effect_profile():
    profile = NoiseProfile.load("SonyA7S2")
    for token, params in LOOP_EFFECTS.items():
        profile = profile.with_effect(token, params)
    return profile


def both(aug, x):
    """(numba output, Triton output) of one call, replayed from the same parameters."""
    previous = backend.set_backend("numba")
    try:
        a = aug(x)
        backend.set_backend("triton")
        b = aug(x, params=aug._params)
    finally:
        backend.set_backend(previous)
    return a, b


# the default run: every stage with the exact samplers at ratio 1 (every Poisson regime) and
# with the Gaussian ones at ratio 150; the other six pairs (15 s each in the interpreter) are slow
EQUIVALENCE_DEFAULT = {("G*+P*+R+U+C", 1.0), ("G+P+R+U", 150.0)}


@pytest.mark.parametrize("model, ratio", [(m, r) if (m, r) in EQUIVALENCE_DEFAULT else pytest.param(m, r, marks=pytest.mark.slow)
                                          for r in (1.0, 150.0) for m in ("G*+P*+R+U+C", "G+P+R+U", "G*+P*", "G")])
def test_numba_and_triton_draw_the_same_noise(model, ratio):
    # signal from 0 to 1 (up to ~15000 DN: every Poisson regime, PTRS included at ratio 1)
    x = torch.rand(3, 4, 24, 40, generator=torch.Generator().manual_seed(0)) * torch.tensor([1e-4, 1e-2, 0.3, 1.0]).view(1, 4, 1, 1)
    aug = RawNoiseAugment(every_effect_profile(), model=model, ratio=ratio, fixed={"exposure_s": 2.0})
    a, b = both(aug, x)
    assert not torch.equal(a, x)
    assert_same_noise(a, b, aug.profile.span_dn / ratio)


def test_column_noise_wanders_alike_on_both_backends_in_a_sequence():
    # Col's AR(1) over a sequence's frames (the loop's syntheses of a stack): both kernels sum
    # the same frames' draws
    prof = NoiseProfile.load("SonyA7S2").with_effect("Col", {"seed": 7, "k": [1.0], "sigma_dn": [2.0], "fixed_dn": [0.5],
                                                             "rho": [0.8]})
    aug = RawNoiseAugment(prof, model="G", ratio=1.0, fixed={"k": 1.0, "sigma_g": 0.5, "sequence": 1, "sensor": 0})
    a, b = both(aug, torch.zeros(5, 4, 16, 24))
    assert_same_noise(a, b, prof.span_dn)


def assert_same_noise(a, b, dn_per_unit):
    """Equal within 1e-5 relative (near zero within 1e-6 of white: cancellation in float32),
    but for values the ADC rounds (``CodeMap``): a pre-rounding value that lies within float32
    error of a rounding boundary may land on either neighbouring code. Measured: 1 such element
    in ~4.6e6 (400 seeds x 11520); allowed: 1 in 1000, each by at most the map's widest step."""
    a, b = a.numpy(), b.numpy()
    close = np.isclose(a, b, rtol=1e-5, atol=1e-6)
    if close.all():
        return
    steps = np.diff(np.asarray(LOOP_EFFECTS["CodeMap"]["map_dn"][0]))
    flips = np.abs(a - b)[~close] * dn_per_unit
    assert (~close).sum() <= a.size // 1000 and flips.max() <= steps.max() + 1e-3, (
        f"{(~close).sum()} of {a.size} values differ; largest difference {flips.max():.4g} DN")


def test_poisson_counts_are_equal_on_both_backends():
    lam = torch.cat([torch.linspace(0, 70, 400), torch.linspace(70, 4096, 400), torch.linspace(4000, 20000, 224)])
    aug = RawNoiseAugment("SonyA7S2", model="P*", ratio=1.0, fixed={"k": 1.0})
    x = (lam / aug.profile.span_dn).reshape(1, 4, 16, 16).float()
    a, b = both(aug, x)
    ca, cb = a * aug.profile.span_dn, b * aug.profile.span_dn
    assert torch.equal(ca.round(), cb.round())
    assert torch.allclose(ca, ca.round(), atol=1e-2)  # whole electrons


@pytest.mark.slow  # 30 s in the interpreter; every stage's equivalence is in the default run above
def test_fixed_patterns_before_shot_noise_give_the_same_counts_on_both_backends():
    # PRNU and DSNU change the Poisson mean of every pixel: a difference of 1e-7 there would
    # move a count now and then, so both backends draw these patterns from one table
    aug = RawNoiseAugment(every_effect_profile(), model="P*", ratio=1.0, fixed={"k": 1.0, "exposure_s": 2.0})
    x = torch.rand(2, 4, 48, 64, generator=torch.Generator().manual_seed(1)) * (40.0 / aug.profile.span_dn)
    a, b = both(aug, x)
    span = aug.profile.span_dn
    assert (a - b).abs().max() * span < 1e-3  # one electron is 1 DN here


def test_parameters_are_counter_based_per_sample():
    aug = RawNoiseAugment(every_effect_profile(), model="G*+P*+R+U+C")
    wide = aug.draw_parameters(6, "cpu", seed=42)["values"]
    narrow = aug.draw_parameters(2, "cpu", seed=42)["values"]
    assert torch.equal(wide[:2], narrow)  # sample b's parameters depend on (seed, b) only
    assert not torch.equal(wide[0], wide[1])


@pytest.mark.parametrize("fixed, match", [
    ({"sigma_TL": 2.0}, "unknown fixed parameter 'sigma_TL'.*sigma_tl"),
    ({"k": 0}, "k must be > 0"),
    ({"ratio": -1}, "ratio must be > 0"),
    ({"k": float("nan")}, "k must be finite"),
    ({"lambda": 3.7}, r"lambda must be in \[-1, 1\], got 3.7"),
    ({"sigma_r": -0.1}, "sigma_r must be >= 0"),
    ({"color_bias_dn": [1, 2, 3]}, "4 values"),
    ({"sequence": 2}, "sequence must be 0 or 1"),
])
def test_fixed_parameters_are_validated(fixed, match):
    with pytest.raises(ValueError, match=match):
        RawNoiseAugment("SonyA7S2", fixed=fixed)


@pytest.mark.parametrize("ratio", [float("inf"), float("nan"), (100, float("inf")), 0.0])
def test_ratio_must_be_finite_and_positive(ratio):
    with pytest.raises(ValueError, match="ratio must be a finite positive number"):
        RawNoiseAugment("SonyA7S2", ratio=ratio)


def test_gradient_is_straight_through_and_noise_unchanged(samplers):
    aug = RawNoiseAugment("SonyA7S2")  # G*+P*+R+U: P* has no derivative of its own
    x = torch.rand(2, 4, 16, 16)
    y = aug(x)
    xg = x.clone().requires_grad_(True)
    yg = aug(xg, params=aug._params)
    assert torch.equal(yg.detach(), y)  # the same noise with or without grad
    (yg * torch.arange(yg.numel()).reshape(yg.shape)).sum().backward()
    assert torch.equal(xg.grad, torch.arange(yg.numel(), dtype=torch.float32).reshape(yg.shape))


def test_gradient_with_a_gain_non_linearity_is_the_slope_of_the_mean(samplers):
    # E[noisy] = x - c (x^2 + K x) at a clean level x DN: d/dx = 1 - c (2 x + K), per sample's K
    # and, in the second record, per channel
    c = 3e-6
    c2 = torch.tensor([2 * c, c, -c, 0.0], dtype=torch.float64).view(4, 1, 1)
    profile = NoiseProfile.load("SonyA7S2").with_effect("NonLin", {"k": [1.0, 3.0], "compression_per_dn": [c, c2.ravel().tolist()]})
    aug = RawNoiseAugment(profile, model="G+P*", ratio=1.0, fixed={"k": [1.0, 3.0]})
    x = torch.rand(2, 4, 8, 8, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    y = aug(x)
    xg = x.clone().requires_grad_(True)
    yg = aug(xg, params=aug._params)
    assert torch.equal(yg.detach(), y)
    yg.sum().backward()
    dn = x * profile.span_dn
    expected = torch.stack([1 - c * (2 * dn[0] + 1.0), 1 - c2 * (2 * dn[1] + 3.0)])
    assert torch.allclose(xg.grad, expected, rtol=1e-12)


def test_non_finite_input_is_refused_without_a_separate_pass():
    x = torch.rand(2, 4, 8, 8)
    x[1, 2, 3, 4] = float("nan")
    with pytest.raises(ValueError, match="1 NaN or Inf"):
        RawNoiseAugment("SonyA7S2")(x)
    assert torch.isnan(RawNoiseAugment("SonyA7S2", check_finite=False)(x)[1, 2, 3, 4])


def test_compiled_operator_equals_eager():
    aug = RawNoiseAugment(every_effect_profile(), model="G*+P*+R+U+C")
    x = torch.rand(2, 4, 16, 16)
    aug(x)
    values, keys = aug._params["values"], aug._stream_keys(int(aug._params["seed"]))

    def op(clean):
        return synthesize_op(clean * 1.0, values, keys, float(aug.profile.span_dn), aug._flags, aug._grids, aug._code_lut, aug._read_lut) + 0.0

    compiled = torch.compile(op, fullgraph=True, backend="aot_eager")  # fullgraph: no graph break at the op
    assert torch.equal(compiled(x), op(x))
    assert torch.equal(op(x), aug(x, params=aug._params))


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
def test_cuda_equals_cpu_no_sync_few_launches_graph_capture():
    from torch.profiler import ProfilerActivity, profile

    aug = RawNoiseAugment(every_effect_profile(), model="G*+P*+R+U+C")
    x = torch.rand(2, 4, 64, 64)
    y = aug(x)
    xc = x.cuda()
    yc = aug(xc, params={k: v for k, v in aug._params.items()})
    np.testing.assert_allclose(y.numpy(), yc.cpu().numpy(), rtol=1e-5, atol=1e-6)
    aug(xc)
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        aug(xc)
    finally:
        torch.cuda.set_sync_debug_mode(0)
    with profile(activities=[ProfilerActivity.CUDA]) as prof:
        aug(xc)
        torch.cuda.synchronize()
    launches = [e for e in prof.events() if e.device_type == torch.autograd.DeviceType.CUDA]
    assert len(launches) <= 3, [e.name for e in launches]
    params = dict(aug._params)
    params["values"] = params["values"].cuda()
    static = torch.empty_like(xc)
    graph = torch.cuda.CUDAGraph()
    aug(xc, params=params)
    with torch.cuda.graph(graph):
        static.copy_(aug(xc, params=params))
    graph.replay()
    torch.testing.assert_close(static, aug(xc, params=params))


@pytest.mark.slow  # 20 s in the interpreter; the kernel at its default block is checked against numba above
def test_the_triton_block_size_does_not_change_the_noise():
    from rawaug.gpu import fused

    aug = RawNoiseAugment(every_effect_profile(), model="G*+P*+R+U+C")
    x = torch.rand(1, 4, 16, 24)  # 384 elements a plane: 3 programs of 128, one of 1024
    previous = backend.set_backend("triton")
    try:
        outs = []
        for block in (128, 1024):
            original = fused.launch
            fused.launch = lambda *a, _block=block, **k: original(*a, **{**k, "block": _block})
            try:
                outs.append(aug(x, params=aug._params if outs else None))
            finally:
                fused.launch = original
    finally:
        backend.set_backend(previous)
    assert torch.equal(outs[0], outs[1])


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
def test_compiled_cuda_training_step_draws_the_noise_of_eager():
    from rawaug.train.unet import UNet

    aug = RawNoiseAugment(every_effect_profile(), model="G*+P*+R+U+C")
    x = torch.rand(2, 4, 64, 64, device="cuda")
    aug(x)
    values, keys = aug._params["values"].cuda(), aug._stream_keys(int(aug._params["seed"])).cuda()
    net = UNet(base_channels=8).cuda()

    def step(clean):
        noisy = synthesize_op(clean, values, keys, float(aug.profile.span_dn), aug._flags, aug._grids, aug._code_lut, aug._read_lut)
        loss = (net(noisy) - clean).abs().mean()
        return noisy, loss

    compiled = torch.compile(step, fullgraph=True)  # inductor: no graph break at the operator
    noisy_c, loss_c = compiled(x)
    noisy_e, loss_e = step(x)
    assert torch.equal(noisy_c, noisy_e)
    torch.testing.assert_close(loss_c, loss_e, rtol=1e-3, atol=1e-5)  # the U-Net's kernels differ, the noise does not


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_values_pass_through_every_backend(samplers, bad):
    x = torch.rand(1, 4, 8, 8)
    x[0, 1, 2, 3] = bad
    y = RawNoiseAugment("SonyA7S2", check_finite=False)(x)
    assert not torch.isfinite(y[0, 1, 2, 3]) and torch.isfinite(y).sum() == y.numel() - 1


# fixed patterns whose every value is fixed by the sensor (no temporal part, no window)
PATTERNS = {
    "Col": {"seed": 7, "k": [1.0], "sigma_dn": [0.0], "fixed_dn": [1.0]},
    "FPN": {"seed": 11, "k": [1.0], "sigma_dn": [0.5], "shading_dn": [[[0.0, 0.0], [0.0, 0.0]]]},
    "Hot": LOOP_EFFECTS["Hot"],
    "PRNU": LOOP_EFFECTS["PRNU"],
    "Dark": {k: v for k, v in LOOP_EFFECTS["Dark"].items() if k not in ("channel", "col_dsnu", "row_dsnu")},  # channel rates: every sensor's; pixel units only
    "Lines": LOOP_EFFECTS["Lines"],
    "RowFix": LOOP_EFFECTS["RowFix"],
}


def _patterns(token, sensor, seed, batch=32):
    """(B, 4 * H * W) fixed pattern of each sample, DN (no other noise)."""
    profile = NoiseProfile.load("SonyA7S2").with_effect(token, PATTERNS[token])
    fixed = {"k": 1.0, "sigma_g": 0.0, "exposure_s": 2.0, **({} if sensor is None else {"sensor": sensor})}
    aug = RawNoiseAugment(profile, model="G", ratio=1.0, fixed=fixed, generator=torch.Generator().manual_seed(seed))
    x = torch.full((batch, 4, 32, 48), 0.2, dtype=torch.float64)
    return ((aug(x) - x) * profile.span_dn).reshape(batch, -1)


@pytest.mark.parametrize("token", sorted(PATTERNS))
def test_each_sample_has_a_sensor_of_its_own_unless_the_sensor_is_fixed(token):
    # a synthesized camera: one sensor (instance 0, the profile's) in every frame of every call
    one = _patterns(token, 0, seed=1)
    assert one.abs().sum() > 0 and torch.equal(one, one[:1].expand_as(one)) and torch.equal(one, _patterns(token, 0, seed=2))
    # training crops: a sensor drawn per sample (2^20 instances: two samples of a batch share
    # one with probability < 5e-4), so a network cannot learn one stand-in realization
    many = _patterns(token, None, seed=1)
    assert not torch.equal(many[0], many[1]) and not torch.equal(many[0], one[0])
    a, b = many[0::2] - many[0::2].mean(1, keepdim=True), many[1::2] - many[1::2].mean(1, keepdim=True)
    r = (a * b).sum(1) / (a.norm(dim=1) * b.norm(dim=1))
    # independent patterns: each pair's correlation has sd 1/sqrt(n_eff); n_eff = the
    # independent units (pixels, or the sensor lines of Col and Lines: 2 x 48 columns + 2 x 32 rows)
    n_eff = 2 * 48 if token == "Col" else 2 * 32 if token == "RowFix" else 2 * (48 + 32) if token == "Lines" else 4 * 32 * 48
    assert abs(float(r.mean())) < 5 / math.sqrt(n_eff * len(r)), float(r.mean())


@pytest.mark.parametrize("value", [1.5, -1, 2**20, float("nan")])
def test_a_fixed_sensor_must_be_an_instance(value):
    with pytest.raises(ValueError, match="sensor"):
        RawNoiseAugment("SonyA7S2", fixed={"sensor": value})
