"""DNL: an ADC whose codes are not equally wide, periodically in the code, through the real
stage, its statistic and its estimator."""
import numpy as np
import pytest
import torch

from rawaug import NoiseProfile, RawNoiseAugment
from rawaug.effects import adc_dnl
from rawaug.engine.layout import COLUMN
from rawaug.statistics import code_dnl

WIDTHS = np.array([1.0, 1.0, 1.0, 0.6, 1.8, 0.6, 1.0, 1.0])  # every code 8k + 4 wide, its neighbours narrow
E = adc_dnl.decision_offsets(WIDTHS)  # [0, 0, 0, 0, -0.4, 0.4, 0, 0]


def converted(dn):
    """Whole codes of ``dn`` by the decision levels ``E`` (the stage's rule, in NumPy)."""
    code = np.floor(dn + 0.5)
    j = np.mod(code, 8).astype(int)
    code = np.where(dn < code - 0.5 + E[j], code - 1, np.where(dn >= code + 0.5 + E[(j + 1) % 8], code + 1, code))
    return code


def synth(n, sigma, seed, offset=0.0, effect=True):
    prof = NoiseProfile.load("SonyA7S2")
    if effect:
        prof = prof.with_effect("DNL", {"period": 8, "threshold_dn": E.tolist()})
    aug = RawNoiseAugment(prof, model="G+C", ratio=1.0,
                          fixed={"k": 1.0, "sigma_g": sigma, "sensor": 0, "color_bias_dn": [offset] * 4}, generator=torch.Generator().manual_seed(seed), rank_seeding=False)
    with torch.no_grad():
        return aug(torch.zeros(n, 4, 64, 64, dtype=torch.float64)).numpy() * prof.span_dn


def test_the_stage_writes_whole_codes_of_the_widths_and_keeps_the_mean():
    # 64 frames of Gaussian noise of 6 DN (over a code the density changes by < 1 %): each phase's
    # share of the counts near the centre is its width / 8, within 5 binomial sigmas
    f = synth(64, 6.0, seed=1, offset=0.3)
    assert np.allclose(f, np.rint(f), atol=1e-3)
    v = np.rint(f).astype(int).ravel()
    near = v[np.abs(v) <= 4 * 8]
    share = np.bincount(np.mod(near, 8), minlength=8) / near.size
    expected = WIDTHS / 8
    assert np.all(np.abs(share - expected) < 5 * np.sqrt(expected * (1 - expected) / near.size))
    # decision levels of mean 0: a smooth input keeps its mean (0.3 DN), within 5 standard errors
    assert abs(f.mean() - 0.3) < 5 * 6.0 / np.sqrt(f.size)


def test_the_stage_is_the_converter_written_out():
    # no noise: a ramp of clean values from -12 to 12 DN through the stage is the NumPy rule's codes,
    # but for values within float32 error of a decision level
    prof = NoiseProfile.load("SonyA7S2").with_effect("DNL", {"period": 8, "threshold_dn": E.tolist()})
    aug = RawNoiseAugment(prof, model="C", ratio=1.0, fixed={"k": 1.0, "sensor": 0, "color_bias_dn": [-12.0] * 4})
    dn = torch.linspace(0.0, 24.0, 4 * 40 * 60, dtype=torch.float64).reshape(1, 4, 40, 60)
    with torch.no_grad():
        out = aug(dn / prof.span_dn).numpy() * prof.span_dn
    x = dn.numpy() - 12.0
    want = converted(x)
    code = np.floor(x + 0.5)
    j = np.mod(code, 8).astype(int)
    near = (np.abs(x - (code - 0.5 + E[j])) < 1e-4) | (np.abs(x - (code + 0.5 + E[(j + 1) % 8])) < 1e-4)
    assert np.allclose(out[~near], want[~near], atol=1e-3)
    assert np.any(want != np.rint(x))  # the ramp crosses moved levels


