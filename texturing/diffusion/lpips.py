"""LPIPS (Zhang et al. 2018, VGG variant) reading the ``lpips`` package's network layout.

The ``lpips`` package imports torchvision (which cannot be installed beside the CPU torch here),
so the network is defined with the same parameter names: ``net.slice1..5.N`` (torchvision's
``vgg16().features`` indices, split after relu1_2, relu2_2, relu3_3, relu4_3, relu5_3),
``lin0..4.model.1.weight`` (1 × 1 convolutions, no bias) and the ``scaling_layer`` buffers. A
checkpoint is the full ``lpips.LPIPS(net="vgg").state_dict()`` (backbone and linear layers).
"""

from __future__ import annotations

import os

import torch
from torch import nn

from facegeo.errors import InputError
from facegeo.torch_checkpoint import read_torch_file

__all__ = ["LPIPS", "load_lpips"]

#: torchvision VGG16 ``features``: output channels of each convolution, "M" = max-pool.
_VGG16 = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)
#: ``features`` index at which each of the five slices starts, and the end.
_SLICES = (0, 4, 9, 16, 23, 30)
_CHANNELS = (64, 128, 256, 512, 512)


class LPIPS(nn.Module):
    """``forward(x, y)``: (B, 3, H, W) images in [−1, 1] -> (B,) perceptual distances."""

    def __init__(self) -> None:
        super().__init__()
        self.scaling_layer = nn.Module()
        self.scaling_layer.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188])[None, :, None, None])
        self.scaling_layer.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450])[None, :, None, None])
        layers: list[nn.Module] = []
        channels = 3
        for v in _VGG16:
            if v == "M":
                layers.append(nn.MaxPool2d(2, 2))
            else:
                layers += [nn.Conv2d(channels, int(v), 3, padding=1), nn.ReLU(inplace=False)]
                channels = int(v)
        self.net = nn.Module()
        for k in range(5):
            block = nn.Sequential()
            for i in range(_SLICES[k], _SLICES[k + 1]):
                block.add_module(str(i), layers[i])
            setattr(self.net, f"slice{k + 1}", block)
        for k, c in enumerate(_CHANNELS):
            lin = nn.Module()
            lin.model = nn.Sequential(nn.Dropout(0.0), nn.Conv2d(c, 1, 1, bias=False))
            setattr(self, f"lin{k}", lin)
        self.requires_grad_(False)

    def _features(self, x: torch.Tensor) -> list[torch.Tensor]:
        h = (x - self.scaling_layer.shift) / self.scaling_layer.scale
        out = []
        for k in range(5):
            h = getattr(self.net, f"slice{k + 1}")(h)
            out.append(h / (h.pow(2).sum(1, keepdim=True).sqrt() + 1e-10))  # unit length per texel
        return out

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        total = x.new_zeros(x.shape[0])
        for k, (fx, fy) in enumerate(zip(self._features(x), self._features(y))):
            total = total + getattr(self, f"lin{k}").model((fx - fy) ** 2).mean(dim=(1, 2, 3))
        return total


def load_lpips(path: str | os.PathLike[str]) -> LPIPS:
    """:class:`LPIPS` from a state dict in the ``lpips`` package's layout.

    Raises:
        InputError: a missing or unreadable file, or missing/unexpected keys (named).
    """
    state = read_torch_file(path, "LPIPS checkpoint")
    model = LPIPS()
    expected = {k for k in model.state_dict() if not k.startswith("scaling_layer.")}  # constants
    found = set(state) if isinstance(state, dict) else set()
    if expected - found:
        raise InputError(path, "state dict", "the lpips package's VGG layout", f"missing {', '.join(sorted(expected - found)[:6])}")
    model.load_state_dict({k: state[k] for k in expected}, strict=False)
    return model.eval()
