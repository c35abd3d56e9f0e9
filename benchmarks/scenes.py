"""The benchmarks' clean scenes: three held-out real test scenes, and training scenes from the
other bundled real scenes plus the bundled photos, unprocessed (Brooks et al., CVPR 2019).

Test scenes: Outdoor4 (outdoor), Indoor1 (indoor), both 8-bit InfiniteISP crops, and HalideN900
(a 10-bit Nokia N900 crop, another sensor). Training scenes: Outdoor1-3 and the four public-domain /
CC0 photos of ``rawaug/data/photos`` turned into clean raw by ``rawaug.train.unprocess`` (gains
fixed by each photo's index). Everything is packed (R, G1, B, G2), normalized to [0, 1].
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from rawaug.io import read_frame
from rawaug.train import PhotoFolder

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "rawaug" / "data" / "scenes"
TRAIN_RAW = ["Outdoor1_1024x1024.npz", "Outdoor2_1024x1024.npz", "Outdoor3_1024x1024.npz"]
TEST_RAW = ["Outdoor4_1024x1024.npz", "Indoor1_1024x1024.npz", "HalideN900_256x344.npz"]


def load_scene(name: str) -> np.ndarray:
    """One bundled real scene, packed and normalized (its levels from the scenes' manifest)."""
    with open(SCENES / "manifest.csv") as f:
        rows = {r["file"]: r for r in csv.DictReader(line for line in f if not line.startswith("#"))}
    r = rows[name]
    frame = read_frame(SCENES / name, cfa=r["cfa"], black_level=float(r["black_level"]), white_level=float(r["white_level"]))
    return np.clip(frame.packed_normalized(), 0, 1).astype(np.float32)


def train_scenes(min_size: int = 0, piece: int | None = None) -> list[tuple[str, np.ndarray]]:
    """[(name, packed)] of the training scenes whose packed height and width are >= ``min_size``
    (a training crop must fit). With ``piece``, a scene is cut into ``h // piece`` x ``w // piece``
    equal pieces (at least one), so that drawing entries uniformly weighs scenes by their area."""
    photos = PhotoFolder()
    scenes = [(n.split("_")[0], load_scene(n)) for n in TRAIN_RAW]
    scenes += [(p.stem, photos[i]["target"].numpy()) for i, p in enumerate(photos.entries)]
    scenes = [(n, s) for n, s in scenes if min(s.shape[1:]) >= min_size]
    if piece is None:
        return scenes
    pieces = []
    for name, packed in scenes:
        _, h, w = packed.shape
        n_h, n_w = max(1, h // piece), max(1, w // piece)
        ph, pw = h // n_h, w // n_w
        pieces += [(f"{name}-{i}{j}" if n_h * n_w > 1 else name, packed[:, i * ph : (i + 1) * ph, j * pw : (j + 1) * pw])
                   for i in range(n_h) for j in range(n_w)]
    return pieces


def test_tiles(size: int, count: int) -> list[tuple[str, np.ndarray]]:
    """[(scene, tile)]: ``count`` packed tiles of ``size`` taken in turn from the test scenes
    (each scene's tiles spread over it; a scene out of tiles, or smaller than one, is skipped)."""
    per_scene = []
    for name in TEST_RAW:
        packed = load_scene(name)
        _, h, w = packed.shape
        grid = [packed[:, i : i + size, j : j + size] for i in range(0, h - size + 1, size) for j in range(0, w - size + 1, size)]
        per_scene.append([(name.split("_")[0], grid[k]) for k in _spread(len(grid))])
    tiles = []
    while len(tiles) < count and any(per_scene):
        for queue in per_scene:
            if queue and len(tiles) < count:
                tiles.append(queue.pop(0))
    return tiles


def _spread(n: int) -> list[int]:
    """0..n-1 in a golden-ratio stride (k * step mod n, step coprime to n near 0.618 n), so that
    the first few tiles of a row-major grid are spread over its rows and columns."""
    step = max(1, round(0.618 * n))
    while math.gcd(step, n) > 1:
        step += 1
    return [k * step % n for k in range(n)]
