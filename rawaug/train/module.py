"""DenoiseModule: the ELD training recipe as a LightningModule.

Training batch (on the device, in ``on_after_batch_transfer``): random ``crop_size`` crops,
flips and 90-degree rotations (kornia), then for clean-only data the noisy input is
synthesized by :class:`rawaug.RawNoiseAugment` (normalized units, already multiplied back
by the low-light ratio); the network maps noisy -> clean with an L1 loss.

Every random draw of a training step is seeded from ``(seed, global_step, rank)``, so a run
resumed from a checkpoint continues exactly as an unbroken run, and every DDP rank draws
different crops and noise.
"""
from __future__ import annotations

import warnings

# The noise is applied in the module's on_after_batch_transfer on purpose (the module owns
# the noise model; every datamodule gets it): Lightning's notice that the module's hook is
# used rather than the datamodule's says nothing a user must act on.
warnings.filterwarnings("ignore", message="You have overridden `on_after_batch_transfer` in `LightningModule`")

import math
import zlib
from pathlib import Path

import kornia.augmentation as KA
import lightning as L
import torch
import torch.distributed as dist
import torch.nn.functional as F
from lightning.pytorch.loggers import TensorBoardLogger

from ..augment import RawNoiseAugment, _rank
from ..profile import NoiseProfile
from .metrics import ResultsTable, centre_crop, evaluate
from .unet import UNet


def packed_to_preview(x: torch.Tensor, size: int) -> torch.Tensor:
    """Packed (4, h, w) normalized -> (3, s, s) RGB preview (R, mean G, B; gamma 1/2.2; centre crop)."""
    x = centre_crop(x, size).clamp(0, 1)
    rgb = torch.stack([x[0], 0.5 * (x[1] + x[3]), x[2]])
    return rgb.pow(1 / 2.2)


def _lr_factor(epoch: int, milestones: list[int], factors: list[float]) -> float:
    factor = 1.0
    for m, f in zip(milestones, factors):
        if epoch >= m:
            factor = f
    return factor


