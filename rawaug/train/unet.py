"""The See-in-the-Dark U-Net (Chen et al., CVPR 2018) as used by ELD for raw-to-raw denoising.

Packed Bayer in (4 channels, normalized), packed Bayer out. Five levels of two 3x3
convolutions with LeakyReLU(0.2); max-pooling down, 2x2 transposed convolutions up,
skip connections by concatenation; a final 1x1 convolution. With ``base_channels=32``
the widths are 32, 64, 128, 256, 512 as in the paper; a smaller base gives a reduced
U-Net that trains on a CPU.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def _double_conv(c_in: int, c_out: int, slope: float) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, padding=1),
        nn.LeakyReLU(slope),
        nn.Conv2d(c_out, c_out, 3, padding=1),
        nn.LeakyReLU(slope),
    )


class UNet(nn.Module):
    """SID U-Net. Input and output ``(B, in_channels, H, W)``; any H, W (reflect-padded to
    a multiple of ``2**(depth-1)`` inside, cropped back on the way out).

    Args:
        in_channels, out_channels: 4 for packed Bayer (R, G1, B, G2).
        base_channels: width of the first level; level ``i`` has ``base * 2**i`` (32 -> 512 in the paper).
        depth: number of levels (5 in the paper).
        negative_slope: LeakyReLU slope (0.2 in the paper).
        residual: predict the correction to the input (``out = x + net(x)``, needs
            ``in_channels == out_channels``); not in the paper (its U-Net predicts the clean
            image directly), it makes short CPU runs converge faster.
    """

    def __init__(self, in_channels: int = 4, out_channels: int = 4, base_channels: int = 32, depth: int = 5, negative_slope: float = 0.2,
                 residual: bool = False) -> None:
        super().__init__()
        if residual and in_channels != out_channels:
            raise ValueError(f"residual=True needs in_channels == out_channels, got {in_channels} and {out_channels}")
        self.residual = bool(residual)
        for name, v in (("in_channels", in_channels), ("out_channels", out_channels), ("base_channels", base_channels)):
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if not isinstance(depth, int) or depth < 2:
            raise ValueError(f"depth must be an integer >= 2, got {depth!r}")
        widths = [base_channels * 2**i for i in range(depth)]
        self.depth = depth
        self.down = nn.ModuleList()
        c = in_channels
        for w in widths:
            self.down.append(_double_conv(c, w, negative_slope))
            c = w
        self.upsample = nn.ModuleList()
        self.up = nn.ModuleList()
        for w in reversed(widths[:-1]):
            self.upsample.append(nn.ConvTranspose2d(c, w, 2, stride=2))
            self.up.append(_double_conv(2 * w, w, negative_slope))
            c = w
        self.head = nn.Conv2d(c, out_channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4:
            raise ValueError(f"UNet input must be (B, C, H, W), got shape {tuple(x.shape)}")
        inp = x
        h, w = x.shape[-2:]
        m = 2 ** (self.depth - 1)
        ph, pw = (-h) % m, (-w) % m
        if ph or pw:
            mode = "reflect" if ph < h and pw < w else "replicate"
            x = F.pad(x, (0, pw, 0, ph), mode=mode)
        skips = []
        for i, block in enumerate(self.down):
            if i:
                x = F.max_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        skips.pop()
        for upsample, block in zip(self.upsample, self.up):
            x = block(torch.cat([upsample(x), skips.pop()], dim=1))
        out = self.head(x)[..., :h, :w]
        return inp + out if self.residual else out
