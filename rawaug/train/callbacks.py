"""Callbacks of the training app."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from lightning.pytorch.callbacks import BasePredictionWriter


class DenoisedWriter(BasePredictionWriter):
    """Write each denoised frame of ``predict``: ``<output_dir>/<name>.npy`` (packed
    (4, H/2, W/2) float32, normalized: 0 = black, 1 = white, R, G1, B, G2 order) and/or
    ``<output_dir>/<name>.dng`` (a CFA DNG a raw developer opens: the input frame's CFA,
    black and white levels, ISO and exposure; codes rounded to whole DN). Atomic writes.

    Args:
        output_dir: where the files go.
        format: ``npy``, ``dng`` or ``both``.
    """

    def __init__(self, output_dir: str = "denoised", format: str = "npy") -> None:
        super().__init__(write_interval="batch")
        if format not in ("npy", "dng", "both"):
            raise ValueError(f"format must be 'npy', 'dng' or 'both', got {format!r}")
        self.output_dir = Path(output_dir)
        self.format = format

    def _frame_of(self, trainer, name: str):
        """The input frame called ``name`` (its levels, CFA and EXIF), read again from its file."""
        from ..io import read_frame

        source = trainer.datamodule.sources["predict"]
        paths = {Path(p).stem: p for p in source.entries}
        return read_frame(paths[name], **getattr(source, "hints", {}))

    def _write_dng(self, trainer, out: np.ndarray, name: str) -> None:
        from ..bayer import unpack
        from ..io.dng import write_dng

        frame = self._frame_of(trainer, name)
        black = frame.black_packed().astype(np.float64)
        span = frame.white_level - black
        codes = unpack(out * span[:, None, None] + black[:, None, None], frame.cfa)
        mosaic = np.clip(np.rint(codes), 0, frame.white_level).astype(np.uint16)
        write_dng(self.output_dir / f"{name}.dng", mosaic, cfa=frame.cfa, black_level=int(round(float(black.mean()))),
                  white_level=int(frame.white_level), iso=frame.iso, exposure_s=frame.exposure_s,
                  camera="rawaug denoised")

    def write_on_batch_end(self, trainer, pl_module, prediction, batch_indices, batch, batch_idx, dataloader_idx=0):
        self.output_dir.mkdir(parents=True, exist_ok=True)
        for out, name in zip(prediction["output"], prediction["name"]):
            if self.format in ("dng", "both"):
                self._write_dng(trainer, out.detach().cpu().float().numpy(), Path(str(name)).name)
            if self.format == "dng":
                continue
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