class DenoiseModule(L.LightningModule):
    """U-Net raw denoiser trained on on-device synthetic (or real) noise.

    Args:
        base_channels, depth: U-Net widths ``base * 2**i`` over ``depth`` levels (32, 5 in the paper).
        residual: the U-Net predicts the correction to its input (not in the paper; faster to train).
        profile: noise profile (built-in camera name or profile file).
        noise_model: noise components, e.g. ``G``, ``G+P``, ``G+P*``, ``G*+P*``, ``G*+P*+R``, ``G*+P*+R+U``
            (the paper's rows), ``+C`` for the colour bias (for a denoiser of one gain); default:
            the profile's fullest model (``NoiseProfile.richest_model``: ``G*+P*+R+U``, or
            ``G+P*+U`` for a Poisson-Gaussian profile).
        profile_effects: extra effects ``{token: params}`` added to the profile (as the closed loop
            writes them); effects already in the profile are used anyway (``include_profile_effects``).
        ratio: training low-light ratio, a number or ``[low, high]`` (default ``[100, 300]``).
        k, iso: fix the training gain K (DN/e-, number or ``[low, high]``) or ISO; default the
            profile's calibrated range.
        exposure_s: exposure of the noisy (short) frames in seconds, for the profile's dark
            current (``Dark``) and amplifier glow (``Glow``); default ``None``: no dark signal.
        crop_size: training crop, packed pixels (512 in the paper).
        flip, rotate: random flips / 90-degree rotations of the crops.
        clip_input: clip the noisy input to [0, 1] as the ELD evaluation does with real data.
        loss: ``l1`` (paper) or ``l2``.
        lr, lr_milestones, lr_factors: Adam learning rate; at each milestone (fraction of
            ``max_epochs``, or of ``max_steps`` when only a step budget is set) the rate becomes
            ``lr * factor`` (paper: 0.5 at 100/200, 0.1 at 180/200).
        eval_iso, eval_k, eval_ratio, eval_seed: the fixed noise at which clean-only validation
            and test frames are evaluated (same noise every epoch and run).
        eval_crop: evaluate centre crops of this size (packed pixels); ``None`` = whole frames.
        seed: seed of the training crops and noise.
        results_dir: where results tables go (default: the logger's folder).
        image_log_size: side of the noisy/denoised/target previews logged to TensorBoard (0 = none).
    """

    def __init__(self, base_channels: int = 32, depth: int = 5, residual: bool = False, profile: str = "SonyA7S2", noise_model: str | None = None,
                 profile_effects: dict | None = None, include_profile_effects: bool = True,
                 ratio: float | list[float] | None = None, k: float | list[float] | None = None, iso: float | None = None,
                 exposure_s: float | None = None, crop_size: int = 512, flip: bool = True, rotate: bool = True, clip_input: bool = True, loss: str = "l1",
                 lr: float = 1e-4, lr_milestones: list[float] | None = None, lr_factors: list[float] | None = None,
                 eval_iso: float | None = 1600.0, eval_k: float | None = None, eval_ratio: float = 100.0, eval_seed: int = 0,
                 eval_crop: int | None = None, seed: int = 0, results_dir: str | None = None, image_log_size: int = 256) -> None:
        super().__init__()
        self.save_hyperparameters()
        lr_milestones = [0.5, 0.9] if lr_milestones is None else list(lr_milestones)
        lr_factors = [0.5, 0.1] if lr_factors is None else list(lr_factors)
        if len(lr_milestones) != len(lr_factors) or any(not 0 < m <= 1 for m in lr_milestones) or sorted(lr_milestones) != lr_milestones:
            raise ValueError(f"lr_milestones must be increasing fractions of max_epochs in (0, 1] with one lr_factor each, got {lr_milestones} and {lr_factors}")
        if any(not f > 0 for f in lr_factors) or not lr > 0:
            raise ValueError(f"lr and lr_factors must be > 0, got lr={lr}, lr_factors={lr_factors}")
        if not isinstance(crop_size, int) or crop_size < 2 ** (depth - 1):
            raise ValueError(f"crop_size must be an integer >= {2 ** (depth - 1)} (packed pixels), got {crop_size!r}")
        if loss not in ("l1", "l2"):
            raise ValueError(f"loss must be 'l1' or 'l2', got {loss!r}")
        self.lr_milestones, self.lr_factors = lr_milestones, lr_factors
        self.net = UNet(4, 4, base_channels=base_channels, depth=depth, residual=residual)
        noise_profile = NoiseProfile.load(profile)
        for token, params in (profile_effects or {}).items():
            noise_profile = noise_profile.with_effect(token, params or {})
        common = dict(profile=noise_profile, model=noise_model, include_profile_effects=include_profile_effects,
                      fixed=None if exposure_s is None else {"exposure_s": exposure_s})
        self.noise = RawNoiseAugment(**common, ratio=(100.0, 300.0) if ratio is None else ratio, k=k, iso=iso)
        eval_fixed_k = eval_k if eval_k is not None else (noise_profile.k_at_iso(eval_iso) if eval_iso is not None else None)
        self.eval_noise = RawNoiseAugment(**common, ratio=eval_ratio, k=eval_fixed_k, rank_seeding=False)
        geometric = [KA.RandomCrop((crop_size, crop_size))]
        if flip:
            geometric += [KA.RandomHorizontalFlip(), KA.RandomVerticalFlip()]
        if rotate:
            geometric += [KA.RandomRotation90(times=(0, 3), resample="nearest", p=1.0)]
        self.geometric = KA.AugmentationSequential(*geometric)
        self._tables: dict[str, ResultsTable] = {}

    # ------------------------------------------------------------------ network
    def forward(self, noisy: torch.Tensor) -> torch.Tensor:
        """Packed normalized noisy ``(B, 4, H, W)`` (already x ratio) -> denoised, same shape."""
        return self.net(noisy)

    # ------------------------------------------------------------------ on-device batch making
    def _step_seed(self) -> int:
        return (int(self.hparams.seed) * 1_000_003 + int(self.global_step) * 7919 + _rank() * 104_729) % (2**63 - 1)

    def make_training_pair(self, batch: dict, seed: int) -> dict:
        """Crop/flip/rotate the batch and, for clean-only data, synthesize the noisy input.
        All draws come from ``seed`` (bit-exact replay); returns ``{"input", "target"}``."""
        target = batch["target"].clamp(0, 1)
        size = self.hparams.crop_size
        if min(target.shape[-2:]) < size:
            raise ValueError(f"training frames are {tuple(target.shape[-2:])} packed pixels, smaller than crop_size {size}")
        real = "input" in batch
        x = torch.cat([batch["input"], target], 1) if real else target
        devices = [x.device.index or 0] if x.device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            torch.manual_seed(seed)
            x = self.geometric(x)
            if real:
                noisy, target = x[:, :4], x[:, 4:]
            else:
                target = x
                noisy = self.noise(target)
        if self.hparams.clip_input:
            noisy = noisy.clamp(0, 1)
        return {"input": noisy, "target": target}

    def eval_input(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """(noisy, target) for evaluation: real pairs as given; clean-only frames get the fixed
        evaluation noise, seeded by the frame's name (the same noise in every epoch and run)."""
        target = centre_crop(batch["target"], self.hparams.eval_crop).clamp(0, 1)
        if "input" in batch:
            noisy = centre_crop(batch["input"], self.hparams.eval_crop)
        else:
            noisy = torch.empty_like(target)
            for i, name in enumerate(batch["name"]):
                seed = int(self.hparams.eval_seed) * 1_000_003 + zlib.crc32(str(name).encode())
                params = self.eval_noise.draw_parameters(1, target.device, seed=seed, shape=target.shape[-2:])
                noisy[i : i + 1] = self.eval_noise(target[i : i + 1], params=params)
        if self.hparams.clip_input:
            noisy = noisy.clamp(0, 1)
        return noisy, target

    def on_after_batch_transfer(self, batch, dataloader_idx: int):
        if self.trainer is not None and self.trainer.training:
            return {**batch, **self.make_training_pair(batch, self._step_seed())}
        return batch

    # ------------------------------------------------------------------ steps
    def training_step(self, batch, batch_idx):
        out = self(batch["input"])
        loss = F.l1_loss(out, batch["target"]) if self.hparams.loss == "l1" else F.mse_loss(out, batch["target"])
        self.log("train/loss", loss, prog_bar=True, batch_size=out.shape[0])
        return loss

    def _evaluate_batch(self, batch, stage: str, batch_idx: int) -> None:
        noisy, target = self.eval_input(batch)
        out = self(noisy)
        got, base = evaluate(out, target), evaluate(noisy, target)
        n = out.shape[0]
        for key, values in (("psnr", got["psnr"]), ("ssim", got["ssim"]), ("psnr_noisy", base["psnr"]), ("ssim_noisy", base["ssim"])):
            self.log(f"{stage}/{key}", values.mean(), batch_size=n, sync_dist=True, prog_bar=key == "psnr")
        table = self._tables.setdefault(stage, ResultsTable())
        for i in range(n):
            ratio = float(batch["ratio"][i]) or float(self.hparams.eval_ratio)
            table.add(batch["camera"][i] or self.noise.profile.camera, ratio, batch["name"][i],
                      base["psnr"][i], base["ssim"][i], got["psnr"][i], got["ssim"][i])
        if batch_idx == 0 and stage == "val":
            self._log_images(noisy[0], out[0], target[0])

    def validation_step(self, batch, batch_idx):
        self._evaluate_batch(batch, "val", batch_idx)

    def test_step(self, batch, batch_idx):
        self._evaluate_batch(batch, "test", batch_idx)

    def predict_step(self, batch, batch_idx, dataloader_idx: int = 0):
        noisy = batch["input"].clamp(0, 1) if self.hparams.clip_input else batch["input"]
        return {"output": self(noisy).clamp(0, 1), "name": batch["name"]}

    # ------------------------------------------------------------------ results
    def on_validation_epoch_start(self) -> None:
        self._tables.pop("val", None)

    def on_test_epoch_start(self) -> None:
        self._tables.pop("test", None)

    def on_validation_epoch_end(self) -> None:
        if not self.trainer.sanity_checking:
            self._finish_table("val", f"epoch {self.current_epoch}")

    def on_test_epoch_end(self) -> None:
        self._finish_table("test", "test")

    def _gathered_rows(self, stage: str) -> list[dict]:
        rows = self._tables.get(stage, ResultsTable()).rows
        if dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1:
            parts = [None] * dist.get_world_size()
            dist.all_gather_object(parts, rows)
            rows = [r for part in parts for r in part]
        return rows

    def _finish_table(self, stage: str, label: str) -> None:
        table = ResultsTable()
        table.rows = self._gathered_rows(stage)
        if not table.rows or self.global_rank != 0:
            return
        directory = Path(self.hparams.results_dir or (self.trainer.log_dir or self.trainer.default_root_dir))
        csv_path, _ = table.write(directory, f"{stage}_results")
        for r in table.summary():
            self.print(f"[{label}] {stage} {r['camera']} x{r['ratio']} ({r['images']} images): noisy input PSNR {r['psnr_noisy_db']:.2f} dB "
                       f"SSIM {r['ssim_noisy']:.4f} -> denoised PSNR {r['psnr_db']:.2f} dB SSIM {r['ssim']:.4f}")
        self.print(f"[{label}] {stage} results table: {csv_path} (.md beside it)")

    def _log_images(self, noisy, out, target) -> None:
        size = int(self.hparams.image_log_size)
        if size <= 0 or not isinstance(self.logger, TensorBoardLogger) or self.global_rank != 0:
            return
        grid = torch.cat([packed_to_preview(t.detach().float(), size) for t in (noisy, out, target)], dim=-1)
        self.logger.experiment.add_image("val/noisy_denoised_target", grid.cpu(), self.global_step)

    # ------------------------------------------------------------------ optimization
    def _lr_at(self, position: int, budget) -> float:
        """``lr`` times the factor of the last milestone (fraction of ``budget``) reached by
        ``position``; constant without a budget."""
        if not budget or budget < 0:
            return float(self.hparams.lr)
        marks = [max(1, math.ceil(m * budget - 1e-9)) for m in self.lr_milestones]
        return float(self.hparams.lr) * _lr_factor(int(position), marks, self.lr_factors)

    def lr_at_epoch(self, epoch: int) -> float:
        """The learning rate of an epoch, milestones as fractions of ``max_epochs``."""
        return self._lr_at(epoch, self._trainer.max_epochs if self._trainer is not None else None)

    def lr_at_step(self, step: int) -> float:
        """The learning rate at a step, milestones as fractions of ``max_steps`` (used when the
        trainer has a step budget and no epoch budget)."""
        return self._lr_at(step, self._trainer.max_steps if self._trainer is not None else None)

    def _step_budget(self) -> bool:
        t = self._trainer
        return t is not None and (not t.max_epochs or t.max_epochs < 0) and t.max_steps is not None and t.max_steps > 0

    def _set_lr(self, lr: float) -> None:
        for optimizer in self.trainer.optimizers:
            for group in optimizer.param_groups:
                group["lr"] = lr

    def on_train_epoch_start(self) -> None:
        # Set from the epoch (or step) number, not by stepping a scheduler: exact after a resume.
        if self._step_budget():
            return
        lr = self.lr_at_epoch(self.current_epoch)
        self._set_lr(lr)
        self.log("train/lr", lr, on_step=False, on_epoch=True, batch_size=1)

    def on_train_batch_start(self, batch, batch_idx) -> None:
        if self._step_budget():
            lr = self.lr_at_step(self.global_step)
            self._set_lr(lr)
            self.log("train/lr", lr, on_step=True, on_epoch=False, batch_size=1)

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.lr_at_step(0) if self._step_budget() else self.lr_at_epoch(0))
