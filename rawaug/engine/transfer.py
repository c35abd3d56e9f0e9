"""Host-to-device moves of a call's small tensors without a host synchronization."""
from __future__ import annotations

import torch


def _on(t: torch.Tensor, device: torch.device) -> bool:
    return t.device.type == device.type and (device.index is None or t.device.index == device.index)


def to_device(tensors, device):
    """Move small host tensors of 8-byte dtypes (the (B, P) float64 parameters, the int64
    stream keys) to ``device`` in one non-blocking copy from pinned memory: one memcpy and
    no host synchronization on CUDA, where a copy from pageable memory waits for the
    device. Tensors already on ``device`` are returned as they are. Takes one tensor or a
    sequence and returns the same."""
    device = torch.device(device)
    single = isinstance(tensors, torch.Tensor)
    items = [tensors] if single else list(tensors)
    moving = [i for i, t in enumerate(items) if not _on(t, device)]
    if moving:
        for i in moving:
            if items[i].element_size() != 8:
                raise ValueError(f"to_device packs 8-byte dtypes only, got {items[i].dtype}")
        sizes = [items[i].numel() for i in moving]
        host = torch.empty(sum(sizes), dtype=torch.int64, pin_memory=device.type == "cuda")
        offset = 0
        for i, n in zip(moving, sizes):
            host[offset:offset + n] = items[i].detach().cpu().contiguous().view(torch.int64).reshape(-1)
            offset += n
        moved = host.to(device, non_blocking=True)
        offset = 0
        for i, n in zip(moving, sizes):
            items[i] = moved[offset:offset + n].view(items[i].dtype).view(items[i].shape)
            offset += n
    return items[0] if single else tuple(items)
