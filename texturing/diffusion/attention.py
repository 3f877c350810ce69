"""Cross-intrinsic attention (the paper's Eq. 3) as a diffusers attention processor.

The M material branches (albedo, normal, rsd) are stacked along the batch axis, modality-major:
items ``[m·b, (m+1)·b)`` are branch m of a batch of b textures. In every attention layer each
branch keeps its own queries, text tokens and RoPE (every branch's tokens are embedded with the
same positions as in the stock processor), and the keys and values of all M branches of a
texture are concatenated along the token axis:

    h_i = softmax(q_i [k_1 … k_M]ᵀ / √d) [v_1 … v_M]

With M = 1 this is exactly :class:`diffusers.models.transformers.transformer_longcat_image.
LongCatImageAttnProcessor` (same projections, norms, RoPE and attention call). It replaces the
processor of both the dual-stream blocks (text and image tokens joined inside the processor) and
the single-stream blocks (text already joined to the image tokens).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch
from diffusers.models.attention_dispatch import dispatch_attention_fn
from diffusers.models.embeddings import apply_rotary_emb
from diffusers.models.transformers.transformer_longcat_image import LongCatImageAttnProcessor

__all__ = ["CrossIntrinsicAttention", "cross_intrinsic"]


class CrossIntrinsicAttention:
    """Attention processor for ``LongCatImageAttention`` whose keys/values span ``modalities``
    branches stacked along the batch axis (module docstring). The batch size must be a multiple
    of ``modalities``."""

    def __init__(self, modalities: int = 3):
        if modalities < 1:
            raise ValueError(f"modalities: expected ≥ 1, got {modalities}")
        self.modalities = modalities

    def _across(self, x: torch.Tensor) -> torch.Tensor:
        """(M·b, L, H, D) -> (M·b, M·L, H, D): each item gets the tokens of all M branches of its
        texture, branch by branch."""
        m = self.modalities
        if m == 1:
            return x
        mb, length, heads, dim = x.shape
        if mb % m:
            raise ValueError(f"cross-intrinsic attention: batch {mb} is not a multiple of {m} branches")
        joined = x.view(m, mb // m, length, heads, dim).transpose(0, 1).reshape(mb // m, m * length, heads, dim)
        return joined.repeat(m, 1, 1, 1)

    def __call__(
        self,
        attn: torch.nn.Module,
        hidden_states: torch.Tensor,
        encoder_hidden_states: torch.Tensor | None = None,
        attention_mask: torch.Tensor | None = None,
        image_rotary_emb: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        if attention_mask is not None:
            raise ValueError("cross-intrinsic attention takes no attention mask (LongCat uses none)")
        if getattr(attn, "fused_projections", False):
            raise ValueError("cross-intrinsic attention needs unfused q/k/v projections")
        query = attn.norm_q(attn.to_q(hidden_states).unflatten(-1, (attn.heads, -1)))
        key = attn.norm_k(attn.to_k(hidden_states).unflatten(-1, (attn.heads, -1)))
        value = attn.to_v(hidden_states).unflatten(-1, (attn.heads, -1))
        joint = encoder_hidden_states is not None and attn.added_kv_proj_dim is not None
        if joint:
            e_query = attn.norm_added_q(attn.add_q_proj(encoder_hidden_states).unflatten(-1, (attn.heads, -1)))
            e_key = attn.norm_added_k(attn.add_k_proj(encoder_hidden_states).unflatten(-1, (attn.heads, -1)))
            e_value = attn.add_v_proj(encoder_hidden_states).unflatten(-1, (attn.heads, -1))
            query = torch.cat([e_query, query], dim=1)
            key = torch.cat([e_key, key], dim=1)
            value = torch.cat([e_value, value], dim=1)
        if image_rotary_emb is not None:  # per branch, before the branches are joined
            query = apply_rotary_emb(query, image_rotary_emb, sequence_dim=1)
            key = apply_rotary_emb(key, image_rotary_emb, sequence_dim=1)
        out = dispatch_attention_fn(query, self._across(key), self._across(value), attn_mask=None)
        out = out.flatten(2, 3).to(query.dtype)
        if encoder_hidden_states is None:
            return out
        n_text = encoder_hidden_states.shape[1]
        context, out = out.split_with_sizes([n_text, out.shape[1] - n_text], dim=1)
        out = attn.to_out[1](attn.to_out[0](out))
        return out, attn.to_add_out(context)


@contextmanager
def cross_intrinsic(transformer: torch.nn.Module, modalities: int) -> Iterator[None]:
    """Within the block every attention layer of ``transformer`` uses
    :class:`CrossIntrinsicAttention` over ``modalities`` branches; the stock LongCat processor is
    put back afterwards."""
    transformer.set_attn_processor(CrossIntrinsicAttention(modalities))
    try:
        yield
    finally:
        transformer.set_attn_processor(LongCatImageAttnProcessor())
