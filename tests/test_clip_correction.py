"""An effect estimated through a clip at the floor is corrected by simulation
(``rawaug.loop.clip_correction``): a tone and a dark signal under a clip that holds about
half of the values come out near their size, not near half of it."""
import numpy as np
import pytest

from rawaug import NoiseProfile

from rawaug.effects import banding, column_banding, column_noise, dark_current, dark_shading, row_pattern
from rawaug.loop import FrameStack, synthesize
from rawaug.loop.clip_correction import clip_corrected, share_at_floor

from test_loop import BASE, K

CLIPPED = BASE.with_effect("Clip", {"floor_dn": 0.0})  # a black level at code 0
TONES = {"Band": (banding, {"k": [K], "freq_per_row": [[0.137]], "amplitude_dn": [[1.0]]}),
         "ColBand": (column_banding, {"k": [K], "freq_per_col": [[0.181]], "amplitude_dn": [[1.0]]})}
DARK = {"seed": 21, "k": [K], "rate_e_per_s": [1.5], "dsnu": [0.0]}


def _measured(profile, seed, exposure_s=None):
    kind = "dark" if exposure_s else "bias"
    template = FrameStack(np.full((8, 4, 128, 128), 0.5), K, kind=kind, exposure_s=exposure_s, offsets_dn=[0.0] * 4)
    frames = synthesize(profile, template, 1, seed)[0].astype(np.float64)
    return FrameStack(frames, K, kind=kind, exposure_s=exposure_s, offsets_dn=[0.0] * 4, label=kind)


@pytest.mark.parametrize("token", list(TONES))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_tone_under_a_clip_at_black_is_estimated_at_its_size(seed, token):
    module, tone = TONES[token]
    stack = _measured(CLIPPED.with_effect(token, tone), 100 + seed)
    assert share_at_floor(stack, 0.0) > 0.4
    base = list(synthesize(CLIPPED, stack, 6, 7 + seed))
    est = module.estimate(stack.frames_dn, base, K)
    # the line means move by the share of values above the floor (~0.45): the tone is halved;
    # corrected, within ~5 % (the tone's circle fit over 8 frames, twice: measured and simulated)
    assert est["amplitude_dn"][0][0] < 0.6, est
    got = clip_corrected(token, est, CLIPPED, [stack], lambda part: module.estimate(part[0].frames_dn, base, K),
                         seed=11 + seed)
    assert abs(got["amplitude_dn"][0][0] - 1.0) < 0.12, got
    assert all(got[key] == est[key] for key in est if key != "amplitude_dn"), got
    # no clip in the model, or one under every value: the estimate as it was
    assert clip_corrected(token, est, BASE, [stack], None) == est
    assert clip_corrected(token, est, BASE.with_effect("Clip", {"floor_dn": -50.0}), [stack], None) == est


def test_a_tone_the_simulation_does_not_find_keeps_its_amplitude():
    """Tones are matched by frequency: one that only the measured frames show is left as it is."""
    est = {"k": [K], "freq_per_row": [[0.137, 0.3]], "amplitude_dn": [[0.5, 0.2]], "frames": [8]}
    sim = {"k": [K], "freq_per_row": [[0.1371]], "amplitude_dn": [[0.25]], "frames": [8]}
    assert banding.aligned(sim, est)["amplitude_dn"] == [[0.25, None]]


@pytest.mark.parametrize("seed", [0, 1])
def test_dark_current_under_a_clip_at_black_is_estimated_at_its_rate(seed):
    """4 s at 1.5 e-/s: 6 DN over read noise of ~2.6 DN, a tenth of the values at the floor."""
    stack = _measured(CLIPPED.with_effect("Dark", DARK), 200 + seed, exposure_s=4.0)
    assert share_at_floor(stack, 0.0) > 0.05
    base = list(synthesize(CLIPPED, stack, 6, 9 + seed))
    estimate = lambda part: dark_current.estimate(part[0].frames_dn, base, K, exposure_s=4.0, seed=21)  # noqa: E731
    est = estimate([stack])
    got = clip_corrected("Dark", est, CLIPPED, [stack], estimate, seed=13 + seed)
    # the rate from ~130 000 values of ~2.9 DN sd: a mean within ~0.01 DN, so the correction's
    # own error is the simulation's; the uncorrected rate is short by the clipped mean's loss
    assert est["rate_e_per_s"][0] < 1.4, est
    assert abs(got["rate_e_per_s"][0] / 1.5 - 1.0) < 0.02, got


