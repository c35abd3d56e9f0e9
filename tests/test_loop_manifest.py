"""`rawaug loop MANIFEST`: calibrate the base model from frames, then find what it lacks."""
import csv
import json
import warnings

import numpy as np
import pytest
import yaml

from rawaug import NoiseProfile
from rawaug.calibration.diagnostics import CalibrationWarning
from rawaug.calibration.synthetic import write_manifest_camera
from rawaug.cli import main

BASE = NoiseProfile.load("SonyA7S2")
COLUMN = {"seed": 3, "k": [1.0], "sigma_dn": [1.5], "fixed_dn": [2.0]}


DARK = {"seed": 21, "k": [0.75, 3.0], "rate_e_per_s": [3.0, 3.0], "dsnu": [0.2, 0.2]}
def digital_gain(dn, rng, **_):
    """Firmware gain of 1.5 after the ADC: a comb of unused codes (no stage of rawaug's)."""
    return np.rint(np.rint(dn) * 1.5)


def interference(dn, rng, **_):
    """A smooth pattern new in every frame (two random low-frequency waves, 2.5 DN, zero mean:
    a frame-mean shift would be a black-level error, which BLE models physically)."""
    y, x = np.mgrid[0 : dn.shape[1], 0 : dn.shape[2]] / dn.shape[1]
    wave = sum(2.5 * np.cos(2 * np.pi * (rng.uniform(0.3, 1.5) * x + rng.uniform(0.3, 1.5) * y) + rng.uniform(0, 6.3))
               for _ in range(2))
    return dn + (wave - wave.mean())[None]


def amp_glow(dn, rng, kind, exposure, k):
    """Amplifier glow in the dark frames: Poisson electrons at 20 e-/s in one corner, falling
    off exponentially over a quarter of the frame (a shape no rawaug grid holds exactly)."""
    if kind != "dark":
        return dn
    h, w = dn.shape[1:]
    y, x = np.mgrid[0:h, 0:w]
    rate = 20.0 * np.exp(-np.hypot(y, x - w) / (0.25 * w))
    return dn + k * rng.poisson(rate[None] * exposure, size=dn.shape)


def soft_knee(dn, rng, **_):
    """An output that compresses as the signal grows: dn / (1 + 0.08 dn / 15871), 6 % lost at
    80 % of the white level (a hyperbola; rawaug's stage is a parabola)."""
    return dn / (1.0 + 0.08 * np.maximum(dn, 0.0) / BASE.span_dn)


def red_knee(dn, rng, **_):
    """The red channel alone compresses (its own amplifier): R reads dn / (1 + 0.08 dn / 15871),
    the other channels are linear."""
    out = np.array(dn, dtype=np.float64)
    out[..., 0, :, :] = soft_knee(out[..., 0, :, :], rng)
    return out


def shallow_traps(dn, rng, kind="", k=1.0, **_):
    """Charge traps (made outside rawaug): a flat's pixel of q electrons (its value over K, shot
    noise included) loses 25 (1 - exp(-q / 25)) of them: a toe at low light, a 25 e- shortfall
    above it."""
    if kind != "flat":
        return dn
    q = np.maximum(dn / k, 0.0)
    return dn - k * 25.0 * -np.expm1(-q / 25.0)


def coupled_readout(dn, rng, **_):
    """Read noise coupled between raw neighbours (made outside rawaug): a raw field of 1.5 DN
    plus 0.6 of its left neighbour's and 0.4 of its upper neighbour's value."""
    _, h, w = dn.shape
    n = rng.normal(0.0, 1.5, (2 * h + 1, 2 * w + 1))
    raw = n[1:, 1:] + 0.6 * n[1:, :-1] + 0.4 * n[:-1, 1:]
    return dn + np.stack([raw[0::2, 0::2], raw[0::2, 1::2], raw[1::2, 1::2], raw[1::2, 0::2]])  # R, G1, B, G2 of RGGB


def interference_tone(dn, rng, **_):
    """Banding from interference during readout (made outside rawaug): 1.2 DN at 0.0813
    cycles per sensor row, a phase of its own in every frame."""
    h = dn.shape[1]
    tone = 1.2 * np.cos(2 * np.pi * 0.0813 * np.arange(2 * h) + rng.uniform(0, 2 * np.pi))
    rows = np.stack([tone[0::2], tone[0::2], tone[1::2], tone[1::2]])  # R, G1 on even sensor rows; B, G2 on odd
    return dn + rows[:, :, None]


def leaky_photodiodes(dn, rng, kind="bias", exposure=0.0, k=1.0, **_):
    """Hot pixels of dark current (made outside rawaug): 0.3 % of the pixels (fixed) collect
    30 e-/s more, Poisson, so they grow with exposure and bias frames show none."""
    where = np.random.default_rng(17).random(dn.shape) < 0.003
    return dn + where * k * rng.poisson(30.0 * exposure, dn.shape)


def column_amplifier_gains(dn, rng, **_):
    """Column gain non-uniformity (made outside rawaug): each sensor column's gain off by
    0.6 % rms, the same in every frame: flats show it in proportion to the signal."""
    g = 1.0 + np.random.default_rng(19).normal(0.0, 0.006, 2 * dn.shape[2])
    return dn * np.stack([g[0::2], g[1::2], g[1::2], g[0::2]])[:, None, :]  # R, G2 on even sensor columns


def herringbone(dn, rng, **_):
    """Diagonal banding from interference during a serial readout, not locked to the line rate
    (made outside rawaug): 1.0 DN at 0.173 cycles per sensor column whose phase advances 0.311
    cycles per sensor row, a phase of its own in every frame."""
    _, h, w = dn.shape
    y, x = np.arange(2 * h)[:, None], np.arange(2 * w)[None, :]
    t = 1.0 * np.cos(2 * np.pi * (0.173 * x + 0.311 * y) + rng.uniform(0, 2 * np.pi))
    return dn + np.stack([t[0::2, 0::2], t[0::2, 1::2], t[1::2, 1::2], t[1::2, 0::2]])  # R, G1, B, G2 (RGGB)