def test_code_dnl_over_seeds():
    # 20 stacks of rounded Gaussian noise of 3 DN and 20 through the stage (8 frames of 4 x 64 x 64):
    # measured: ideal 0.15 to 1.29, wide codes 812 to 876; apart by far more than their spreads
    ideal = [code_dnl(np.rint(synth(8, 3.0, seed=10 + s, effect=False))) for s in range(20)]
    wide = [code_dnl(np.rint(synth(8, 3.0, seed=40 + s))) for s in range(20)]
    assert max(ideal) < 2.0 and min(wide) > 100.0
    assert code_dnl(synth(2, 3.0, seed=3, effect=False) + 0.25) == 0.0  # not whole codes: nothing to tell


def camera(seed, planted, shape=(4, 4, 48, 64)):
    """DNL records of one camera: three stacks (read noise 1.5, 3 and 6 DN; the model's 2 % low),
    measured with the wide codes or plain rounding, against four rounded syntheses each."""
    rng = np.random.default_rng(seed)
    records = []
    for sigma in (1.5, 3.0, 6.0):
        meas = rng.normal(0.2, sigma * 1.02, shape)
        meas = converted(meas) if planted else np.rint(meas)
        records.append(adc_dnl.estimate(meas, [np.rint(rng.normal(0.2, sigma, shape)) for _ in range(4)], 1.0))
    return adc_dnl.combine(records)


def test_estimate_finds_the_period_and_the_levels_over_seeds():
    # measured: period 8 in 20 of 20 cameras, e[4] and e[5] within 0.02 of -0.4 and 0.4
    got = [camera(s, True) for s in range(20)]
    assert sum(g["period"] == 8 for g in got) >= 19
    for g in got:
        if g["period"] == 8:
            assert np.allclose(g["threshold_dn"], E, atol=0.05)


def test_without_dnl_the_estimate_is_near_nothing_over_seeds():
    # measured: period 1 (nothing) in 18 of 20 cameras, the other two (periods 2 and 3) below 0.007 DN
    got = [camera(100 + s, False) for s in range(20)]
    assert sum(adc_dnl.empty(g) for g in got) >= 16
    assert max(max(abs(v) for v in g["threshold_dn"]) for g in got) < 0.05


def test_codes_that_are_not_whole_or_too_few_cannot_show_it():
    f = np.rint(np.random.default_rng(0).normal(0, 3, (2, 4, 16, 16)))
    with pytest.raises(ValueError, match="whole codes"):
        adc_dnl.estimate(f + 0.5, [f], 1.0)
    with pytest.raises(ValueError, match="well-filled codes"):
        adc_dnl.estimate(np.zeros_like(f), [f], 1.0)


@pytest.mark.parametrize("params, match", [
    ({"period": 2, "threshold_dn": [0.5, -0.5, 0.0]}, r"threshold_dn must hold 2"),
    ({"period": 2, "threshold_dn": [1.0, -1.0]}, r"in \(-1, 1\)"),
    ({"period": 0, "threshold_dn": []}, r"period must be a whole number of codes in \[1, 64\]"),
    ({"period": 3, "threshold_dn": [0.6, -0.6, 0.0]}, "negative width"),
    ({"period": 1, "threshold_dn": [0.0], "lo": 1}, "unknown keys"),
])
def test_bad_entries_are_refused(params, match):
    with pytest.raises(ValueError, match=match):
        NoiseProfile.load("SonyA7S2").with_effect("DNL", params)


def test_a_profile_with_the_converter_is_not_dithered_as_well():
    # U stands for the rounding the converter does: with DNL the codes are the stage's, not
    # dithered first (a second quantization noise of 1/12 DN^2)
    prof = NoiseProfile.load("SonyA7S2").with_effect("DNL", {"period": 8, "threshold_dn": E.tolist()})
    aug = RawNoiseAugment(prof, model="G+U", ratio=1.0, fixed={"k": 1.0, "sigma_g": 3.0})
    values = aug.draw_parameters(4, seed=0)["values"]
    assert torch.all(values[:, COLUMN["step_dn"]] == 0.0)
    plain = RawNoiseAugment("SonyA7S2", model="G+U", ratio=1.0, fixed={"k": 1.0, "sigma_g": 3.0})
    assert torch.all(plain.draw_parameters(4, seed=0)["values"][:, COLUMN["step_dn"]] > 0.0)
