"""The regressor's one configuration file: network sizes, loss weights and training settings.

A JSON file with three sections (any key may be left out; the defaults below apply)::

    {"network": {"image_size": 224, "convnext": "base", "dino": "vitb16", ...},
     "loss":    {"lan": 1.0, "pho": 0.2, "per": 0.2, "reg": 1.0, ...},
     "train":   {"lr": 1e-4, "batch_size": 32, "epochs": 50, ...}}

``convnext`` and ``dino`` are a preset name (the paper's defaults: ConvNeXt V2 Base and DINOv3
ViT-B/16) or a dict of ``transformers`` config fields (tiny test networks); ``dino: null`` drops the
DINOv3 branch (the "w/o MSSF" ablation rows). Unknown keys are an error naming the file.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from facegeo.errors import InputError

__all__ = ["NetworkConfig", "LossConfig", "TrainConfig", "RegressorConfig", "load_config",
           "CONVNEXT_PRESETS", "DINO_PRESETS"]

#: ConvNeXt V2 sizes (Woo et al. 2023, Table 1): ``ConvNextV2Config`` fields.
CONVNEXT_PRESETS: dict[str, dict[str, Any]] = {
    "atto": {"hidden_sizes": [40, 80, 160, 320], "depths": [2, 2, 6, 2]},
    "nano": {"hidden_sizes": [80, 160, 320, 640], "depths": [2, 2, 8, 2]},
    "tiny": {"hidden_sizes": [96, 192, 384, 768], "depths": [3, 3, 9, 3]},
    "base": {"hidden_sizes": [128, 256, 512, 1024], "depths": [3, 3, 27, 3]},
    "large": {"hidden_sizes": [192, 384, 768, 1536], "depths": [3, 3, 27, 3]},
}
#: DINOv3 ViT sizes (Siméoni et al. 2025; patch 16, 4 register tokens): ``DINOv3ViTConfig`` fields.
DINO_PRESETS: dict[str, dict[str, Any]] = {
    "vits16": {"hidden_size": 384, "num_hidden_layers": 12, "num_attention_heads": 6, "intermediate_size": 1536},
    "vitb16": {"hidden_size": 768, "num_hidden_layers": 12, "num_attention_heads": 12, "intermediate_size": 3072},
    "vitl16": {"hidden_size": 1024, "num_hidden_layers": 24, "num_attention_heads": 16, "intermediate_size": 4096},
}


@dataclass
class NetworkConfig:
    """The MSSF encoder and regression head.

    image_size: side of the square face crop in pixels (a multiple of 32 and of the ViT patch).
    convnext / dino: preset name or a dict of transformers config fields; dino None = no DINOv3.
    dino_layers: 1-based ViT layers whose patch tokens become feature maps (0 = the patch
        embedding); empty = four evenly spaced layers ending at the last.
    width: channels of the fused feature maps and of the head.
    crop_scale: the crop is this times the larger side of the landmarks' bounding box.
    convnext_weights / dino_weights: local Hugging Face folders (``from_pretrained``); None =
        the environment variables FACEGEO_CONVNEXT_WEIGHTS / FACEGEO_DINOV3_WEIGHTS, else random.
    """

    image_size: int = 224
    convnext: str | dict[str, Any] = "base"
    dino: str | dict[str, Any] | None = "vitb16"
    dino_layers: list[int] = field(default_factory=list)
    width: int = 256
    crop_scale: float = 1.5
    convnext_weights: str | None = None
    dino_weights: str | None = None


@dataclass
class LossConfig:
    """λ of L = λ_lan·L_lan + λ_pho·L_pho + λ_per·L_per + λ_reg·L_reg and the parts of L_reg.

    landmarks: ``"hybrid88"`` (the paper's enhanced loss, LANDMARK_WEIGHTS) or ``"ibug68"`` (the
    68 iBUG points, unit weights: the "Baseline" ablation row). perceptual_checkpoint: a
    TorchScript file mapping (B, 3, H, W) sRGB in [0, 1] to (B, D) embeddings (e.g. a face
    recognition network); None skips L_per with a logged note. L_reg on α and δ is the MAP fit's
    prior weighted by the network's current landmark noise (:mod:`facegeo.regressor.losses`);
    reg_tex and reg_sh weigh the mean squares of β (σ units) and of γ − ambient white.
    """

    lan: float = 1.0
    pho: float = 0.2
    per: float = 0.2
    reg: float = 1.0
    landmarks: str = "hybrid88"
    perceptual_checkpoint: str | None = None
    reg_tex: float = 1e-3
    reg_sh: float = 1e-3


@dataclass
class TrainConfig:
    """AdamW with a constant learning rate; the paper: lr 1e-4, batch 128, 50 epochs."""

    lr: float = 1e-4
    weight_decay: float = 0.05
    batch_size: int = 32
    epochs: int = 50
    val_fraction: float = 0.05
    seed: int = 0
    checkpoint_every: int = 500
    augment: bool = True
    max_grad_norm: float = 1.0


@dataclass
class RegressorConfig:
    """The three sections together (what a checkpoint stores)."""

    network: NetworkConfig = field(default_factory=NetworkConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready nested dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "<config>") -> "RegressorConfig":
        """Build from a nested dict; unknown sections or keys raise :class:`InputError`."""
        if not isinstance(data, dict):
            raise InputError(source, "config", "a JSON object with sections network, loss, train", type(data).__name__)
        sections = {"network": NetworkConfig, "loss": LossConfig, "train": TrainConfig}
        unknown = set(data) - set(sections)
        if unknown:
            raise InputError(source, "config", f"sections among {', '.join(sections)}", ", ".join(sorted(unknown)))
        built = {}
        for name, kind in sections.items():
            part = data.get(name, {})
            names = {f.name for f in fields(kind)}
            if not isinstance(part, dict) or set(part) - names:
                bad = sorted(set(part) - names) if isinstance(part, dict) else [type(part).__name__]
                raise InputError(source, f"config.{name}", f"keys among {', '.join(sorted(names))}", ", ".join(bad))
            built[name] = kind(**part)
        config = cls(**built)
        config.check(source)
        return config

    def check(self, source: str = "<config>") -> None:
        """Raise :class:`InputError` for values no network or loss can use."""
        n = self.network
        if n.image_size <= 0 or n.image_size % 32:
            raise InputError(source, "network.image_size", "a positive multiple of 32", str(n.image_size))
        if isinstance(n.convnext, str) and n.convnext not in CONVNEXT_PRESETS:
            raise InputError(source, "network.convnext", f"one of {', '.join(CONVNEXT_PRESETS)} or a dict", repr(n.convnext))
        if isinstance(n.dino, str) and n.dino not in DINO_PRESETS:
            raise InputError(source, "network.dino", f"one of {', '.join(DINO_PRESETS)}, a dict or null", repr(n.dino))
        if self.loss.landmarks not in ("hybrid88", "ibug68"):
            raise InputError(source, "loss.landmarks", "hybrid88 or ibug68", repr(self.loss.landmarks))
        if self.train.batch_size < 1 or self.train.epochs < 0 or not 0 <= self.train.val_fraction < 1:
            raise InputError(source, "train", "batch_size >= 1, epochs >= 0, 0 <= val_fraction < 1",
                             f"{self.train.batch_size}, {self.train.epochs}, {self.train.val_fraction}")


def load_config(path: str | Path | None) -> RegressorConfig:
    """Read a JSON config file (None: all defaults)."""
    if path is None:
        return RegressorConfig()
    p = Path(path)
    try:
        data = json.loads(p.read_text())
    except FileNotFoundError:
        raise InputError(p, "config", "an existing JSON file", "no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(p, "config", "a readable JSON file", str(exc)) from None
    return RegressorConfig.from_dict(data, str(p))
