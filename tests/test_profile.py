import math

import pytest
import yaml

from rawaug import BUILTIN_PROFILES, NoiseProfile


@pytest.mark.parametrize("name", BUILTIN_PROFILES)
def test_builtins_load_and_round_trip(name, tmp_path):
    profile = NoiseProfile.load(name)
    assert math.isclose(profile.k_max / profile.k_min, 64, rel_tol=1e-6)
    assert math.isclose(profile.k_at_iso(100), profile.k_min) and math.isclose(profile.k_at_iso(6400), profile.k_max)
    assert math.isclose(profile.k_at_iso(800), profile.k_min * 8, rel_tol=1e-9)
    path = tmp_path / "p.yaml"
    profile.save(path)
    assert NoiseProfile.load(path) == profile
    assert [p.name for p in tmp_path.iterdir()] == ["p.yaml"]  # no temp file left behind


def test_builtin_matches_the_published_eld_numbers():
    sony = NoiseProfile.load("SonyA7S2")
    assert sony.k_min == pytest.approx(0.09391607086816033)
    assert sony.tukey_scale.slope == pytest.approx(0.46210495986526035)
    assert sony.row_scale.intercept == pytest.approx(-0.5917002648887661)
    assert sony.tukey_shape.values.count(0.0) == 2
    assert (sony.black_level, sony.white_level) == (512, 16383)


def test_segments_and_floor_round_trip():
    data = NoiseProfile.load("SonyA7S2").to_dict()
    data["read_noise"]["tukey_scale"] = {
        "segments": [
            {"slope": 0.7, "intercept": 0.8, "residual_std": 0.01},
            {"slope": 0.75, "intercept": -0.1, "residual_std": 0.01, "k_from": 1.0},
        ],
        "floor_dn": 0.5,
    }
    profile = NoiseProfile.from_dict(data)
    assert profile.tukey_scale.median(0.5) == pytest.approx(math.hypot(math.exp(0.7 * math.log(0.5) + 0.8), 0.5))
    assert profile.tukey_scale.median(2.0) == pytest.approx(math.hypot(math.exp(0.75 * math.log(2.0) - 0.1), 0.5))
    assert NoiseProfile.from_dict(profile.to_dict()) == profile


def broken(edit):
    data = NoiseProfile.load("SonyA7S2").to_dict()
    edit(data)
    return data


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda d: d["system_gain"].update(k_min=0.0), "system_gain.k_min must be > 0, got 0.0"),
        (lambda d: d["system_gain"].update(k_min=-2), "system_gain.k_min must be > 0, got -2"),
        (lambda d: d["read_noise"]["tukey_shape"]["lambda"].__setitem__(0, 1.7), "lambda must be in [-1, 1], got 1.7"),
        (lambda d: d["row_noise"].pop("scale"), "missing required field 'row_noise.scale'"),
        (lambda d: d.pop("sensor"), "missing required field 'profile.sensor'"),
        (lambda d: d["sensor"].update(cfa="RGBW"), "'RGBW'"),
        (lambda d: d["sensor"].update(white_level=100), "white_level must exceed black_level"),
        (lambda d: d["color_bias"]["dn"].__setitem__(0, [1, 2, 3]), "must hold 4 values"),
        (lambda d: d.update(version=9), "'version' must be 1, got 9"),
        (lambda d: d["effects"].update(Bogus={}), "'Bogus' is not a registered effect"),
        (lambda d: d["effects"].update(RTS={"seed": 1, "density": 0.01, "high": 0.5, "log_std": 0.1, "k": [1.0],
                                            "median_dn": [20.0], "_detection": object()}),
         "effect 'RTS' parameters hold ['_detection']"),
        (lambda d: d["read_noise"]["tukey_scale"].update(slope="abc"), "tukey_scale.slope must be a number, got 'abc'"),
    ],
)
def test_invalid_profiles_name_the_value(edit, words):
    with pytest.raises(ValueError) as info:
        NoiseProfile.from_dict(broken(edit))
    assert words in str(info.value)


def test_load_errors(tmp_path):
    with pytest.raises(ValueError, match="neither a built-in"):
        NoiseProfile.load(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: [unclosed")
    with pytest.raises(ValueError, match="not valid YAML"):
        NoiseProfile.load(bad)
    bad.write_text(yaml.safe_dump({"format": "something-else"}))
    with pytest.raises(ValueError, match="'format' must be"):
        NoiseProfile.load(bad)