def column_interference_tone(dn, rng, **_):
    """Vertical banding from interference during a serial row readout (made outside rawaug):
    1.0 DN at 0.147 cycles per sensor column, a phase of its own in every frame."""
    w = dn.shape[2]
    tone = 1.0 * np.cos(2 * np.pi * 0.147 * np.arange(2 * w) + rng.uniform(0, 2 * np.pi))
    cols = np.stack([tone[0::2], tone[1::2], tone[1::2], tone[0::2]])  # R, G2 on even sensor columns; G1, B on odd
    return dn + cols[:, None, :]


def row_drivers(dn, rng, **_):
    """A fixed row pattern (made outside rawaug): 1.5 DN per sensor row, the same in every frame."""
    rows = np.random.default_rng(7).normal(0.0, 1.5, (2, dn.shape[1], 1))
    return dn + rows[[0, 0, 1, 1]]  # R, G1 on even sensor rows; B, G2 on odd


def adc_banks(dn, rng, **_):
    """Row noise of each ADC bank (made outside rawaug): 1.5 DN per channel row and frame."""
    return dn + rng.normal(0.0, 1.5, (dn.shape[0], dn.shape[1], 1))


def split_amplifiers(dn, rng, **_):
    """Read noise of its own per readout half and channel (made outside rawaug): the right
    half of the columns 2.0 DN more, the B channel 2.0 DN more."""
    out = dn.copy()
    out[:, :, dn.shape[2] // 2:] += rng.normal(0.0, 2.0, out[:, :, dn.shape[2] // 2:].shape)
    out[2] += rng.normal(0.0, 2.0, dn.shape[1:])
    return out


def shared_readout(dn, rng, **_):
    """A 2x2 shared-pixel readout (made outside rawaug): a Bayer tile's four pixels share 1.5 DN."""
    return dn + rng.normal(0.0, 1.5, dn.shape[1:])[None]


def flicker(dn, rng, **_):
    """Random telegraph pixels (made outside rawaug): 1 % of the pixels (fixed) jump by +20 DN in
    about half the frames."""
    where = np.random.default_rng(99).random(dn.shape) < 0.01
    return dn + 20.0 * (where & (rng.random(dn.shape) < 0.5))


def leaky_column_bus(dn, rng, exposure=0.0, k=1.0, **_):
    """Leaky columns (made outside rawaug): 2 % of the sensor columns (fixed) collect 10 e-/s
    more dark current, Poisson, so they show in long exposures and not in bias frames."""
    leaky = np.random.default_rng(31).random(2 * dn.shape[2]) < 0.02
    cols = np.stack([leaky[0::2], leaky[1::2], leaky[1::2], leaky[0::2]])[:, None, :]  # R, G2 on even sensor columns
    return dn + cols * k * rng.poisson(10.0 * exposure, dn.shape)


def warming_amplifier(dn, rng, exposure=0.0, **_):
    """The black level rises while the amplifier warms up (made outside rawaug): +0.5 DN per
    second of exposure, no electrons, so no shot noise."""
    return dn + 0.5 * exposure


def charge_bursts(dn, rng, **_):
    """Impulsive noise (made outside rawaug): 0.1 % of the values of every frame, at new pixels
    each frame, 20 to 300 DN brighter (log-uniform)."""
    hit = rng.random(dn.shape) < 1e-3
    return dn + hit * np.exp(rng.uniform(np.log(20.0), np.log(300.0), dn.shape))


def column_traps(dn, rng, **_):
    """Column telegraph noise (made outside rawaug): sensor columns 9, 40, 71 and 100 read 6 DN
    higher in a random 40 % of the frames."""
    flick = np.isin(np.arange(2 * dn.shape[2]), (9, 40, 71, 100))
    step = 6.0 * flick * (rng.random(2 * dn.shape[2]) < 0.4)
    return dn + np.stack([step[0::2], step[1::2], step[1::2], step[0::2]])[:, None, :]  # R, G2 on even sensor columns


def jittery_gain(dn, rng, kind="bias", **_):
    """Frame-to-frame gain (made outside rawaug): each frame's analog gain off by 1 % rms."""
    return dn * (1.0 + rng.normal(0.0, 0.01))


def settling_clamp(dn, rng, **_):
    """A black clamp that settles after the frame starts (made outside rawaug): the first sensor
    rows read high, 5 exp(-Y / 3) DN on sensor row Y, and the first sensor columns 3 exp(-X / 2)
    DN, the same in every frame: fixed line offsets no random line pattern describes."""
    _, h, w = dn.shape
    rows, cols = 5.0 * np.exp(-np.arange(2 * h) / 3.0), 3.0 * np.exp(-np.arange(2 * w) / 2.0)
    row = np.stack([rows[0::2], rows[0::2], rows[1::2], rows[1::2]])[:, :, None]  # R, G1 on even sensor rows
    col = np.stack([cols[0::2], cols[1::2], cols[1::2], cols[0::2]])[:, None, :]  # R, G2 on even sensor columns
    return dn + row + col


def twelve_bit_adc(dn, rng, **_):
    """A 12-bit ADC in a 14-bit container (made outside rawaug): every raw code (the DN plus the
    base camera's black level) has its two lowest bits 0, a multiple of 4."""
    black = int(BASE.black_level)
    return ((np.rint(dn).astype(np.int64) + black) & ~3) - float(black)


def _raw_to_packed(raw):
    return np.stack([raw[0::2, 0::2], raw[0::2, 1::2], raw[1::2, 1::2], raw[1::2, 0::2]])  # R, G1, B, G2 (RGGB)


def uneven_light(dn, rng, kind="bias", k=1.0, **_):
    """Flats under uneven light (made outside rawaug): a lamp 12 % brighter on the left than on
    the right and a lens falling off to 80 % in the corners (cos^4), red falling off faster (a
    lens's colour shading); bias and dark frames untouched. The light, not the sensor: nothing
    should be added."""
    if kind != "flat":
        return dn
    _, h, w = dn.shape
    y, x = np.mgrid[0:2 * h, 0:2 * w] / np.array([2 * h - 1, 2 * w - 1])[:, None, None] - 0.5
    r2 = (y**2 + x**2) / 0.5
    light = _raw_to_packed((1.06 - 0.12 * (x + 0.5)) * (1.0 - 0.2 * r2) ** 1.0)
    light[0] *= 1.0 - 0.08 * _raw_to_packed(r2)[0]  # red
    light /= light.max()  # thinning takes light away: the brightest pixel keeps all of it
    electrons = np.maximum(np.rint(dn / k), 0).astype(np.int64)
    return dn - k * rng.binomial(electrons, 1.0 - light)  # thinned: the shot noise stays Poisson


def row_driver_gains(dn, rng, **_):
    """Row gain mismatch (made outside rawaug): each sensor row's gain off by 0.5 % rms (fixed)
    and by 0.2 % rms from frame to frame; bias frames show nothing."""
    h = dn.shape[1]
    g = 1.0 + np.random.default_rng(29).normal(0.0, 0.005, 2 * h) + rng.normal(0.0, 0.002, 2 * h)
    return dn * np.stack([g[0::2], g[0::2], g[1::2], g[1::2]])[:, :, None]  # R, G1 on even sensor rows



def offset_pattern(dn, rng, **_):
    """A fixed offset per pixel (made outside rawaug): 0.7 DN rms, the same in every frame."""
    return dn + 0.7 * np.random.default_rng(29).standard_normal(dn.shape)


def skewed_dark_current(dn, rng, exposure=0.0, k=1.0, **_):
    """Dark current of a log-normal rate per pixel (made outside rawaug): median 1.2 e-/s, 0.7 in
    log, with its shot noise."""
    rate = 1.2 * np.exp(0.7 * np.random.default_rng(31).standard_normal(dn.shape))
    return dn + k * rng.poisson(rate * exposure)


def raised_floor(dn, rng, **_):
    """A camera that stores nothing under 2 DN below black (made outside rawaug): the lower
    tail of the read noise piles up there (a quarter of a bias frame at K 0.75)."""
    return np.maximum(dn, -2.0)


def frame_locked_tone(dn, rng, **_):
    """Interference locked to the frame start (made outside rawaug): 0.7 DN at 0.23 cycles per
    sensor column and 0.17 per sensor row, at the same place in every frame."""
    _, h, w = dn.shape
    y, x = np.arange(2 * h)[:, None], np.arange(2 * w)[None, :]
    t = 0.7 * np.cos(2 * np.pi * (0.23 * x + 0.17 * y) + 0.5)
    return dn + np.stack([t[0::2, 0::2], t[0::2, 1::2], t[1::2, 1::2], t[1::2, 0::2]])  # R, G1, B, G2 (RGGB)


MEASURED = {"CodeMap", "LowFreq", "ReadDist", "LineMap"}  # the measured fallbacks; every other effect is physical


# case -> (planted rawaug effect, its parameters, what the frames undergo besides, what the loop should add)
PRNU = {"seed": 23, "sigma": 0.015}
CASES = {"Col": ("Col", COLUMN, None, ["Col"]), "Dark": ("Dark", DARK, None, ["Dark"]), "PRNU": ("PRNU", PRNU, None, ["PRNU"]),
         "comb": (None, None, digital_gain, ["CodeMap"]), "interference": (None, None, interference, ["LowFreq"]),
         "glow": (None, None, amp_glow, ["Glow"]),
         "nonlin": (None, None, soft_knee, ["NonLin"]),
         "red nonlin": (None, None, red_knee, ["NonLin"]),
         "toe": (None, None, shallow_traps, ["Trap"]),
         "crosstalk": (None, None, coupled_readout, ["Xtalk"]),
         "banding": (None, None, interference_tone, ["Band"]),
         "column banding": (None, None, column_interference_tone, ["ColBand"]),
         "dark hot pixels": (None, None, leaky_photodiodes, ["DarkHot"]),
         "column gain": (None, None, column_amplifier_gains, ["ColGain"]),
         "diagonal banding": (None, None, herringbone, ["DiagBand"]),
         "fixed rows": (None, None, row_drivers, ["RowFix"]),
         "row per channel": (None, None, adc_banks, ["RowCh"]),
         "split amplifiers": (None, None, split_amplifiers, ["ReadMap"]),
         "shared readout": (None, None, shared_readout, ["Shared"]),
         "telegraph": (None, None, flicker, ["RTS"]),
         "leaky columns": (None, None, leaky_column_bus, ["DarkCol"]),
         "black drift": (None, None, warming_amplifier, ["DarkOffset"]),
         "impulses": (None, None, charge_bursts, ["Spikes"]),
         "column flicker": (None, None, column_traps, ["ColRTS"]),
         "gain jitter": (None, None, jittery_gain, ["FrameGain"]),
         "settling clamp": (None, None, settling_clamp, ["LineMap"]),
         "uneven light": (None, None, uneven_light, []),
         "row gain": (None, None, row_driver_gains, ["RowGain"]),
         "offset pattern": (None, None, offset_pattern, ["FPN"]),
         "skewed dark current": (None, None, skewed_dark_current, ["Dark"]),
         "raised floor": (None, None, raised_floor, ["Clip"]),
         "frame-locked tone": (None, None, frame_locked_tone, ["DiagBand"]),
         "twelve-bit ADC": (None, None, twelve_bit_adc, ["StuckBit"]),
         "none": (None, None, None, []), "none_series": (None, None, None, [])}
SERIES = (0.02, 0.1, 0.3, 0.5, 0.8)  # flat levels (fraction of white) of a flat series, taken at exposures in proportion
# every other case: two levels, no series; the gain jitter's pairs at five levels (one degree
# of freedom each, judged pooled over the 10 pairs of the camera)
FLAT_LEVELS = {"nonlin": SERIES, "red nonlin": SERIES, "toe": SERIES, "none_series": SERIES, "gain jitter": SERIES}
# physical effects a case may add besides its own: the clamp's decay has low-frequency power that
# FPN's fixed shading (a smooth fixed offset) reproduces; where FPN takes that part first (3 of
# sessions 1-10), LineMap reproduces the rest
BESIDES = {"settling clamp": {"FPN"}}


def write_frames(folder, effect=None, params=None, post=None, seed=0, dark_exposures=(4.0,), flat_levels=(0.02, 0.1),
                 lights=False, n_flat=2):
    """The manifest camera (``write_manifest_camera``) of the base camera plus ``effect`` nobody
    declared, plus ``post`` (a change to the DN no rawaug stage makes)."""
    profile = BASE.with_effect(effect, params) if effect else BASE
    return write_manifest_camera(folder, profile, post=post, seed=seed, dark_exposures=dark_exposures,
                                 flat_levels=flat_levels, lights=lights, n_flat=n_flat)


# cases whose effect the default run checks on bias stacks (tests/test_loop.py); on a manifest
# they run with the slow rates below, to keep the default run short ("Col" is found on a
# manifest by test_loop_diagnoses_the_central_view_of_large_frames; "glow"'s estimator is checked
# by its round trip in tests/test_effects_loop.py, on a manifest at two exposures by the slow tests below)
SLOW_CASES = {"Col", "crosstalk", "banding", "column banding", "diagonal banding", "dark hot pixels", "column gain", "fixed rows", "row per channel", "split amplifiers", "shared readout", "telegraph",
              "leaky columns", "black drift", "impulses", "column flicker", "gain jitter", "row gain", "offset pattern",
              "skewed dark current", "raised floor", "frame-locked tone", "glow", "toe",
              "settling clamp", "nonlin", "red nonlin", "PRNU",  # (these three since the twenty-second session, to keep the default run near 5 minutes)
              "Dark", "twelve-bit ADC", "comb", "interference"}  # (since the twenty-fifth session: Dark is found in dark
# frames by tests/test_loop.py, the stuck bits by tests/test_stuck_bit.py through calibration and the estimate, the comb's
# CodeMap by tests/test_code_map.py and on a real dark frame by tests/test_real_noise_smoke.py, the interference's
# LowFreq by its estimate in tests/test_effects_loop.py; on a manifest all four with -m slow)


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c in SLOW_CASES else c for c in CASES])
def test_loop_on_a_manifest_names_the_undeclared_effect(tmp_path, case):
    check_case(tmp_path, case, seed=0)


