"""The benchmarks' scene split (benchmarks/scenes.py): three held-out real test scenes, none of
them in training, and training pieces that keep every pixel of the scenes they come from."""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import scenes  # noqa: E402


def test_test_tiles_come_in_turn_from_three_held_out_scenes():
    tiles = scenes.test_tiles(128, 9)  # the ablation's CPU scale
    names = [n for n, _ in tiles]
    assert names == ["Outdoor4", "Indoor1", "HalideN900", "Outdoor4", "Indoor1", "Outdoor4", "Indoor1", "Outdoor4", "Indoor1"]
    assert all(t.shape == (4, 128, 128) for _, t in tiles)
    # the tiles of one scene are different regions of it
    for name in ("Outdoor4", "Indoor1"):
        mine = [t for n, t in tiles if n == name]
        assert all(not np.array_equal(a, b) for i, a in enumerate(mine) for b in mine[i + 1 :])
    # HalideN900 (128 x 172 packed) has one tile of 128 and none of 256
    assert [n for n, _ in scenes.test_tiles(256, 8)].count("HalideN900") == 0


def test_no_test_scene_is_trained_on_and_pieces_keep_the_pixels():
    assert not {n.split("_")[0] for n in scenes.TEST_RAW} & {n.split("_")[0] for n in scenes.TRAIN_RAW}
    whole = scenes.train_scenes()
    assert [n for n, _ in whole] == ["Outdoor1", "Outdoor2", "Outdoor3", "astronaut", "chelsea", "coffee", "rocket"]
    pieces = scenes.train_scenes(piece=256)
    assert len(pieces) == 3 * 4 + 4  # each 512 x 512 scene in four, each photo whole
    outdoor1 = dict(whole)["Outdoor1"]
    rebuilt = np.block([[dict(pieces)[f"Outdoor1-{i}{j}"] for j in range(2)] for i in range(2)])
    assert np.array_equal(rebuilt, outdoor1)
    assert [n for n, _ in scenes.train_scenes(min_size=256)] == ["Outdoor1", "Outdoor2", "Outdoor3", "astronaut"]


def test_every_benchmark_scale_tests_on_the_three_held_out_scenes():
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "ablation" / "run.py"
    sys.path.insert(0, str(path.parent))  # its own imports (testcam)
    spec = importlib.util.spec_from_file_location("ablation_run", path)  # not "run": the real-noise driver has that name
    ablation = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ablation)
    assert set(ablation.SCALES) >= {"cpu", "gpu", "gpu-short"}
    for name, scale in ablation.SCALES.items():
        if name == "smoke":
            continue
        names = {n for n, _ in scenes.test_tiles(scale["tile"], scale["test_tiles"])}
        assert names == {"Outdoor4", "Indoor1", "HalideN900"}, (name, names)
        assert len(scenes.train_scenes(min_size=scale["crop"])) >= 4, name  # the real training scenes and at least one photo
