"""Callbacks of the training app."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from lightning.pytorch.callbacks import BasePredictionWriter


class DenoisedWriter(BasePredictionWriter):
    """Write each denoised frame of ``predict`` as ``<output_dir>/<name>.npy``: packed
    (4, H/2, W/2) float32, normalized (0 = black, 1 = white), R, G1, B, G2 order. Atomic writes."""

    def __init__(self, output_dir: str = "denoised") -> None:
        super().__init__(write_interval="batch")
        self.output_dir = Path(output_dir)

    def write_on_batch_end(self, trainer, pl_module, prediction, batch_indices, batch, batch_idx, dataloader_idx=0):
        self.output_dir.mkdir(parents=True, exist_ok=True)
        for out, name in zip(prediction["output"], prediction["name"]):
            path = self.output_dir / f"{Path(str(name)).name}.npy"
            fd, tmp = tempfile.mkstemp(dir=self.output_dir, prefix=f".{path.name}.", suffix=".tmp")
            try:
                with os.fdopen(fd, "wb") as f:
                    np.save(f, out.detach().cpu().float().numpy())
                os.replace(tmp, path)
            except BaseException:
                if os.path.exists(tmp):
                    os.unlink(tmp)
                raise