def check_case(tmp_path, case, seed):
    effect, params, post, expected = CASES[case]
    manifest = write_frames(tmp_path, effect, params, post, seed=seed, flat_levels=FLAT_LEVELS.get(case, (0.02, 0.1)))
    out, report = tmp_path / "loop.yaml", tmp_path / "report"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationWarning)
        assert main(["loop", str(manifest), "--out", str(out), "--report", str(report), "--n-synth", "8"]) == 0
    missing_codes = [w for w in caught if "never occur (missing ADC codes" in str(w.message)]
    assert bool(missing_codes) == (post is digital_gain), [str(w.message) for w in caught]  # the comb is also diagnosed
    assert (report / "calibration" / "base_profile.yaml").is_file()  # the base model was calibrated first
    data = json.loads((report / "report.json").read_text())
    steps = data["steps"]
    accepted = [s for s in steps if s.get("accepted")]
    effects = yaml.safe_load(out.read_text())["effects"]
    assert [e for e in effects if e not in BESIDES.get(case, ())] == expected, steps
    for token in expected:
        step = next(s for s in accepted if s["effect"] == token)
        assert step["error_after"] <= 0.5 * step["error_before"], step
        # the curve behind the evidence (spectrum, histogram, ...) moved toward the measured one
        sig = step["signature"]
        assert sig["statistic"] == step["evidence"]["statistic"] and len(sig["x"]) == len(sig["measured"]) >= 8
        assert sig["distance_after"] < sig["distance_before"], (token, sig["kind"], sig["distance_before"], sig["distance_after"])
        assert step["kind"] == ("measured" if token in MEASURED else "physical")
    assert data["reproduced_by_measurement"] == [t for t in effects if t in MEASURED]
    if case == "Col":  # its temporal part had gone into the calibrated read noise: the re-fit takes it out
        base = NoiseProfile.load(report / "calibration" / "base_profile.yaml")
        loop = NoiseProfile.load(out)
        assert data["read_noise_refits"] and data["read_noise_refits"][0]["kept"], data["read_noise_refits"]
        for k in (0.75, 3.0):
            true = BASE.tukey_scale.median(k)
            assert abs(loop.tukey_scale.median(k) / true - 1) <= 0.5 * abs(base.tukey_scale.median(k) / true - 1)
    levels = FLAT_LEVELS.get(case, (0.02, 0.1))
    check_setting_curves(report, data, dark_added="Dark" in expected, n_flats=len(levels))
    if case in FLAT_LEVELS:  # a flat series: the photon transfer's bend does not bias K
        base = NoiseProfile.load(report / "calibration" / "base_profile.yaml")
        for k in (0.75, 3.0):
            assert abs(base.k_at_iso(800 if k == 0.75 else 3200) / k - 1) < 0.05, (k, base.k_at_iso(800), base.k_at_iso(3200))
    if case == "red nonlin":  # the red channel's own compression; the others' near none
        for c in effects["NonLin"]["compression_per_dn"]:
            assert isinstance(c, list) and 0.8 < c[0] * BASE.span_dn / 0.08 < 1.05 and max(abs(v) for v in c[1:]) * BASE.span_dn < 0.01, c
    if case == "nonlin":  # the hyperbola's compression near zero is 0.08 / span per DN; a parabola over the series fits a bit less
        c = effects["NonLin"]["compression_per_dn"]
        assert all(0.8 < v * BASE.span_dn / 0.08 < 1.05 for v in c), c
        from rawaug.loop.report import setting_curves

        for g in setting_curves(data):
            if g["statistic"] == "flat_linearity":
                points = g["points"]  # flats only: a bias stack has no linearity
                assert len(points) == len(SERIES), points
                assert points[0]["before"][2] and points[-1]["before"][2], points  # the ends of the series are off the line
                assert not any(p["after"][2] for p in points), points
    if not expected:
        assert accepted == [], steps
        assert "Nothing was added" in (report / "report.md").read_text()
        assert not (report / "steps.png").exists()
    else:
        assert (report / "steps.png").stat().st_size > 1000 and "![steps](steps.png)" in (report / "report.md").read_text()


