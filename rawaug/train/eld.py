"""The ELD dataset layout (Wei et al., CVPR 2020) and the authors' evaluation pairs.

Layout under ``root``: ``<camera>/scene-<n>/IMG_<k:04d>.<ext>`` (``.CR2``, ``.nef``,
``.ARW`` in the release; any extension ``read_frame`` supports is accepted).

Per scene, 16 frames: references at base ISO are ``IMG_0001, 0006, 0011, 0016``; between
them come the noisy frames of each ISO (800, 1600, 3200). The evaluation pairs follow the
authors' ``ELDEvalDataset``/``test_ELD.py``: inputs ``[4, 9, 14]`` for ratio x100 and
``[5, 10, 15]`` for x200; each input's reference is the nearest of ``[1, 6, 11, 16]``
(``argmin |k - ref|``, first on ties). The input is multiplied by
``ratio = (ISO * exposure of the reference) / (ISO * exposure of the input)`` from the
files' metadata (EXIF, or ``iso``/``exposure_s`` stored in an ``.npz``); when a file lacks
them the nominal ratio (100 or 200) is used. Results are labelled by the nominal ratio.
Scenes 1-10 are the paper's 10 indoor scenes.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .sources import Source, find_any_extension

REFERENCE_IDS = (1, 6, 11, 16)
INPUT_IDS = {100: (4, 9, 14), 200: (5, 10, 15)}


def reference_id(img_id: int) -> int:
    """The reference frame the authors pair with noisy frame ``img_id`` (nearest, first on ties)."""
    refs = np.array(REFERENCE_IDS)
    return int(refs[np.argmin(np.abs(int(img_id) - refs))])


def eld_pairs(root: str | Path, camera: str, scenes=range(1, 11), ratios=(100, 200)) -> list[dict]:
    """Evaluation pairs ``{input, target, ratio, scene, img_id}`` (paths) of one camera."""
    pairs = []
    for ratio in ratios:
        if int(ratio) not in INPUT_IDS:
            raise ValueError(f"ELD ratios are {sorted(INPUT_IDS)}, got {ratio!r}")
        for scene in scenes:
            folder = Path(root) / camera / f"scene-{int(scene)}"
            if not folder.is_dir():
                raise FileNotFoundError(f"ELD scene folder {str(folder)!r} does not exist: get the ELD data set "
                                        "(Wei et al., CVPR 2020) and set the source's root to "
                                        "the folder that holds <camera>/scene-<n>/")
            for img_id in INPUT_IDS[int(ratio)]:
                pairs.append({"input": find_any_extension(folder / f"IMG_{img_id:04d}"),
                              "target": find_any_extension(folder / f"IMG_{reference_id(img_id):04d}"),
                              "ratio": float(ratio), "scene": int(scene), "img_id": img_id})
    return pairs


class ELD(Source):
    """ELD evaluation pairs of one camera (real noisy input x ratio, base-ISO reference).

    Args:
        root: the folder holding ``<camera>/scene-<n>/``.
        camera: e.g. ``SonyA7S2``, ``NikonD850``, ``CanonEOS70D``, ``CanonEOS700D``.
        scenes: scene numbers (1-10 in the release).
        ratios: nominal low-light ratios to evaluate, from ``{100, 200}``.
    """

    def __init__(self, root: str, camera: str = "SonyA7S2", scenes: list[int] | None = None, ratios: list[int] | None = None) -> None:
        super().__init__(camera=camera)
        self.root = Path(root)
        self.scenes = list(range(1, 11)) if scenes is None else [int(s) for s in scenes]
        self.ratios = [100, 200] if ratios is None else [int(r) for r in ratios]

    def describe(self) -> str:
        return f"root={str(self.root)!r}, camera={self.camera!r}, scenes={self.scenes}, ratios={self.ratios}"

    def list_entries(self) -> list[dict]:
        return eld_pairs(self.root, self.camera, self.scenes, self.ratios)

    @staticmethod
    def exposure_ratio(target_meta: dict, input_meta: dict, nominal: float) -> float:
        """``(ISO * t)_reference / (ISO * t)_input`` from metadata, else ``nominal``."""
        values = [target_meta.get("iso"), target_meta.get("exposure_s"), input_meta.get("iso"), input_meta.get("exposure_s")]
        if any(v is None for v in values):
            return float(nominal)
        return float(values[0] * values[1] / (values[2] * values[3]))

    def load(self, entry: dict) -> dict:
        noisy, in_meta = self.cache.get(entry["input"])
        target, ref_meta = self.cache.get(entry["target"])
        scale = self.exposure_ratio(ref_meta, in_meta, entry["ratio"])
        return {"input": noisy * np.float32(scale), "target": target, "ratio": entry["ratio"],
                "name": f"scene-{entry['scene']}/IMG_{entry['img_id']:04d}"}
