"""Real-ESRGAN super-resolution (the paper's Sec. 3.5): an RRDBNet that reads the official
checkpoints, run in overlapping tiles so a 4K output fits CPU memory.

Why our own network: ``realesrgan``/``basicsr`` and ``spandrel`` import torchvision at module
level, and torchvision's only wheel for the project's torch 2.13.0 CPU is a CUDA build that breaks
transformers/peft imports. Making spandrel import without it means faking a ``torchvision``
module; the RRDBNet generator itself is ~40 lines of convolutions, so it is written here with the
official parameter names (``conv_first``, ``body.N.rdbK.convM``, ``conv_body``, ``conv_up1/2``,
``conv_hr``, ``conv_last``) and loads ``RealESRGAN_x4plus.pth`` (``params_ema`` wrapper) as is.
"""

from __future__ import annotations

import os

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from facegeo.errors import InputError
from facegeo.torch_checkpoint import read_torch_file

__all__ = ["RRDBNet", "load_realesrgan", "upscale_tiled"]


class _RDB(nn.Module):
    """Residual dense block: five 3 × 3 convolutions, each seeing all previous outputs."""

    def __init__(self, feat: int, grow: int):
        super().__init__()
        for i in range(5):
            setattr(self, f"conv{i + 1}", nn.Conv2d(feat + i * grow, grow if i < 4 else feat, 3, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        feats = [x]
        for i in range(4):
            feats.append(F.leaky_relu(getattr(self, f"conv{i + 1}")(torch.cat(feats, 1)), 0.2))
        return self.conv5(torch.cat(feats, 1)) * 0.2 + x


class _RRDB(nn.Module):
    def __init__(self, feat: int, grow: int):
        super().__init__()
        self.rdb1, self.rdb2, self.rdb3 = _RDB(feat, grow), _RDB(feat, grow), _RDB(feat, grow)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.rdb3(self.rdb2(self.rdb1(x))) * 0.2 + x


class RRDBNet(nn.Module):
    """ESRGAN's generator ×``scale`` (4, 2 or 1; 2 and 1 pixel-unshuffle the input first, as
    Real-ESRGAN does). Input/output (B, C, H, W) in [0, 1]; output (B, C, scale·H, scale·W)."""

    def __init__(self, in_ch: int = 3, out_ch: int = 3, scale: int = 4, feat: int = 64, blocks: int = 23, grow: int = 32):
        super().__init__()
        if scale not in (1, 2, 4):
            raise ValueError(f"scale: expected 1, 2 or 4, got {scale}")
        self.scale = scale
        self.conv_first = nn.Conv2d(in_ch * {4: 1, 2: 4, 1: 16}[scale], feat, 3, 1, 1)
        self.body = nn.Sequential(*[_RRDB(feat, grow) for _ in range(blocks)])
        self.conv_body = nn.Conv2d(feat, feat, 3, 1, 1)
        self.conv_up1 = nn.Conv2d(feat, feat, 3, 1, 1)
        self.conv_up2 = nn.Conv2d(feat, feat, 3, 1, 1)
        self.conv_hr = nn.Conv2d(feat, feat, 3, 1, 1)
        self.conv_last = nn.Conv2d(feat, out_ch, 3, 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.scale < 4:
            x = F.pixel_unshuffle(x, 4 // self.scale)
        feat = self.conv_first(x)
        feat = feat + self.conv_body(self.body(feat))
        feat = F.leaky_relu(self.conv_up1(F.interpolate(feat, scale_factor=2, mode="nearest")), 0.2)
        feat = F.leaky_relu(self.conv_up2(F.interpolate(feat, scale_factor=2, mode="nearest")), 0.2)
        return self.conv_last(F.leaky_relu(self.conv_hr(feat), 0.2))


def load_realesrgan(path: str | os.PathLike[str], scale: int = 4) -> RRDBNet:
    """An :class:`RRDBNet` from an official Real-ESRGAN checkpoint (``params_ema`` or
    ``params`` wrapper, or a bare state dict); widths and depth are read from the weights.

    Raises:
        InputError: a missing or unreadable file, or one without the RRDBNet keys.
    """
    state = read_torch_file(path, "Real-ESRGAN checkpoint")
    for wrapper in ("params_ema", "params"):
        if isinstance(state, dict) and wrapper in state:
            state = state[wrapper]
            break
    if not isinstance(state, dict) or "conv_first.weight" not in state or "body.0.rdb1.conv1.weight" not in state:
        raise InputError(path, "state dict", "RRDBNet keys (conv_first, body.N.rdbK.convM, ...)", "other keys")
    feat, in_total = state["conv_first.weight"].shape[:2]
    out_ch = state["conv_last.weight"].shape[0]
    blocks = 1 + max(int(k.split(".")[1]) for k in state if k.startswith("body."))
    grow = state["body.0.rdb1.conv1.weight"].shape[0]
    in_ch = in_total // {4: 1, 2: 4, 1: 16}[scale]
    net = RRDBNet(in_ch, out_ch, scale, feat, blocks, grow)
    net.load_state_dict(state, strict=True)
    return net.eval()


@torch.no_grad()
def upscale_tiled(net: RRDBNet, image: np.ndarray, tile: int = 128, pad: int = 16) -> np.ndarray:
    """(H, W, C) float in [0, 1] -> (s·H, s·W, C) float32, clipped to [0, 1], s = ``net.scale``.

    The input is cut into ``tile`` × ``tile`` tiles each read with ``pad`` texels of context (edge
    replicated at the border); only the tile's own part of each output is kept, so memory is one
    padded tile's activations and the result equals the whole-image output wherever the
    network's receptive field fits in ``pad`` (the official 23-block network's is wider, so tile
    seams differ from a whole-image run by a little, as in Real-ESRGAN's own tiling). Memory at
    the default 128-texel tiles and 64 features: ~85 MB per full-resolution activation, so a 1K →
    4K map runs in about 1 GB besides the 4K output.
    """
    s = net.scale
    h, w, _ = image.shape
    param = next(net.parameters())
    x = torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1), dtype=np.float32))[None]
    x = F.pad(x, (pad, pad, pad, pad), mode="replicate")
    out = np.empty((s * h, s * w, image.shape[2]), np.float32)
    for r in range(0, h, tile):
        for c in range(0, w, tile):
            th, tw = min(tile, h - r), min(tile, w - c)
            piece = x[:, :, r : r + th + 2 * pad, c : c + tw + 2 * pad].to(param.device, param.dtype)
            y = net(piece)[0, :, s * pad : s * (pad + th), s * pad : s * (pad + tw)]
            out[s * r : s * (r + th), s * c : s * (c + tw)] = y.float().clamp(0, 1).permute(1, 2, 0).cpu().numpy()
    return out
