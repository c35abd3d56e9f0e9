"""The data module: clean (or real noisy) packed frames from any source, loaded once.

It only loads and batches; crops, flips, rotations and the synthetic noise are made on
the device by :class:`~rawaug.train.module.DenoiseModule`.
"""
from __future__ import annotations

import lightning as L
import torch
from torch.utils.data import DataLoader, Sampler

from .cache import FrameCache
from .sources import Source


class EpochShuffle(Sampler):
    """A random permutation that depends only on ``(seed, epoch)``; Lightning calls
    ``set_epoch``, so a run resumed from a checkpoint sees the same order as an unbroken one."""

    def __init__(self, length: int, seed: int = 0) -> None:
        self.length, self.seed, self.epoch = int(length), int(seed), 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __iter__(self):
        gen = torch.Generator().manual_seed(self.seed * 1_000_003 + self.epoch)
        return iter(torch.randperm(self.length, generator=gen).tolist())

    def __len__(self) -> int:
        return self.length


class RawDenoiseData(L.LightningDataModule):
    """Training, validation, test and prediction sources for the denoiser.

    Args:
        train: frames to train on: clean-only sources (``CleanFolder``, ``SIDSony`` in
            ``clean`` mode) get synthetic noise on the device; sources with real noisy
            inputs (``SIDSony`` ``paired``/``noise2noise``) train on those.
        val, test: evaluation sources; clean-only ones are evaluated at the model's fixed
            evaluation noise, real pairs as they are.
        predict: a ``NoisyFolder`` (or any source with inputs) to denoise.
        batch_size: training batch size (1 in the paper); whole frames are stacked, so
            frames of different sizes need the source's ``window``.
        num_workers: data-loader worker processes.
        cache_dir: also keep the decoded packed frames here as ``.npy`` (memory-mapped later).
        seed: seed of the training order (epoch-wise, exact on resume).
    """

    def __init__(self, train: Source | None = None, val: Source | None = None, test: Source | None = None, predict: Source | None = None,
                 batch_size: int = 1, num_workers: int = 0, cache_dir: str | None = None, seed: int = 0) -> None:
        super().__init__()
        if not isinstance(batch_size, int) or batch_size < 1:
            raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
        if not isinstance(num_workers, int) or num_workers < 0:
            raise ValueError(f"num_workers must be a non-negative integer, got {num_workers!r}")
        self.cache = FrameCache(cache_dir)
        self.sources = {"train": train, "val": val, "test": test, "predict": predict}
        for source in self.sources.values():
            if source is not None:
                source.bind(self.cache)
        self.batch_size, self.num_workers, self.seed = batch_size, num_workers, seed

    def _source(self, stage: str) -> Source:
        source = self.sources[stage]
        if source is None:
            raise ValueError(f"no {stage!r} source configured: set data.init_args.{stage} in the config")
        return source

    def _loader(self, dataset, **kw) -> DataLoader:
        return DataLoader(dataset, num_workers=self.num_workers, persistent_workers=self.num_workers > 0, **kw)

    def train_dataloader(self) -> DataLoader:
        dataset = self._source("train")
        distributed = self.trainer is not None and self.trainer.world_size > 1
        if distributed:  # Lightning swaps in a DistributedSampler (epoch-seeded)
            return self._loader(dataset, batch_size=self.batch_size, shuffle=True)
        return self._loader(dataset, batch_size=self.batch_size, sampler=EpochShuffle(len(dataset), self.seed))

    def val_dataloader(self) -> DataLoader | list:
        if self.sources["val"] is None:
            return []  # no validation
        return self._loader(self._source("val"), batch_size=1)

    def test_dataloader(self) -> DataLoader:
        return self._loader(self._source("test"), batch_size=1)

    def predict_dataloader(self) -> DataLoader:
        return self._loader(self._source("predict"), batch_size=1)