LINES = {"Col": (column_noise, {"seed": 5, "k": [0.75], "sigma_dn": [0.3], "fixed_dn": [0.5]}),
         "RowFix": (row_pattern, {"seed": 37, "k": [0.75], "fixed_dn": [1.2]}),
         "FPN": (dark_shading, {"seed": 9, "k": [0.75], "sigma_dn": [0.8], "shading_dn": [[[0.0]]]})}


@pytest.mark.parametrize("token", list(LINES))
@pytest.mark.parametrize("seed", [0, 1])
def test_line_offsets_under_a_clip_at_black_are_estimated_at_their_size(seed, token):
    """Column offsets (a new and a fixed part), fixed row offsets and per-pixel offsets (FPN's
    white part) on NikonD850 at ISO 800 (black level 0: 60 % of the values at the floor) read
    about half their size; corrected, within 10 % (the spread of ~200 lines' offsets: ~5 %
    each, measured and simulated; FPN's: 0.41-0.42 DN read for 0.8, 0.80-0.81 corrected)."""
    module, params = LINES[token]
    model = NoiseProfile.load("NikonD850").with_effect("Clip", {"floor_dn": 0.0})
    k = params["k"][0]
    template = FrameStack(np.full((8, 4, 192, 256), 0.5), k, offsets_dn=[0.0] * 4)
    stack = FrameStack(synthesize(model.with_effect(token, params), template, 1, 100 + seed)[0].astype(np.float64), k,
                       offsets_dn=[0.0] * 4, label="bias")
    assert share_at_floor(stack, 0.0) > 0.5
    base = list(synthesize(model, stack, 6, 7 + seed))
    estimate = lambda part: module.estimate(part[0].frames_dn, base, k, seed=params["seed"])  # noqa: E731
    est = estimate([stack])
    got = clip_corrected(token, est, model, [stack], estimate, seed=11 + seed)
    for key in (key for key in module.AMPLITUDES if np.isscalar(params[key][0])):  # FPN's shading grid: below
        assert est[key][0] < 0.6 * params[key][0], est
        assert abs(got[key][0] / params[key][0] - 1.0) < 0.1, got


def _nikon_bias(clip):
    """NikonD850 at ISO 800 (K 0.75) and 8 bias frames of it: with ``Clip`` (black level 0)
    about half of the values at the floor, without it none."""
    base = NoiseProfile.load("NikonD850")
    camera = base.with_effect("Clip", {"floor_dn": 0.0}) if clip else base
    template = FrameStack(np.full((8, 4, 128, 128), 0.5), 0.75, kind="bias", offsets_dn=[0.0] * 4)
    frames = synthesize(camera, template, 1, 31)[0].astype(np.float64)
    stack = FrameStack(frames, 0.75, kind="bias", offsets_dn=[0.0] * 4, label="bias")
    assert (np.mean(stack.frames_dn == 0.0) > 0.3) == clip  # the clip piles values on the floor
    return camera, stack


@pytest.mark.parametrize("clip", [False, True])
def test_read_noise_re_fit_through_a_clip_finds_the_factor(clip):
    """A model whose read noise is 1.25x the camera's (NikonD850 at ISO 800, black level 0:
    about half of the values at the floor with ``Clip``). The unclipped re-fit subtracts
    variances exactly; through the clip a pixel keeps only part of its temporal variance,
    so the variance difference cuts a third of the excess (1.25x -> 1.17x at K 0.375-3,
    three seeds each), and the factor comes by simulation (1.25x -> 0.989-0.997x there).
    Within 3 %: the temporal std of ~130 000 pixels over 8 frames is known to ~0.1 %, the
    secant's remaining curvature is what the bound allows for."""
    from rawaug.loop import diagnose
    from rawaug.loop.refit import apply_read_noise_factors, read_noise_factors

    camera, stack = _nikon_bias(clip)
    [noisy], model = apply_read_noise_factors([stack], camera, {"bias": 1.25})
    diags = {"bias": diagnose(noisy, model, n_synth=4, seed=3)}
    factors = read_noise_factors([noisy], diags, model, seed=5)
    assert abs(factors["bias"] * 1.25 - 1.0) < 0.03, factors


