"""Data layouts of the training app (SID Sony, ELD, clean folders, bundled scenes), on small
trees of .npz stand-ins the tests write (no camera raw file can be downloaded here)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rawaug.io import read_frame
from rawaug.train.cache import FrameCache
from rawaug.train.data import EpochShuffle, RawDenoiseData
from rawaug.train.eld import ELD, INPUT_IDS, REFERENCE_IDS, eld_pairs, reference_id
from rawaug.train.sid import SIDSony, exposure_from_name, read_sid_list
from rawaug.train.sources import BUNDLED_SCENES, CleanFolder, NoisyFolder, find_any_extension

BLACK, WHITE = 512, 16383


def _scene(rng, size, level):
    """A smooth real-looking test pattern (raw codes, black added), mean about `level` of white."""
    yy, xx = np.mgrid[0:size, 0:size] / size
    img = 0.5 + 0.3 * np.sin(6 * xx) * np.cos(4 * yy) + 0.1 * rng.standard_normal((size, size))
    return np.clip(BLACK + level * (WHITE - BLACK) * img, 0, WHITE).astype(np.uint16)


def write_frame(path: Path, mosaic, **meta):
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, mosaic=mosaic, black_level=BLACK, white_level=WHITE, cfa="RGGB", **meta)


SID_LISTS = {
    "Sony_train_list.txt": [("00001_00_0.1s", "00001_00_10s", 200), ("00001_01_0.1s", "00001_00_10s", 200),
                            ("00001_00_0.04s", "00001_00_10s", 200), ("00002_00_0.033s", "00002_00_10s", 400)],
    "Sony_val_list.txt": [("20005_00_0.1s", "20005_00_10s", 200)],
    "Sony_test_list.txt": [("10003_00_0.04s", "10003_00_10s", 100), ("10003_00_0.1s", "10003_00_10s", 100)],
}


def make_sid_tree(root: Path, size: int = 64) -> Path:
    """SID Sony layout with the original list files (``.ARW`` names) and ``.npz`` stand-ins."""
    rng = np.random.default_rng(1)
    for list_name, rows in SID_LISTS.items():
        lines = []
        for short, long, iso in rows:
            write_frame(root / "Sony/long" / f"{long}.npz", _scene(rng, size, 0.5))
            ratio = exposure_from_name(long + ".ARW") / exposure_from_name(short + ".ARW")
            write_frame(root / "Sony/short" / f"{short}.npz", _scene(rng, size, 0.5 / ratio))
            lines.append(f"./Sony/short/{short}.ARW ./Sony/long/{long}.ARW ISO{iso} F8")
        (root / list_name).write_text("\n".join(lines) + "\n")
    return root


def make_eld_tree(root: Path, camera: str = "SonyA7S2", scenes=(1, 2), size: int = 64) -> Path:
    """ELD layout: 16 frames per scene; references 1/6/11/16 at ISO 100, 1 s; the frames of
    each block at ISO 800/1600/3200 with ratios 1, 10, 100, 200 (exposure set from it)."""
    rng = np.random.default_rng(2)
    for scene in scenes:
        folder = root / camera / f"scene-{scene}"
        for img_id in range(1, 17):
            if img_id in REFERENCE_IDS:
                iso, exposure = 100.0, 1.0
            else:
                block, offset = (img_id - 1) // 5, (img_id - 1) % 5
                iso, ratio = (800.0, 1600.0, 3200.0)[block], (1, 10, 100, 200)[offset - 1]
                exposure = 100.0 * 1.0 / (iso * ratio)
            write_frame(folder / f"IMG_{img_id:04d}.npz", _scene(rng, size, 0.4), iso=iso, exposure_s=exposure)
    return root


# ---------------------------------------------------------------- SID
def test_sid_list_parsing_ratio_and_paths(tmp_path):
    root = make_sid_tree(tmp_path)
    pairs = read_sid_list(root / "Sony_train_list.txt", root)
    assert [p["ratio"] for p in pairs] == [100.0, 100.0, 250.0, 300.0]  # 10/0.033 = 303 is capped at 300
    assert pairs[0]["short"] == root / "Sony/short/00001_00_0.1s.ARW"
    assert [p["scene"] for p in pairs] == [1, 1, 1, 2] and pairs[0]["iso"] == 200.0
    assert find_any_extension(pairs[0]["short"]).name == "00001_00_0.1s.npz"


def test_sid_bad_names_and_lines(tmp_path):
    with pytest.raises(ValueError, match="exposure"):
        exposure_from_name("00001_00_fast.ARW")
    (tmp_path / "bad.txt").write_text("./Sony/short/00001_00_0.1s.ARW\n")
    with pytest.raises(ValueError, match="line 1"):
        read_sid_list(tmp_path / "bad.txt", tmp_path)
    with pytest.raises(FileNotFoundError):
        read_sid_list(tmp_path / "missing.txt", tmp_path)
    with pytest.raises(ValueError, match="mode"):
        SIDSony(str(tmp_path), mode="fancy")


def test_sid_modes(tmp_path):
    root = make_sid_tree(tmp_path)
    clean = SIDSony(str(root), "Sony_train_list.txt", mode="clean")
    assert [e["long"].stem for e in clean.entries] == ["00001_00_10s", "00002_00_10s"]
    item = clean[0]
    assert set(item) >= {"target", "name", "ratio", "camera"} and "input" not in item
    expected = read_frame(root / "Sony/long/00001_00_10s.npz").packed_normalized()
    np.testing.assert_array_equal(item["target"].numpy(), expected)

    paired = SIDSony(str(root), "Sony_train_list.txt", mode="paired")
    assert len(paired) == 4
    item = paired[2]
    short = read_frame(root / "Sony/short/00001_00_0.04s.npz").packed_normalized()
    np.testing.assert_allclose(item["input"].numpy(), short * np.float32(250.0), rtol=1e-6)
    assert item["ratio"] == 250.0

    n2n = SIDSony(str(root), "Sony_train_list.txt", mode="noise2noise")
    # only scene 1 at 0.1 s has two short frames: (00, 01) and (01, 00)
    assert [item["name"] for item in n2n] == ["00001_00_0.1s~00001_01_0.1s", "00001_01_0.1s~00001_00_0.1s"]
    b = read_frame(root / "Sony/short/00001_01_0.1s.npz").packed_normalized()
    np.testing.assert_allclose(n2n[0]["target"].numpy(), b * np.float32(100.0), rtol=1e-6)

    only = SIDSony(str(root), "Sony_train_list.txt", mode="paired", scenes=[2])
    assert len(only) == 1


# ---------------------------------------------------------------- ELD
def test_eld_reference_rule_matches_the_authors():
    # ELDEvalDataset: gt_ids = [1, 6, 11, 16]; ind = argmin |img_id - gt_ids|
    assert {i: reference_id(i) for i in (4, 5, 9, 10, 14, 15)} == {4: 6, 5: 6, 9: 11, 10: 11, 14: 16, 15: 16}
    assert INPUT_IDS == {100: (4, 9, 14), 200: (5, 10, 15)}
    assert reference_id(3) == 1 and reference_id(8) == 6  # ties (|3-1| = |3-6| - 1) and nearest


def test_eld_pairs_and_metadata_ratio(tmp_path):
    root = make_eld_tree(tmp_path)
    pairs = eld_pairs(root, "SonyA7S2", scenes=[1, 2], ratios=[100, 200])
    assert len(pairs) == 2 * 2 * 3
    assert [(p["img_id"], p["target"].stem) for p in pairs[:3]] == [(4, "IMG_0006"), (9, "IMG_0011"), (14, "IMG_0016")]
    ds = ELD(str(root), camera="SonyA7S2", scenes=[1, 2], ratios=[200])
    item = ds[1]  # scene 1, IMG_0010 (ISO 1600, x200) against IMG_0011
    noisy = read_frame(root / "SonyA7S2/scene-1/IMG_0010.npz")
    ref = read_frame(root / "SonyA7S2/scene-1/IMG_0011.npz")
    ratio = ref.iso * ref.exposure_s / (noisy.iso * noisy.exposure_s)
    assert ratio == pytest.approx(200.0, rel=1e-9)
    np.testing.assert_allclose(item["input"].numpy(), noisy.packed_normalized() * np.float32(ratio), rtol=1e-5)
    np.testing.assert_array_equal(item["target"].numpy(), ref.packed_normalized())
    assert item["ratio"] == 200.0 and item["name"] == "scene-1/IMG_0010" and item["camera"] == "SonyA7S2"


def test_eld_ratio_falls_back_to_nominal_without_metadata():
    assert ELD.exposure_ratio({"iso": None, "exposure_s": 1.0}, {"iso": 800.0, "exposure_s": 0.01}, 100.0) == 100.0
    assert ELD.exposure_ratio({"iso": 100.0, "exposure_s": 1.0}, {"iso": 800.0, "exposure_s": 0.00125}, 100.0) == pytest.approx(100.0)


def test_eld_bad_input(tmp_path):
    with pytest.raises(ValueError, match="ratios"):
        eld_pairs(tmp_path, "SonyA7S2", scenes=[1], ratios=[300])
    with pytest.raises(FileNotFoundError, match="scene-1"):
        eld_pairs(tmp_path, "SonyA7S2", scenes=[1], ratios=[100])


# ---------------------------------------------------------------- folders, bundled scenes, cache
def test_bundled_scenes_split_and_levels():
    train = CleanFolder(split="train")
    val = CleanFolder(split="val")
    assert len(train) == 4 and len(val) == 2
    assert not {p.name for p in train.entries} & {p.name for p in val.entries}
    for p in train.entries + val.entries:
        assert (BUNDLED_SCENES / p.name).is_file()
    item = train[0]
    assert item["target"].shape == (4, 512, 512) and item["target"].dtype.is_floating_point
    # normalized: black 12.5 -> 0, white 255 -> 1; some pixels are dark, some bright
    t = item["target"].numpy()
    assert -12.5 / 242.5 - 1e-6 <= t.min() < 0.1 and 0.3 < t.max() <= 1.0 + 1e-6
    for name in ("LICENSE-InfiniteISP", "LICENSE-Halide", "manifest.csv"):
        assert (BUNDLED_SCENES / name).is_file()
    total = sum(p.stat().st_size for p in BUNDLED_SCENES.iterdir())
    assert total < 6_500_000


def test_clean_folder_hints_window_and_repeat(tmp_path):
    rng = np.random.default_rng(3)
    mosaic = rng.integers(64, 1023, size=(40, 48), dtype=np.uint16)
    np.save(tmp_path / "a.npy", mosaic)
    (tmp_path / "notes.txt").write_text("not a frame")
    src = CleanFolder(str(tmp_path), cfa="GRBG", black_level=64, white_level=1023, repeat=3, window=8)
    assert len(src) == 3 and [p.name for p in src.entries] == ["a.npy"]
    item = src[2]
    assert item["target"].shape == (4, 8, 8)
    full = read_frame(tmp_path / "a.npy", cfa="GRBG", black_level=64, white_level=1023).packed_normalized()
    # the window is a sub-block of the full packed frame
    hits = [(i, j) for i in range(20 - 8 + 1) for j in range(24 - 8 + 1) if np.array_equal(full[:, i:i + 8, j:j + 8], item["target"].numpy())]
    assert len(hits) == 1
    with pytest.raises(ValueError, match="do not store|does not store"):
        CleanFolder(str(tmp_path))[0]
    with pytest.raises(FileNotFoundError):
        CleanFolder(str(tmp_path / "nope")).entries
    with pytest.raises(ValueError, match="repeat"):
        CleanFolder(str(tmp_path), repeat=0)


def test_noisy_folder_scales_by_ratio(tmp_path):
    mosaic = np.full((8, 8), 100, dtype=np.uint16)
    np.save(tmp_path / "n.npy", mosaic)
    item = NoisyFolder(str(tmp_path), ratio=50, cfa="RGGB", black_level=64, white_level=1023)[0]
    np.testing.assert_allclose(item["input"].numpy(), np.full((4, 4, 4), 36 / 959 * 50, np.float32), rtol=1e-6)


def test_frame_cache_reads_once_and_disk_cache_round_trips(tmp_path):
    path = tmp_path / "f.npz"
    rng = np.random.default_rng(4)
    write_frame(path, rng.integers(0, WHITE, (16, 16), dtype=np.uint16), iso=800.0, exposure_s=0.01)
    cache = FrameCache(tmp_path / "cache")
    a, meta = cache.get(path)
    assert cache.get(path)[0] is a and meta == {"iso": 800.0, "exposure_s": 0.01}
    again, meta2 = FrameCache(tmp_path / "cache").get(path)  # a new process: from the .npy cache
    assert isinstance(again, np.memmap) and meta2 == meta
    np.testing.assert_array_equal(np.asarray(again), a)
    assert len(list((tmp_path / "cache").glob("*.npy"))) == 1 and not list((tmp_path / "cache").glob("*.tmp"))


def test_epoch_shuffle_depends_on_seed_and_epoch_only():
    a, b = EpochShuffle(50, seed=3), EpochShuffle(50, seed=3)
    assert list(a) == list(b) and sorted(a) == list(range(50))
    first = list(a)
    a.set_epoch(1)
    assert list(a) != first
    b.set_epoch(1)
    assert list(a) == list(b)


def test_data_module_errors():
    with pytest.raises(ValueError, match="batch_size"):
        RawDenoiseData(batch_size=0)
    with pytest.raises(ValueError, match="'test'"):
        RawDenoiseData().test_dataloader()
    assert RawDenoiseData().val_dataloader() == []


def test_clean_folder_split_by_subfolder_or_none(tmp_path):
    from rawaug.train import CleanFolder

    for split in ("train", "val"):
        (tmp_path / split).mkdir()
        np.save(tmp_path / split / f"{split}0.npy", np.zeros((8, 8), dtype=np.uint16))
    np.save(tmp_path / "top.npy", np.zeros((8, 8), dtype=np.uint16))
    hints = {"cfa": "RGGB", "black_level": 0, "white_level": 1023}
    assert [p.name for p in CleanFolder(str(tmp_path), split="val", **hints).entries] == ["val0.npy"]
    assert [p.name for p in CleanFolder(str(tmp_path), split="None", **hints).entries] == ["top.npy"]
    with pytest.raises(ValueError, match="neither a manifest.csv.*set split to null"):
        CleanFolder(str(tmp_path), split="test", **hints).entries
