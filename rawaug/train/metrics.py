"""Evaluation as in the ELD paper: least-squares brightness correction, then PSNR and SSIM
on the packed raw (normalized, data range 1); results tables per camera and ratio."""
from __future__ import annotations

import csv
import io
import os
from collections import defaultdict
from pathlib import Path

import torch
from kornia.metrics import ssim as _kornia_ssim

from ..atomic import write_text_atomic


def _check_pair(output: torch.Tensor, target: torch.Tensor) -> None:
    if output.shape != target.shape or output.ndim != 4:
        raise ValueError(f"output and target must both be (B, C, H, W) of one shape, got {tuple(output.shape)} and {tuple(target.shape)}")


def fit_scale(output: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per image, the scalar ``a = <out, target> / <out, out>`` minimizing ``||a out - target||^2``.

    Accounts for shutter-speed and analog-gain imprecision between a noisy frame and its
    reference (ELD Sec. 6.2). Returns ``(B,)``; 1 where the output is all zeros.
    """
    _check_pair(output, target)
    o = output.flatten(1).double()
    t = target.flatten(1).double()
    num = (o * t).sum(1)
    den = (o * o).sum(1)
    return torch.where(den > 0, num / den.clamp_min(1e-300), torch.ones_like(den)).to(output.dtype)


def corrected(output: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``clip(output, 0, 1)`` scaled by :func:`fit_scale` and clipped to [0, 1] again."""
    out = output.clamp(0, 1)
    a = fit_scale(out, target)
    return (a.view(-1, 1, 1, 1) * out).clamp(0, 1)


def psnr(output: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-image PSNR in dB for data range 1, ``(B,)``; +inf for identical images."""
    _check_pair(output, target)
    mse = ((output.double() - target.double()) ** 2).flatten(1).mean(1)
    return (-10.0 * torch.log10(mse)).to(torch.float32)


def ssim(output: torch.Tensor, target: torch.Tensor, window_size: int = 11) -> torch.Tensor:
    """Per-image SSIM (Gaussian window 11, sigma 1.5, data range 1), computed per channel
    over the valid region and averaged over channels and pixels, ``(B,)``."""
    _check_pair(output, target)
    if min(output.shape[-2:]) < window_size:
        raise ValueError(f"SSIM needs images of at least {window_size}x{window_size} pixels, got {tuple(output.shape[-2:])}")
    m = _kornia_ssim(output.float(), target.float(), window_size, max_val=1.0, padding="valid")
    return m.flatten(1).mean(1)


def evaluate(output: torch.Tensor, target: torch.Tensor) -> dict[str, torch.Tensor]:
    """ELD protocol: brightness-correct the clipped output, then PSNR and SSIM, per image."""
    out = corrected(output, target)
    tgt = target.clamp(0, 1)
    return {"psnr": psnr(out, tgt), "ssim": ssim(out, tgt)}


def centre_crop(x: torch.Tensor, size: int | None) -> torch.Tensor:
    """Central ``size x size`` region of ``(..., H, W)``; the whole image if ``size`` is None or larger."""
    if size is None:
        return x
    h, w = x.shape[-2:]
    sh, sw = min(size, h), min(size, w)
    top, left = (h - sh) // 2, (w - sw) // 2
    return x[..., top : top + sh, left : left + sw]


class ResultsTable:
    """Per-image metric rows, summarized as mean per (camera, ratio) group."""

    COLUMNS = ("camera", "ratio", "images", "psnr_noisy_db", "ssim_noisy", "psnr_db", "ssim")

    def __init__(self) -> None:
        self.rows: list[dict] = []

    def add(self, camera: str, ratio: float, name: str, psnr_noisy: float, ssim_noisy: float, psnr_db: float, ssim_val: float) -> None:
        self.rows.append(dict(camera=str(camera), ratio=float(ratio), name=str(name), psnr_noisy_db=float(psnr_noisy), ssim_noisy=float(ssim_noisy), psnr_db=float(psnr_db), ssim=float(ssim_val)))

    def summary(self) -> list[dict]:
        groups: dict[tuple, list[dict]] = defaultdict(list)
        for r in self.rows:
            groups[(r["camera"], round(r["ratio"]))].append(r)
        out = []
        for (camera, ratio), rows in sorted(groups.items()):
            mean = lambda key: sum(r[key] for r in rows) / len(rows)  # noqa: E731
            out.append(dict(camera=camera, ratio=ratio, images=len(rows), psnr_noisy_db=mean("psnr_noisy_db"), ssim_noisy=mean("ssim_noisy"), psnr_db=mean("psnr_db"), ssim=mean("ssim")))
        return out

    def to_csv(self) -> str:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=self.COLUMNS, lineterminator="\n")
        writer.writeheader()
        for row in self.summary():
            writer.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in row.items()})
        return buf.getvalue()

    def to_markdown(self) -> str:
        lines = ["| camera | ratio | images | noisy PSNR (dB) | noisy SSIM | PSNR (dB) | SSIM |", "|---|---|---|---|---|---|---|"]
        for r in self.summary():
            lines.append(f"| {r['camera']} | x{r['ratio']} | {r['images']} | {r['psnr_noisy_db']:.2f} | {r['ssim_noisy']:.4f} | {r['psnr_db']:.2f} | {r['ssim']:.4f} |")
        return "\n".join(lines) + "\n"

    def write(self, directory: str | os.PathLike, stem: str = "results") -> tuple[Path, Path]:
        """Write ``<stem>.csv`` and ``<stem>.md`` atomically; returns their paths."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        paths = directory / f"{stem}.csv", directory / f"{stem}.md"
        for path, text in zip(paths, (self.to_csv(), self.to_markdown())):
            write_text_atomic(path, text)
        return paths


