"""The MSSF encoder (paper Sec. 3.2): a trainable ConvNeXt V2 and a frozen DINOv3 ViT whose
multi-scale features are projected to a common width, resized to one grid and fused by
convolutions before a regression head that predicts χ = (α, δ, β, γ, pose).

Backbones are ``transformers``' ``ConvNextV2Model`` and ``DINOv3ViTModel``. Their weights load
from local folders in the Hugging Face layout (``from_pretrained(folder)``, never a hub); without
a folder the backbone is randomly initialised and a warning says so once per process.

Output parametrisation (so the head starts at the mean face, frontal, centred in the crop):
α, β linear in σ units; δ linear, projected into the model's expression range (ICT-FaceKit's
[0, 1]) with a straight-through gradient (see :meth:`MSSFRegressor.decode`); γ = ambient white +
output; pose =
axis-angle ω (rad) and the crop-pixel position and depth of the mean landmark centroid, turned
into t with the crop camera's intrinsics (so the same image gives the same pose whatever the
crop's focal length).
"""

from __future__ import annotations

import logging
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from facegeo.camera import rotation_from_axis_angle
from facegeo.errors import InputError
from facegeo.lighting import AMBIENT_WHITE, N_SH
from facegeo.morphable_model import MorphableModel
from facegeo.regressor.config import CONVNEXT_PRESETS, DINO_PRESETS, NetworkConfig
from facegeo.landmarks.scheme import IBUG68

__all__ = ["ModelSignature", "MSSFRegressor", "IMAGENET_MEAN", "IMAGENET_STD",
           "CONVNEXT_ENV", "DINO_ENV"]

log = logging.getLogger("facegeo.regressor")

CONVNEXT_ENV = "FACEGEO_CONVNEXT_WEIGHTS"
DINO_ENV = "FACEGEO_DINOV3_WEIGHTS"
#: Both backbones were trained on ImageNet-normalised RGB.
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
_said_random: set[str] = set()


@dataclass(frozen=True)
class ModelSignature:
    """What a trained head depends on in the morphable model (stored in checkpoints).

    n_id, n_exp, n_tex: coefficient counts; n_vertices: V; name: the model's name.
    exp_lower / exp_upper: (n_exp,) expression bounds. anchor: (3,) mm, the mean shape's 68
    landmark centroid (the point whose crop position the head predicts); extent: mm, the larger
    side of those landmarks' bounding box (sets the nominal depth).
    """

    name: str
    n_id: int
    n_exp: int
    n_tex: int
    n_vertices: int
    exp_lower: tuple[float, ...]
    exp_upper: tuple[float, ...]
    anchor: tuple[float, float, float]
    extent: float

    @classmethod
    def of(cls, model: MorphableModel) -> "ModelSignature":
        """The signature of a loaded model."""
        lower, upper = model.expression_range
        points = model.mean_shape[model.landmark_indices[IBUG68]].astype(np.float64)
        extent = float(np.max(points[:, :2].max(0) - points[:, :2].min(0)))
        return cls(model.name, model.n_id, model.n_exp, model.n_tex, model.n_vertices,
                   tuple(float(x) for x in lower), tuple(float(x) for x in upper),
                   tuple(float(x) for x in points.mean(0)), extent)

    def to_dict(self) -> dict[str, Any]:
        """JSON/pickle-free dict (floats, ints, strings, lists)."""
        d = asdict(self)
        d["exp_lower"], d["exp_upper"], d["anchor"] = list(self.exp_lower), list(self.exp_upper), list(self.anchor)
        return d

    @property
    def n_outputs(self) -> int:
        """n_id + n_exp + n_tex + 27 SH + 6 pose."""
        return self.n_id + self.n_exp + self.n_tex + 3 * N_SH + 6


def _spec(spec: str | dict[str, Any], presets: dict[str, dict[str, Any]]) -> dict[str, Any]:
    return dict(presets[spec]) if isinstance(spec, str) else dict(spec)


def _weights_dir(explicit: str | None, env: str) -> Path | None:
    value = explicit or os.environ.get(env) or None
    if value is None:
        return None
    path = Path(value)
    if not (path / "config.json").is_file():
        raise InputError(path, "backbone weights", "a local Hugging Face model folder with config.json "
                         "and model.safetensors (from_pretrained layout)", "no config.json there")
    return path


def _from_pretrained(cls: Any, path: Path) -> nn.Module:
    try:
        return cls.from_pretrained(str(path), local_files_only=True)
    except (OSError, ValueError) as exc:
        raise InputError(path, "backbone weights", f"a {cls.__name__} checkpoint", str(exc).splitlines()[0]) from None


def _say_random(name: str, env: str) -> None:
    if name not in _said_random:
        _said_random.add(name)
        log.warning("%s: no weights given (option or $%s): randomly initialised", name, env)


