"""Export a training checkpoint for shipping: the model and normalisers, without the optimiser states
(half the file), keeping the `_train_state` facts a viewer shows (iteration, samples, wall time, last
test); `reference=True` drops `_train_state` entirely, for MimicKit's own strict loader."""

from __future__ import annotations

import io
from pathlib import Path

import torch

from mimickit.learning.base_agent import TRAIN_STATE_KEY
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import atomic_write_bytes


def export_checkpoint(src: str | Path, dst: str | Path, reference: bool = False) -> dict[str, int]:
    """Write the exported checkpoint atomically; returns the source and exported sizes in bytes."""
    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise MimicKitError(f"checkpoint not found: {src}")
    try:
        state = torch.load(src, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file is the same user error
        raise MimicKitError(f"{src}: not a checkpoint ({e.__class__.__name__})") from None
    if not isinstance(state, dict) or not any(k.startswith("_model.") for k in state):
        raise MimicKitError(f"{src}: not a MimicKit agent checkpoint (no _model.* keys)")
    train_state = state.pop(TRAIN_STATE_KEY, None)
    if train_state is not None and not reference:
        state[TRAIN_STATE_KEY] = {k: v for k, v in train_state.items() if k != "optimizers"}
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write_bytes(dst, buf.getvalue())
    return {"source_bytes": src.stat().st_size, "exported_bytes": dst.stat().st_size}