def check_setting_curves(report, data, dark_added, n_flats=2):
    """The report's statistics against exposure (bias 1e-4 s, dark 4 s) and level (bias at 0,
    then ``n_flats`` flats) at each ISO; with dark current planted, the model's dark signal and its shot
    noise are off at 4 s before the loop, and all three (DSNU too: a MAD of whole codes moves
    in steps of 0.19 DN, so it is not always significant before) within its spread after."""
    from rawaug.loop.report import setting_curves

    curves = {(g["iso"], g["axis"], g["statistic"]): g["points"] for g in setting_curves(data)}
    for iso in (800, 3200):
        dark = {name: curves[(iso, "exposure_s", name)] for name in ("mean_dn", "temporal_std", "fixed_std")}
        for points in dark.values():
            assert [p["x"] for p in points] == [1e-4, 4.0] and points[1]["stack"] == f"ISO {iso} dark 4 s"
        light = curves[(iso, "level_dn", "temporal_std")]
        assert [p["x"] for p in light][0] == 0.0 and len(light) == 1 + n_flats and all(np.diff([p["x"] for p in light]) > 0)
        assert light[-1]["measured"] > 5 * light[0]["measured"]  # shot noise grows with the level
        for name, points in dark.items():
            before, after = points[1]["before"], points[1]["after"]
            if dark_added:
                assert (before[2] or name == "fixed_std") and not after[2], (iso, name, points)
                assert abs(after[0] - points[1]["measured"]) < abs(before[0] - points[1]["measured"]) / 4, (iso, name, points)
    text = (report / "report.md").read_text()
    assert "## Statistics across settings" in text and "![curves](curves.png)" in text
    assert (report / "curves.png").stat().st_size > 1000