class _Projection(nn.Sequential):
    """Normalise one feature map and project it to the common width with a 1×1 convolution."""

    def __init__(self, channels: int, width: int):
        super().__init__(nn.GroupNorm(1, channels), nn.Conv2d(channels, width, 1))


class MSSFRegressor(nn.Module):
    """Image crop → χ. ``forward`` returns the raw (B, n_outputs) head output; :meth:`decode`
    turns it into parameters; :meth:`predict` does both.

    Args:
        config: the network section of the config.
        signature: the morphable model's :class:`ModelSignature` (sets the head's sizes).
        convnext_config / dino_config: transformers config dicts to build the backbones from
            (checkpoint loading); None = from ``config`` (preset, or the weights folders).
    """

    def __init__(self, config: NetworkConfig, signature: ModelSignature,
                 convnext_config: dict[str, Any] | None = None, dino_config: dict[str, Any] | None | bool = None):
        super().__init__()
        try:
            from transformers import ConvNextV2Config, ConvNextV2Model, DINOv3ViTConfig, DINOv3ViTModel
        except ImportError:
            raise InputError("<installation>", "transformers", "the regressor extra: pip install -c constraints.txt "
                             "'facegeo[regressor]'", "not installed") from None

        self.config, self.signature = config, signature
        self.loaded: dict[str, str] = {}
        if convnext_config is not None:
            self.convnext = ConvNextV2Model(ConvNextV2Config.from_dict(convnext_config))
        elif (path := _weights_dir(config.convnext_weights, CONVNEXT_ENV)) is not None:
            self.convnext = _from_pretrained(ConvNextV2Model, path)
            self.loaded["convnext"] = str(path)
        else:
            self.convnext = ConvNextV2Model(ConvNextV2Config(**_spec(config.convnext, CONVNEXT_PRESETS)))
            _say_random("ConvNeXt V2", CONVNEXT_ENV)
        self.dino: nn.Module | None = None
        if dino_config is not None and dino_config is not False:
            self.dino = DINOv3ViTModel(DINOv3ViTConfig.from_dict(dino_config))
        elif dino_config is None and config.dino is not None:
            if (path := _weights_dir(config.dino_weights, DINO_ENV)) is not None:
                self.dino = _from_pretrained(DINOv3ViTModel, path)
                self.loaded["dino"] = str(path)
            else:
                spec = {"num_register_tokens": 4, "patch_size": 16, **_spec(config.dino, DINO_PRESETS)}
                self.dino = DINOv3ViTModel(DINOv3ViTConfig(image_size=config.image_size, **spec))
                _say_random("DINOv3", DINO_ENV)
        width = config.width
        maps = [_Projection(c, width) for c in self.convnext.config.hidden_sizes]
        self.dino_layers: list[int] = []
        if self.dino is not None:
            self.dino.requires_grad_(False)  # frozen: semantic priors only
            self.dino.eval()
            dc = self.dino.config
            if config.image_size % dc.patch_size:
                raise InputError("<config>", "network.image_size", f"a multiple of the ViT patch {dc.patch_size}", str(config.image_size))
            n = dc.num_hidden_layers
            self.dino_layers = list(config.dino_layers) or [round(n * k / 4) for k in range(1, 5)]
            if any(not 0 <= i <= n for i in self.dino_layers):
                raise InputError("<config>", "network.dino_layers", f"layers in [0, {n}]", str(self.dino_layers))
            maps += [_Projection(dc.hidden_size, width) for _ in self.dino_layers]
        self.projections = nn.ModuleList(maps)
        self.grid = config.image_size // 16
        self.fusion = nn.Sequential(
            nn.Conv2d(len(maps) * width, width, 3, padding=1), nn.GroupNorm(8 if width % 8 == 0 else 1, width), nn.GELU(),
            nn.Conv2d(width, width, 3, stride=2, padding=1), nn.GroupNorm(8 if width % 8 == 0 else 1, width), nn.GELU(),
        )
        self.head = nn.Sequential(nn.Linear(width, width), nn.GELU(), nn.Linear(width, signature.n_outputs))
        # zero-initialised last layer: α = β = 0, δ = 0 (or its nearest bound), γ = ambient white,
        # frontal at the crop centre: the network starts at the mean face
        nn.init.zeros_(self.head[-1].weight)
        nn.init.zeros_(self.head[-1].bias)
        lower, upper = (torch.tensor(b, dtype=torch.float32) for b in (signature.exp_lower, signature.exp_upper))
        self.register_buffer("exp_lower", lower, persistent=False)
        self.register_buffer("exp_upper", upper, persistent=False)
        self.register_buffer("exp_start", torch.zeros_like(lower).clamp(lower, upper), persistent=False)
        self.register_buffer("anchor", torch.tensor(signature.anchor, dtype=torch.float32), persistent=False)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def train(self, mode: bool = True) -> "MSSFRegressor":
        """As nn.Module.train, but the frozen DINOv3 always stays in eval mode."""
        super().train(mode)
        if self.dino is not None:
            self.dino.eval()
        return self

    def backbone_configs(self) -> tuple[dict[str, Any], dict[str, Any] | None]:
        """The transformers config dicts of both backbones (None without DINOv3)."""
        return self.convnext.config.to_dict(), None if self.dino is None else self.dino.config.to_dict()

    def features(self, image: torch.Tensor) -> list[torch.Tensor]:
        """Multi-scale feature maps: 4 ConvNeXt stages (strides 4–32), then the DINOv3 layers
        (stride 16). ``image``: (B, 3, S, S) sRGB in [0, 1]."""
        x = (image - self.mean) / self.std
        out = list(self.convnext(pixel_values=x, output_hidden_states=True).hidden_states[1:])
        if self.dino is not None:
            with torch.no_grad():
                hidden = self.dino(pixel_values=x, output_hidden_states=True).hidden_states
            prefix = 1 + self.dino.config.num_register_tokens
            side = image.shape[-1] // self.dino.config.patch_size
            for i in self.dino_layers:
                tokens = hidden[i][:, prefix:]
                # contiguous: GroupNorm's CPU backward crashes on the transposed view (torch 2.13)
                out.append(tokens.transpose(1, 2).reshape(len(image), -1, side, side).contiguous())
        return out

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """(B, 3, S, S) sRGB crop in [0, 1] -> (B, n_outputs) raw head output."""
        fused = []
        for proj, f in zip(self.projections, self.features(image)):
            f = proj(f)
            if f.shape[-1] > self.grid:
                f = F.adaptive_avg_pool2d(f, self.grid)  # downsampling: average, no aliasing
            elif f.shape[-1] < self.grid:
                f = F.interpolate(f, size=(self.grid, self.grid), mode="bilinear", align_corners=False)
            fused.append(f)
        x = self.fusion(torch.cat(fused, dim=1)).mean(dim=(2, 3))
        return self.head(x)

    def decode(self, raw: torch.Tensor, intrinsics: torch.Tensor) -> dict[str, torch.Tensor]:
        """Raw head output (B, n_outputs) and crop intrinsics (B, 3) = (focal, cx, cy) px ->
        alpha (B, n_id), delta (B, n_exp), delta_free (B, n_exp), beta (B, n_tex), gamma (B, 3, 9),
        rotation (B, 3, 3), translation (B, 3) mm (X_c = R·X + t, OpenGL camera axes). All float32.

        ``delta_free`` is the head's unconstrained expression output; ``delta`` its projection
        into the model's range (as ``fit_landmarks`` projects), whose gradient passes straight
        through to ``delta_free``. Not a sigmoid: most expression weights of a face sit exactly
        at 0, where a sigmoid's gradient vanishes (a head starting at 0.01 barely moved δ in
        training); with a plain clamp an output pushed below 0 would get no gradient again. The
        objective's prior acts on ``delta_free``, so it cannot drift far outside the range."""
        s = self.signature
        raw = raw.float()
        alpha, delta, beta, gamma, pose = torch.split(raw, [s.n_id, s.n_exp, s.n_tex, 3 * N_SH, 6], dim=1)
        free = self.exp_start + delta
        delta = free + (free.clamp(self.exp_lower, self.exp_upper) - free).detach()
        gamma = torch.tensor(AMBIENT_WHITE).to(raw) + gamma.reshape(-1, 3, N_SH)
        rotation = rotation_from_axis_angle(pose[:, :3])
        size = float(self.config.image_size)
        focal, cx, cy = intrinsics.float().unbind(-1)
        u = size / 2 * (1 + pose[:, 3])
        v = size / 2 * (1 + pose[:, 4])
        depth = focal * s.extent * self.config.crop_scale / size * torch.exp(pose[:, 5])
        anchor_cam = torch.stack([(u - cx) * depth / focal, -(v - cy) * depth / focal, -depth], dim=-1)
        translation = anchor_cam - rotation @ self.anchor
        return {"alpha": alpha, "delta": delta, "delta_free": free, "beta": beta, "gamma": gamma, "rotation": rotation,
                "translation": translation}

    def predict(self, image: torch.Tensor, intrinsics: torch.Tensor) -> dict[str, torch.Tensor]:
        """:meth:`decode` of :meth:`forward`."""
        return self.decode(self(image), intrinsics)

    def trainable_parameters(self) -> list[nn.Parameter]:
        """The parameters the optimiser updates (everything but the frozen DINOv3)."""
        return [p for p in self.parameters() if p.requires_grad]

