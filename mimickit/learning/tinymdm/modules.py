"""The DiT's parts, as the reference's `tinymdm/modules.py` (attribute names are its state-dict keys).

Diffusers supplies the attention (`Attention`, bias-free q/k/v) and the sinusoidal timestep features with
their MLP (`Timesteps`, `TimestepEmbedding`). A block is adaLN-single (PixArt-α): one timestep embedding,
projected once to 6·dim, gives every block the shift, scale and gate of its attention and feed-forward
halves, added to the block's own learned `scale_shift_table`.
"""

from __future__ import annotations

import math

import torch
from diffusers.models.attention import Attention
from diffusers.models.embeddings import TimestepEmbedding, Timesteps
from torch import nn

TIME_PROJ_DIM = 256
"""Sinusoidal features of the timestep before its MLP (the reference's 256)."""


class SwiGLU(nn.Module):
    """x·silu(gate) of one projection to 2·dim_out split in two (the reference's diffusers copy)."""

    def __init__(self, dim_in: int, dim_out: int, bias: bool = True) -> None:
        super().__init__()
        self.proj = nn.Linear(dim_in, dim_out * 2, bias=bias)
        self.activation = nn.SiLU()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x, gate = self.proj(x).chunk(2, dim=-1)
        return x * self.activation(gate)


class FeedForward(nn.Module):
    """SwiGLU → dropout → linear (`net.0`, `net.1`, `net.2`); hidden width mult·dim unless inner_dim."""

    def __init__(
        self, dim: int, mult: int = 4, dropout: float = 0.0, inner_dim: int | None = None, bias: bool = True
    ) -> None:
        super().__init__()
        inner_dim = inner_dim or dim * mult
        self.net = nn.ModuleList([SwiGLU(dim, inner_dim, bias=bias), nn.Dropout(dropout), nn.Linear(inner_dim, dim)])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for module in self.net:
            x = module(x)
        return x


class LabelEmbedding(nn.Module):
    """Class labels → vectors; with dropout_prob > 0 one extra row is the "no label" of classifier-free
    guidance, which labels take with that probability in training or where `force_drop_ids` is 1."""

    def __init__(self, num_classes: int, hidden_size: int, dropout_prob: float) -> None:
        super().__init__()
        self.embedding_table = nn.Embedding(num_classes + int(dropout_prob > 0), hidden_size)
        self.num_classes = num_classes
        self.dropout_prob = dropout_prob

    def forward(self, labels: torch.Tensor, force_drop_ids: torch.Tensor | None = None, **_: object) -> torch.Tensor:
        if force_drop_ids is not None:
            labels = torch.where(force_drop_ids == 1, self.num_classes, labels)
        elif self.training and self.dropout_prob > 0:
            drop = torch.rand(labels.shape[0], device=labels.device) < self.dropout_prob
            labels = torch.where(drop, self.num_classes, labels)
        return self.embedding_table(labels)


class PixArtAlphaCombinedTimestepModeEmbeddings(nn.Module):
    """Timestep [N] → embedding [N, 1, dim] (plus the class embedding when conditioned on classes)."""

    def __init__(self, embedding_dim: int, use_additional_conditions: bool, num_class: int, cfg_dropout: float) -> None:
        super().__init__()
        self.time_proj = Timesteps(num_channels=TIME_PROJ_DIM, flip_sin_to_cos=True, downscale_freq_shift=0)
        self.timestep_embedder = TimestepEmbedding(in_channels=TIME_PROJ_DIM, time_embed_dim=embedding_dim)
        self.use_additional_conditions = use_additional_conditions
        if use_additional_conditions:
            self.class_embedder = LabelEmbedding(num_class, embedding_dim, dropout_prob=cfg_dropout)

    def forward(self, timestep: torch.Tensor, class_cond: torch.Tensor | None = None, **kwargs: object) -> torch.Tensor:
        cond = self.timestep_embedder(self.time_proj(timestep)).unsqueeze(1)
        if self.use_additional_conditions:
            cond = cond + self.class_embedder(class_cond, **kwargs).unsqueeze(1)
        return cond


class AdaLayerNormSingle(nn.Module):
    """adaLN-single: timestep [N] → (modulation [N, 1, 6·dim], embedding [N, 1, dim])."""

    def __init__(
        self, embedding_dim: int, use_additional_conditions: bool = False, num_class: int = 0, cfg_dropout: float = 0.0
    ) -> None:
        super().__init__()
        self.emb = PixArtAlphaCombinedTimestepModeEmbeddings(
            embedding_dim, use_additional_conditions, num_class, cfg_dropout
        )
        self.silu = nn.SiLU()
        self.linear = nn.Linear(embedding_dim, 6 * embedding_dim, bias=True)

    def forward(
        self, timestep: torch.Tensor, class_labels: torch.Tensor | None = None, **kwargs: object
    ) -> tuple[torch.Tensor, torch.Tensor]:
        embedded = self.emb(timestep, class_cond=class_labels, **kwargs)
        return self.linear(self.silu(embedded)), embedded


class SinusoidalPositionalEmbedding(nn.Module):
    """Adds sin/cos position codes to x [N, L, dim], L <= max_seq_length (buffer `pe` [1, max, dim])."""

    pe: torch.Tensor

    def __init__(self, embed_dim: int, max_seq_length: int = 32) -> None:
        super().__init__()
        position = torch.arange(max_seq_length).unsqueeze(1)
        div_term = torch.exp(torch.arange(0, embed_dim, 2) * (-math.log(10000.0) / embed_dim))
        pe = torch.zeros(1, max_seq_length, embed_dim)
        pe[0, :, 0::2] = torch.sin(position * div_term)
        pe[0, :, 1::2] = torch.cos(position * div_term)
        self.register_buffer("pe", pe)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.pe[:, : x.shape[1]]


class StableMotionDiTBlock(nn.Module):
    """Pre-norm self-attention and SwiGLU feed-forward, each shifted, scaled and gated by the timestep."""

    def __init__(
        self,
        dim: int,
        num_attention_heads: int,
        attention_head_dim: int,
        dropout: float = 0.0,
        norm_eps: float = 1e-5,
        ff_inner_dim: int | None = None,
    ) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=norm_eps, elementwise_affine=False)
        self.attn1 = Attention(
            query_dim=dim, heads=num_attention_heads, dim_head=attention_head_dim, dropout=dropout, bias=False
        )
        self.norm2 = nn.LayerNorm(dim, eps=norm_eps, elementwise_affine=False)
        self.ff = FeedForward(dim, dropout=dropout, inner_dim=ff_inner_dim, bias=True)
        self.scale_shift_table = nn.Parameter(torch.randn(1, 1, 6, dim) / dim**0.5)

    def forward(
        self, x: torch.Tensor, time_hidden_states: torch.Tensor, attention_mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        """x [N, L, dim], time_hidden_states [N, 1, 6·dim] → [N, L, dim]."""
        mod = self.scale_shift_table + time_hidden_states.reshape(x.shape[0], 1, 6, -1)
        shift_msa, scale_msa, gate_msa, shift_mlp, scale_mlp, gate_mlp = (m.squeeze(-2) for m in mod.chunk(6, dim=-2))
        h = self.norm1(x) * (1 + scale_msa) + shift_msa
        x = x + gate_msa * self.attn1(h, attention_mask=attention_mask)
        h = self.norm2(x) * (1 + scale_mlp) + shift_mlp
        return x + gate_mlp * self.ff(h)