@pytest.mark.parametrize("clip", [False, True])
def test_row_noise_re_fit_through_a_clip_finds_the_factor(clip):
    """A model whose row noise is 1.5x the camera's (NikonD850 at ISO 800; with ``Clip`` about
    half of the values at the floor). Through the clip the sensor-row means keep about a third
    of their variance, so the variance difference cut 1.5x only to 1.40x; the factor now comes
    by simulation. Measured over the frame seeds 1, 2, 3 and 31: 0.97-1.05x with the clip,
    1.02-1.06x without it (the unclipped variance difference). Within 8 %: the row variance of
    256 sensor rows over 8 frames is known to ~3 % (sigma_r to ~1.5 %), the model's from 4 and
    2 syntheses to ~2-3 %, and the seeds above spread over 0.08."""
    from rawaug.loop import diagnose
    from rawaug.loop.refit import apply_row_noise_factors, row_noise_factors

    camera, stack = _nikon_bias(clip)
    [noisy], model = apply_row_noise_factors([stack], camera, {"bias": 1.5})
    diags = {"bias": diagnose(noisy, model, n_synth=4, seed=3)}
    factors = row_noise_factors([noisy], diags, model, seed=5)
    assert abs(factors["bias"] * 1.5 - 1.0) < 0.08, factors


@pytest.mark.parametrize("seed", [0, 1])
def test_a_black_shading_under_a_clip_at_black_is_estimated_at_its_size(seed):
    """A smooth fixed offset (FPN's shading grid: a 2 DN bump, 0.51 DN rms about its mean) on
    NikonD850 at ISO 800 (62 % of the values at the floor) reads at 0.54-0.55 of its size;
    corrected cell by cell (signed: the grid is negative at the edges), 0.99-1.00 with an rms
    error of 0.05-0.06 DN (seeds 0 and 1). Within 10 % and 0.12 DN: each cell is the mean of
    ~3000 pixels over 8 frames, known to ~0.02 DN, measured and simulated."""
    model = NoiseProfile.load("NikonD850").with_effect("Clip", {"floor_dn": 0.0})
    k = 0.75
    y, x = np.mgrid[0:8, 0:8]
    bump = 2.0 * np.exp(-((y - 3.5) ** 2 + (x - 3.5) ** 2) / 8.0)
    bump -= bump.mean()
    params = {"seed": 9, "k": [k], "sigma_dn": [0.0], "shading_dn": [bump.tolist()]}
    template = FrameStack(np.full((8, 4, 192, 256), 0.5), k, offsets_dn=[0.0] * 4)
    stack = FrameStack(synthesize(model.with_effect("FPN", params), template, 1, 100 + seed)[0].astype(np.float64), k,
                       offsets_dn=[0.0] * 4, label="bias")
    assert share_at_floor(stack, 0.0) > 0.5
    base = list(synthesize(model, stack, 6, 7 + seed))
    estimate = lambda part: dark_shading.estimate(part[0].frames_dn, base, k, seed=9)  # noqa: E731
    est = estimate([stack])
    got = clip_corrected("FPN", est, model, [stack], estimate, seed=11 + seed)
    gain = lambda p: np.polyfit(bump.ravel(), np.ravel(p["shading_dn"][0]), 1)[0]  # noqa: E731
    grid = np.asarray(got["shading_dn"][0])
    assert gain(est) < 0.7, est["shading_dn"]
    assert abs(gain(got) - 1.0) < 0.1, got["shading_dn"]
    assert np.sqrt(np.mean((grid - grid.mean() - bump) ** 2)) < 0.12, got["shading_dn"]


def test_a_fixed_pattern_is_judged_with_the_read_noise_re_fitted_only_under_a_clip():
    """``FPN`` and ``Col`` share the read noise where the model clips at its floor (the censored
    fit took their spread), and nowhere else; an effect that always shares it keeps doing so."""
    from rawaug.loop.frames_loop import _shares_noise

    for token in ("FPN", "Col"):
        assert _shares_noise(token, CLIPPED) == "read noise"
        assert _shares_noise(token, BASE) == ""
        assert _shares_noise(token) == ""
    assert _shares_noise("Xtalk", BASE) == "read noise" and _shares_noise("Band", CLIPPED) == "row noise"
    assert _shares_noise("Hot", CLIPPED) == ""


def test_the_report_says_when_an_effect_was_sized_again_through_the_clip():
    """``report.md`` states the second sizing in the re-fitted base, kept or not (it was only in the log)."""
    from rawaug.loop.frames_loop import LoopResult
    from rawaug.loop.report import outcome_summary

    result = LoopResult(CLIPPED)
    before, after = {"mean_rel_error": 0.2, "n_significant": 3}, {"mean_rel_error": 0.15, "n_significant": 2}
    result.resized = [{"effect": "Col", "round": 1, "kept": True, "battery_before": before, "battery_after": after},
                      {"effect": "Band", "round": 2, "kept": False, "battery_before": after, "battery_after": before}]
    text = outcome_summary(result)
    assert "`Col`, its size was found again through the clip in the re-fitted base" in text
    assert "battery 0.200 -> 0.150, kept." in text
    assert "`Band`" in text and "battery 0.150 -> 0.200, not kept (the first size stays)." in text