# Measured over sessions 1-10 (python -m pytest -m slow tests/test_loop_manifest.py): Col, Dark,
# PRNU, comb, interference, glow, nonlin, none and none_series 10 of 10 each (2026-11-24; again
# with crosstalk, banding, fixed rows and row per channel, also 10 of 10 each); over
# sessions 11-20 nonlin, none and none_series 10 of 10 each (none_series was 18 of 20 over 1-20
# before residuals were confirmed on 24 syntheses). Interference was 4 of 10 (FPN added besides
# LowFreq) before FPN's shading left out the temporal smooth power a mean of N frames keeps and
# LowFreq chose its grid by the spectrum. With ReadMap, Shared and RTS among the candidates:
# split amplifiers, shared readout, telegraph, Col, none and none_series 9 or 10 of 10 each
# (the others passed the same bound one change earlier). 2026-11-25 (third session), every case
# in one run: 10 of 10 but interference and black drift (9) and impulses (8, the curve check
# alone; 10 of 10 once histograms were compared by their cumulative tails). The default run
# checks session 0 of each.
RATE_CASES = list(CASES)


@pytest.mark.slow
@pytest.mark.parametrize("case", RATE_CASES)
def test_manifest_loop_rates_over_seeds(tmp_path, case):
    # 10 camera sessions (frames and patterns from seeds 1-10): 9 of 10 or better pass the
    # same checks (a success rate of 0.95 passes with probability 0.91, one of 0.7 with 0.15)
    passed, ratios = 0, {}
    for seed in range(1, 11):
        folder = tmp_path / str(seed)
        folder.mkdir()
        try:
            check_case(folder, case, seed)
            passed += 1
        except AssertionError:
            pass
        report = folder / "report" / "report.json"
        for step in json.loads(report.read_text())["steps"] if report.is_file() else []:
            sig = step.get("signature") or {}
            if step.get("accepted") and sig.get("distance_before"):  # the curve behind the evidence, after over before
                ratios.setdefault(step["effect"], []).append(sig["distance_after"] / sig["distance_before"])
    curves = "; ".join(f"{t} curve after/before median {np.median(r):.2f} (max {max(r):.2f}, {len(r)} steps)" for t, r in ratios.items())
    print(f"{case}: {passed} of 10 sessions; {curves or 'nothing added'}")  # shown with -rA: the counts, not only the bound
    assert passed >= 9, f"{case}: {passed} of 10 sessions"


