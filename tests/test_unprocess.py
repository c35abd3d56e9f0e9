"""Unprocessing sRGB photos into clean raw: each step inverts its forward stage, and a
folder of photos trains through the real LightningCLI."""
import numpy as np
import pytest

from rawaug.train import PhotoFolder
from rawaug.train.unprocess import (XYZ_TO_SONY_A7S2, inverse_gamma, inverse_tone, mosaic_packed, random_gains,
                                    rgb_to_camera, unprocess)


def forward_pipeline(cam, gains):
    """The camera pipeline unprocessing inverts: white balance, colour correction, gamma, tone."""
    red, blue, digital = gains
    rgb = cam * np.array([red, 1.0, blue]) * digital
    rgb = np.clip(rgb @ np.linalg.inv(rgb_to_camera(XYZ_TO_SONY_A7S2)).T, 0.0, 1.0)
    x = rgb ** (1 / 2.2)
    return 3 * x**2 - 2 * x**3


def test_inverse_tone_inverts_the_smoothstep():
    x = np.linspace(0, 1, 101)
    np.testing.assert_allclose(inverse_tone(3 * x**2 - 2 * x**3), x, atol=1e-12)
    np.testing.assert_allclose(inverse_gamma(x ** (1 / 2.2)), x, atol=1e-8)


def test_rgb_to_camera_keeps_white():
    np.testing.assert_allclose(rgb_to_camera(XYZ_TO_SONY_A7S2) @ np.ones(3), np.ones(3))


def test_unprocessing_recovers_the_camera_mosaic():
    rng = np.random.default_rng(0)
    gains = random_gains(np.random.default_rng(5))
    # the camera RGB of linear sRGB colours inside the gamut (not near white: no highlight roll-off)
    rgb = 0.05 + 0.3 * rng.random((32, 48, 3))
    cam = (rgb @ rgb_to_camera(XYZ_TO_SONY_A7S2).T) / (np.array([gains[0], 1.0, gains[1]]) * gains[2])
    srgb = forward_pipeline(cam, gains)
    assert srgb.min() > 0 and srgb.max() < 1
    packed = unprocess(srgb, np.random.default_rng(5))  # the same gains
    np.testing.assert_allclose(packed, mosaic_packed(cam), rtol=1e-4, atol=1e-6)


def test_bad_images_are_refused():
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        unprocess(np.zeros((8, 8)), np.random.default_rng(0))
    with pytest.raises(ValueError, match="3x3"):
        PhotoFolder("x", xyz_to_cam=[[1, 0], [0, 1]])


def write_photos(folder, n=2, size=(96, 128)):
    import imageio.v3 as iio

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    y, x = np.mgrid[0 : size[0], 0 : size[1]]
    for i in range(n):
        img = np.stack([(x / size[1]), (y / size[0]), rng.random(size) * 0.3 + 0.2], axis=-1)
        iio.imwrite(folder / f"photo{i}.png", (img * 255).astype(np.uint8))


def test_photo_folder_items_are_packed_clean_raw_and_repeatable(tmp_path):
    write_photos(tmp_path / "photos")
    source = PhotoFolder(str(tmp_path / "photos"))
    assert len(source) == 2
    item = source[1]
    assert item["target"].shape == (4, 48, 64) and item["target"].dtype.is_floating_point
    assert 0 <= float(item["target"].min()) and float(item["target"].max()) <= 1
    assert (item["target"] == source[1]["target"]).all()  # the same gains every epoch
    assert item["camera"] == "unprocessed-photos" and item["name"] == "photo1"


def test_a_folder_of_photos_trains_through_the_cli(tmp_path):
    from test_train_cli import REPO, _small, main

    write_photos(tmp_path / "photos", n=3)
    args = ["fit", "--config", str(REPO / "configs" / "quickstart.yaml"), *_small(tmp_path),
            "--data.init_args.train=rawaug.train.PhotoFolder", f"--data.init_args.train.root={tmp_path / 'photos'}",
            "--trainer.fast_dev_run", "1"]
    cli = main(args)
    assert cli.trainer.state.finished and cli.trainer.global_step == 1


def test_the_bundled_photos_unprocess_and_each_has_a_licence():
    import csv

    from rawaug.train.sources import BUNDLED_PHOTOS

    source = PhotoFolder()  # default: the bundled public-domain / CC0 photos
    with open(BUNDLED_PHOTOS / "manifest.csv") as f:
        rows = {r["file"]: r for r in csv.DictReader(line for line in f if not line.startswith("#"))}
    assert sorted(p.name for p in source.entries) == sorted(rows)
    for i, path in enumerate(source.entries):
        row = rows[path.name]
        assert row["license"].strip() and row["source"].strip()
        target = source[i]["target"]
        assert tuple(target.shape) == (4, int(row["height"]) // 2, int(row["width"]) // 2)
        assert 0 <= float(target.min()) and float(target.max()) <= 1 and float(target.mean()) > 0.01
