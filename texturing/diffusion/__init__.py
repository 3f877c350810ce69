"""The diffusion texture stack (the paper's Sec. 3.3–3.5), installed as
``facegeo.texturing.diffusion``; needs the optional extra ``pip install -e ".[diffusion]"``
(diffusers, peft, transformers, safetensors).

- :class:`DiffusionBackend` (:mod:`.backend`): the ``TextureBackend`` over a LongCat-Image-Edit
  DiT with five task LoRAs and Real-ESRGAN, loaded from local folders only.
- :mod:`.model`: latents, packing, the velocity call, LoRA targets and mixed-adapter batches.
- :class:`CrossIntrinsicAttention` (:mod:`.attention`): Eq. 3's processor.
- :func:`sample` (:mod:`.sampling`): Euler flow matching with classifier-free guidance.
- :func:`train_lora` (:mod:`.training`): flow-matching LoRA training, the two-stage materials
  schedule and the shading loss; ``facegeo train-lora``. :func:`validation_loss`: the loss on a
  fixed σ grid and fixed noise, comparable before and after training.
- :func:`make_texture_pairs` (:mod:`.data`): paired data from PBR sets; ``facegeo
  make-texture-pairs``.
- :class:`RRDBNet`, :func:`load_realesrgan`, :func:`upscale_tiled` (:mod:`.sr`).

Names are imported lazily, so the CLI can register the subcommands without importing diffusers.
"""

from __future__ import annotations

from facegeo.lazy_exports import lazy_exports

_EXPORTS = {
    "DiffusionBackend": ".backend",
    "missing_weight_files": ".backend",
    "CrossIntrinsicAttention": ".attention",
    "cross_intrinsic": ".attention",
    "sample": ".sampling",
    "train_lora": ".training",
    "TrainConfig": ".training",
    "encode_samples": ".training",
    "validation_loss": ".training",
    "make_texture_pairs": ".data",
    "procedural_pbr_set": ".data",
    "RRDBNet": ".sr",
    "load_realesrgan": ".sr",
    "upscale_tiled": ".sr",
    "Components": ".components",
    "load_components": ".components",
    "tiny_components": ".components",
}

__all__ = [*_EXPORTS, "require_extra"]


def require_extra() -> None:
    """Raise :class:`facegeo.errors.InputError` saying how to install the optional extra when
    diffusers or peft cannot be imported."""
    from facegeo.errors import InputError

    try:
        import diffusers  # noqa: F401
        import peft  # noqa: F401
    except ImportError as exc:
        raise InputError("<install>", "diffusers/peft", 'the optional extra: pip install -e ".[diffusion]"', str(exc)) from None


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