@pytest.mark.slow  # 16 s; the default run checks the undoing of a re-fit (tests/test_loop.py)
def test_an_effect_a_later_one_makes_redundant_is_taken_out(tmp_path):
    """Session 2 of the interference camera (the one of sessions 1-10 where this happens): the
    forward loop adds RowDrift (physical, for the row means) before LowFreq (measured: the whole
    smooth field). Beside LowFreq no residual needs RowDrift, so backward elimination takes it
    out, undoes the row-noise re-fit it was judged with and estimates LowFreq again."""
    check_case(tmp_path, "interference", seed=2)  # LowFreq alone, its error at least halved
    data = json.loads((tmp_path / "report" / "report.json").read_text())
    drift = [s for s in data["steps"] if s["effect"] == "RowDrift"]
    assert len(drift) == 1 and not drift[0]["accepted"] and drift[0]["note"].startswith("added, then removed"), drift
    assert [r["effect"] for r in data["removed"]] == ["RowDrift"], data["removed"]
    assert all(not r["kept"] for r in data["read_noise_refits"] if r["after"] == "RowDrift"), data["read_noise_refits"]
    low = next(s for s in data["steps"] if s["accepted"])
    assert low["effect"] == "LowFreq" and low["note"] == "estimated again once RowDrift was removed", low
    assert "`RowDrift` was added, then removed" in (tmp_path / "report" / "report.md").read_text()


@pytest.mark.slow  # about 4 minutes: the geometry
def test_an_effect_the_model_overshoots_with_is_taken_out_though_it_shares_no_statistic(tmp_path):
    """The reset_transient probe at the issue's geometry (benchmarks/loop_unseen.py, session 0,
    the one the benchmark reports): Hot is added for the high first rows before LineMap
    reproduces them, and the model's hot pixels then overshoot fixed_pixel_var, a statistic of
    FPN and Dark, not of Hot, so only the rule for a model that overshoots makes Hot a
    candidate. Backward elimination takes it out: the battery is no worse without it."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from loop_unseen import run_case

    row = run_case("reset_transient", 0, "issue", keep=tmp_path)
    data = json.loads((tmp_path / "reset_transient" / "report" / "report.json").read_text())
    assert row["fixed"] and "Hot" not in row["added"], row
    assert [r["effect"] for r in data["removed"]] == ["Hot"], data["removed"]
    after = data["removed"][0]["battery_after"]
    before = data["removed"][0]["battery_before"]
    assert after["n_significant"] <= before["n_significant"] and after["mean_rel_error"] <= before["mean_rel_error"]


@pytest.mark.slow  # about 4 minutes each: the geometry
@pytest.mark.parametrize("case, token", [("frame_row_noise", "FrameRow"), ("black_step", "BlackStep"), ("masked_rows", "Masked"),
                                         ("interleaved_row_gain", "GainGrid")])
def test_cameras_of_the_thirty_first_session_are_fixed_by_their_effect(tmp_path, case, token):
    """Probes of the thirteenth and fourteenth fresh batches (benchmarks/loop_unseen.py, session 0,
    issue geometry) that no effect fixed before the thirty-first session: each now gets its one
    effect, its evidence's error at least halved and nothing left. On interleaved_row_gain the
    physical RowGain (a random gain per row) cut its evidence only to 0.77 and kept GainGrid,
    which reproduces the period, out; the fallbacks are now tried beside it and GainGrid wins
    with the gains after shot noise (conversion near 1)."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from loop_unseen import run_case

    row = run_case(case, 0, "issue", keep=tmp_path)
    assert row["fixed"] and row["added"] == [token], row
    if token == "GainGrid":
        profile = NoiseProfile.load(tmp_path / case / "loop.yaml")
        assert profile.effects["GainGrid"]["conversion"] > 0.9, profile.effects["GainGrid"]


@pytest.mark.slow  # about 4 minutes each: the geometry
@pytest.mark.parametrize("case, token", [("row_gain_band", "TapGain"), ("column_group_gain", "GainGrid"),
                                         ("dead_clusters", "Dead")])
def test_cameras_of_the_thirty_second_session_are_fixed_by_their_effect(tmp_path, case, token):
    """Probes of the sixteenth fresh batch (benchmarks/loop_unseen.py, session 0, issue
    geometry) missed on its first run: row_gain_band (40 sensor rows at 0.97 gain) had TapGain
    acceptable but its gains' plain mean of 1 made the flats 0.7 % too bright, so ReadMap won;
    column_group_gain (a gain pattern repeating every 8 columns) had ColGain halve col_excess
    and keep GainGrid out of the round; from the seventeenth, dead_clusters (3 x 3 clusters dead
    at black, seen only in flats, which come in pairs) was below the 3 frames stuck_fraction and
    Dead asked for. Each now gets its one effect and nothing is left."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from loop_unseen import run_case

    row = run_case(case, 0, "issue", keep=tmp_path)
    assert row["fixed"] and row["added"] == [token], row


@pytest.mark.slow  # about 4 minutes each: the geometry
@pytest.mark.parametrize("case, token", [("half_column_noise", "ColTap"), ("pixel_nonlinearity", "PRNU"),
                                         ("column_read_spread", "NoisyCol"), ("row_dark_current", "Dark")])
def test_cameras_of_the_thirty_third_session_are_fixed_by_their_effect(tmp_path, case, token):
    """Probes missed on their first run: half_column_noise (seventeenth batch: column noise in
    the left half only) had no effect with column noise by region; from the eighteenth,
    pixel_nonlinearity (each pixel's gain bending with the level) had PRNU estimated on the
    first, dimmest flat stack alone (nothing), column_read_spread (every column its own white
    noise, log-normal) had NoisyCol's few noisy columns, row_dark_current (every row its own
    dark current) had no row factor on the dark rate. Each now gets its one effect and nothing
    is left."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from loop_unseen import run_case

    row = run_case(case, 0, "issue", keep=tmp_path)
    assert row["fixed"] and row["added"] == [token], row


@pytest.mark.slow  # about 3 minutes each: the geometry
@pytest.mark.parametrize("case, token", [("serial_cti", "ChargeShare"), ("diagonal_crosstalk", "ChargeShare"),
                                         ("edge_row_gain", "TapGain"), ("column_gain_high_iso", "ColGain"),
                                         ("pixel_read_spread", "Noisy")])
