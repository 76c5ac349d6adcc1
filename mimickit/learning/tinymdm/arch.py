"""The denoisers: a small DiT over a window of frames, as the reference's `tinymdm/arch.py`.

A sample x [N, S·C] (S frames of C features, flat) is read as a sequence [N, S, C]: a 1×1 conv (residual)
mixes each frame's features, a linear lifts them to dim = heads·head_dim, position codes are added, the
DiT blocks run under the timestep's modulation, and the way back mirrors the way in → [N, S·C].
`CondTinyStableMotionDiTModel` adds class labels (classifier-free guidance). The top-level
`scale_shift_table` is unused in the forward pass, as in the reference; it is kept for its state dict.
"""

from __future__ import annotations

import torch
from torch import nn

from mimickit.learning.tinymdm.modules import AdaLayerNormSingle, SinusoidalPositionalEmbedding, StableMotionDiTBlock

MAX_SEQ_LEN = 32
"""Longest window (frames) the position codes cover: the reference's max_seq_len."""


class TinyStableMotionDiTModel(nn.Module):
    def __init__(
        self,
        in_channels: int = 64,
        num_layers: int = 4,
        attention_head_dim: int = 64,
        num_attention_heads: int = 4,
        out_channels: int = 64,
        dropout: float = 0.0,
        max_seq_len: int = MAX_SEQ_LEN,
        num_class: int = 0,
        cfg_dropout: float = 0.0,
    ) -> None:
        super().__init__()
        self.dropout = dropout
        self.in_channels = in_channels
        self.out_channels = out_channels
        self.inner_dim = dim = num_attention_heads * attention_head_dim
        self.transformer_blocks = nn.ModuleList(
            [StableMotionDiTBlock(dim, num_attention_heads, attention_head_dim, dropout) for _ in range(num_layers)]
        )
        self.scale_shift_table = nn.Parameter(torch.randn(1, 1, 2, dim) / dim**0.5)
        self.adaln_single = AdaLayerNormSingle(
            dim, use_additional_conditions=num_class > 0, num_class=num_class, cfg_dropout=cfg_dropout
        )
        self.preprocess_conv = nn.Conv1d(in_channels, in_channels, 1, bias=False)
        self.proj_in = nn.Linear(in_channels, dim, bias=False)
        self.proj_out = nn.Linear(dim, out_channels, bias=False)
        self.postprocess_conv = nn.Conv1d(out_channels, out_channels, 1, bias=False)
        self.sequence_pos_encoder = SinusoidalPositionalEmbedding(dim, max_seq_length=max_seq_len)

    def forward(
        self,
        hidden_states: torch.Tensor,
        timestep: torch.Tensor,
        attention_mask: torch.Tensor | None = None,
        class_labels: torch.Tensor | None = None,
        **kwargs: object,
    ) -> torch.Tensor:
        """hidden_states [N, S·C] (or [N, S, C]), timestep [N] (int) → prediction [N, S·C_out]."""
        n = hidden_states.shape[0]
        h = hidden_states.reshape(n, -1, self.in_channels).transpose(1, 2)  # [N, C, S]
        h = (self.preprocess_conv(h) + h).transpose(1, 2)
        h = self.proj_in(h)
        time_hidden_states, _ = self.adaln_single(timestep, class_labels, **kwargs)
        h = self.sequence_pos_encoder(h)
        for block in self.transformer_blocks:
            h = block(h, time_hidden_states, attention_mask=attention_mask)
        h = self.proj_out(h).transpose(1, 2)  # [N, C_out, S]
        h = (self.postprocess_conv(h) + h).transpose(1, 2)
        return h.reshape(n, -1)


class CondTinyStableMotionDiTModel(TinyStableMotionDiTModel):
    """The DiT conditioned on a class label per sample (`class_labels` [N] int); `num_class` > 0."""