def test_cameras_of_the_thirty_fourth_session_are_fixed_by_their_effect(tmp_path, case, token):
    """Probes missed on their first run: serial_cti (nineteenth batch: 2 % of each pixel's charge
    trailing along the row, in flats) was hidden in neighbour_corr's rms under the high-pass's
    -0.03 at the same-colour lags; edge_row_gain (the first and last 6 sensor rows at 0.95 gain)
    was out of the gain steps' reach, 32 lines from the ends; from the twentieth,
    diagonal_crosstalk (3 % from the upper-left diagonal neighbour, in flats) had no diagonal
    share, column_gain_high_iso (column gains off by 0.8 % at K >= 1.5 only) one ColGain for
    every gain, rejected, and pixel_read_spread (every pixel its own read noise, log-normal) a
    sparse population of noisy pixels. Each now gets its one effect and nothing is left."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from loop_unseen import run_case

    row = run_case(case, 0, "issue", keep=tmp_path)
    assert row["fixed"] and row["added"] == [token], row

@pytest.mark.slow  # the default run checks the glow at one exposure (the manifest case "glow"); 17 s
def test_glow_grows_with_exposure_over_two_dark_exposures(tmp_path):
    check_glow_two_exposures(tmp_path, seed=0)


@pytest.mark.slow
def test_glow_two_exposures_rate_over_seeds(tmp_path):
    # sessions 1-10, as test_manifest_loop_rates_over_seeds (measured 2026-11-24: 10 of 10)
    passed = 0
    for seed in range(1, 11):
        folder = tmp_path / str(seed)
        folder.mkdir()
        try:
            check_glow_two_exposures(folder, seed)
            passed += 1
        except AssertionError:
            pass
    assert passed >= 9, f"glow, darks of 2 s and 8 s: {passed} of 10 sessions"


def check_glow_two_exposures(tmp_path, seed):
    """Darks of 2 s and 8 s: the glow's low-frequency power grows with exposure and the bias
    frames show none; the loop adds Glow alone (one grid per gain, fitted through the origin
    over both exposures) and its syntheses follow the measured curve at every point."""
    manifest = write_frames(tmp_path, post=amp_glow, dark_exposures=(2.0, 8.0), seed=seed)
    out, report = tmp_path / "loop.yaml", tmp_path / "report"
    assert main(["loop", str(manifest), "--out", str(out), "--report", str(report), "--n-synth", "8"]) == 0
    data = json.loads((report / "report.json").read_text())
    assert [s["effect"] for s in data["steps"] if s.get("accepted")] == ["Glow"], data["steps"]
    glow = yaml.safe_load(out.read_text())["effects"]["Glow"]
    assert len(glow["k"]) == 2  # one record per ISO, not per dark exposure
    from rawaug.loop.report import setting_curves

    curves = {(g["iso"], g["axis"], g["statistic"]): g["points"] for g in setting_curves(data)}
    for iso in (800, 3200):
        points = curves[(iso, "exposure_s", "psd2d_lowfreq")]
        assert [p["x"] for p in points] == [1e-4, 2.0, 8.0]
        measured = [p["measured"] for p in points]
        assert measured[0] < measured[1] < measured[2], points
        assert not points[0]["before"][2] and points[1]["before"][2] and points[2]["before"][2], points
        assert not any(p["after"][2] for p in points), points


@pytest.mark.slow  # 40 s: two loops over a whole manifest
def test_a_component_that_spoils_the_battery_is_not_added(tmp_path, monkeypatch):
    # The two-exposure glow camera with Glow taken out of the candidates: LowFreq (a field new
    # in every frame) cuts the glow's psd2d_lowfreq error by 70 %, but nearly doubles the
    # battery's mean error (0.45 -> 0.78 at session 0), so it is rejected; Dark is added
    # (the glow's mean) and the glow stays unexplained, which the report says.
    from rawaug.loop import registry

    monkeypatch.delitem(registry.CANDIDATES, "Glow")
    manifest = write_frames(tmp_path, post=amp_glow, dark_exposures=(2.0, 8.0))
    out, report = tmp_path / "loop.yaml", tmp_path / "report"
    assert main(["loop", str(manifest), "--out", str(out), "--report", str(report), "--n-synth", "8"]) == 0
    data = json.loads((report / "report.json").read_text())
    lowfreq = [s for s in data["steps"] if s["effect"] == "LowFreq"]
    assert lowfreq and not any(s["accepted"] for s in lowfreq), data["steps"]
    assert any(s["error_after"] <= 0.8 * s["error_before"]
               and s["battery_after"]["mean_rel_error"] > 1.25 * s["battery_before"]["mean_rel_error"] for s in lowfreq)
    assert [s["effect"] for s in data["steps"] if s["accepted"]] == ["Dark"]
    assert any(u["statistic"] == "psd2d_lowfreq" and "dark" in u["stack"] for u in data["unexplained"])
    assert "Unexplained" in (report / "report.md").read_text()


@pytest.mark.slow  # 14 s: moved out of the default run to keep it under 5 minutes
def test_loop_diagnoses_the_central_view_of_large_frames(tmp_path):
    manifest = write_frames(tmp_path, "Col", COLUMN)  # 64 x 64 per packed channel
    out, report = tmp_path / "loop.yaml", tmp_path / "report"
    assert main(["loop", str(manifest), "--out", str(out), "--report", str(report), "--n-synth", "8", "--loop-size", "48"]) == 0
    data = json.loads((report / "report.json").read_text())
    assert data["loop_view"] == {"frame": [64, 64], "diagnosed": [48, 48]}
    assert "central 48 x 48" in (report / "report.md").read_text()
    assert list(yaml.safe_load(out.read_text())["effects"]) == ["Col"]  # still found on the view
    assert main(["loop", str(manifest), "--out", str(tmp_path / "x.yaml"), "--report", str(tmp_path / "r2"),
                 "--loop-size", "8"]) == 2 and not (tmp_path / "x.yaml").exists()


def test_a_chance_residual_is_confirmed_before_it_is_acted_on(tmp_path):
    # Session 4 of the ELD-only camera with a flat series: the 8 syntheses of the 1587 DN flat
    # at ISO 3200 happen to spread little, so its psd2d_lowfreq stands at z = 7.9 and FPN, tried
    # on it, cut its error by 21 % and was added (measured before the confirmation existed).
    # Against 24 fresh syntheses it is z = 2.5: nothing is tried on it, and the report says so.
    manifest = write_frames(tmp_path, seed=4, flat_levels=SERIES)
    out, report = tmp_path / "loop.yaml", tmp_path / "report"
    assert main(["loop", str(manifest), "--out", str(out), "--report", str(report), "--n-synth", "8"]) == 0
    data = json.loads((report / "report.json").read_text())
    assert data["steps"] == [] and yaml.safe_load(out.read_text())["effects"] == {}
    chance = [u for u in data["unconfirmed"] if u["statistic"] == "psd2d_lowfreq"]
    assert chance and all(abs(u["z"]) > 6 > abs(u["z_confirm"]) and u["n_synth_confirm"] == 24 for u in chance), data["unconfirmed"]
    assert not any(u["statistic"] == "psd2d_lowfreq" for u in data["unexplained"])
    assert "Not confirmed on a larger sample of syntheses" in (report / "report.md").read_text()


@pytest.mark.slow  # 16 s: moved out of the default run to keep it under 5 minutes
def test_flats_under_known_lights_form_a_series(tmp_path, capsys):
    # the soft-knee camera's flat series taken at one exposure time under five lights: with
    # the manifest's light column the loop checks the response and names the non-linearity;
    # without it those flats are no series (a warning says so) and nothing is found
    manifest = write_frames(tmp_path, post=soft_knee, flat_levels=SERIES, lights=True)
    out = tmp_path / "loop.yaml"
    assert main(["loop", str(manifest), "--out", str(out), "--report", str(tmp_path / "report"), "--n-synth", "8"]) == 0
    effects = yaml.safe_load(out.read_text())["effects"]
    assert list(effects) == ["NonLin"] and all(0.8 < v * BASE.span_dn / 0.08 < 1.05 for v in effects["NonLin"]["compression_per_dn"])
    rows = list(csv.reader(manifest.open()))
    no_light = tmp_path / "no_light.csv"
    with open(no_light, "w", newline="") as f:
        csv.writer(f).writerows([r[:-1] for r in rows])
    out2 = tmp_path / "loop2.yaml"
    capsys.readouterr()
    assert main(["loop", str(no_light), "--out", str(out2), "--report", str(tmp_path / "report2"), "--n-synth", "8"]) == 0
    printed = capsys.readouterr().out  # each light's flats made a stack of their own, not one stack of mixed levels
    assert "ISO 800: the flats at 0.5 s fall at 5 levels" in printed and "'light' column" in printed
    assert "NonLin" not in (yaml.safe_load(out2.read_text()).get("effects") or {})


def _clipped_at_code_zero(folder, seed):
    """An ELD-model camera whose black level is 0 (NikonD850's): the files hold no code under 0,
    so half the read noise of its bias frames piles up there. Returns the loop's report.json."""
    manifest = write_manifest_camera(folder, NoiseProfile.load("NikonD850"), seed=seed)
    out, report = folder / "loop.yaml", folder / "report"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        assert main(["loop", str(manifest), "--out", str(out), "--report", str(report), "--n-synth", "8"]) == 0
    assert yaml.safe_load(out.read_text())["effects"].get("Clip") == {"floor_dn": 0.0}  # calibration's code floor
    assert "`Clip` came with the calibration" in (report / "report.md").read_text()
    return json.loads((report / "report.json").read_text())


@pytest.mark.slow
def test_a_camera_clipped_at_code_zero_gets_nothing_added_rate_over_seeds(tmp_path):
    # the clip at code 0 is the recording format's, in the calibrated profile; the loop re-fits
    # the read noise with it and adds nothing: at least 19 of 20 sessions (a false-addition rate
    # of 0.05 passes with probability 0.74, one of 0.25 with 0.02)
    clean = 0
    for seed in range(20):
        folder = tmp_path / str(seed)
        folder.mkdir()
        data = _clipped_at_code_zero(folder, seed)
        clean += not [s for s in data["steps"] if s.get("accepted")] and not data.get("unexplained")
    print(f"clipped at code 0: nothing added and nothing left in {clean} of 20 sessions")
    assert clean >= 19, f"{clean} of 20"


def test_the_flat_light_leaves_out_stuck_pixels_and_keeps_dim_rows():
    # a flat pair at 1000 DN with Poisson-like noise: a dead column stuck at code 3 and a row of
    # pixels that collect half the light (phase-detection rows). The light is the mean over the
    # pixels that move: the dead column left out, the dim row kept (a gain grid of mean 1 holds it)
    from rawaug.loop.command import light_on_live_pixels

    rng = np.random.default_rng(0)
    stack = 1000.0 + 30.0 * rng.standard_normal((2, 4, 32, 32))
    stack[:, :, 5, :] *= 0.5  # the dim row
    stack[:, 1, :, 7] = 3.0  # the dead column of G1
    light = light_on_live_pixels(stack)
    live = np.ones((4, 32, 32), dtype=bool)
    live[1, :, 7] = False
    want = np.array([stack[:, c][:, live[c]].mean() for c in range(4)])
    # each channel's mean holds the dim row alike; two channels' means differ by noise (sd ~0.7 DN)
    assert np.allclose(light, want) and abs(light[1] - light[0]) < 5.0, light
    assert stack.mean(axis=(0, 2, 3))[1] < light[1] - 25.0  # the plain mean: ~31 DN low from the dead column
    assert np.allclose(light_on_live_pixels(stack[:1]), stack[:1].mean(axis=(0, 2, 3)))  # one frame: its plain mean
