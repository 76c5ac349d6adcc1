"""Export a training checkpoint for shipping: the model and normalisers, without the optimiser states
(half the file), keeping the `_train_state` facts a viewer shows (iteration, samples, wall time, last
test); `reference=True` drops `_train_state` entirely, for MimicKit's own strict loader."""

from __future__ import annotations

from pathlib import Path

from mimickit.learning.checkpoint import TRAIN_STATE_KEY, read_checkpoint, write_checkpoint
from mimickit.util.errors import MimicKitError


def export_checkpoint(src: str | Path, dst: str | Path, reference: bool = False) -> dict[str, int]:
    """Write the exported checkpoint atomically; returns the source and exported sizes in bytes."""
    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise MimicKitError(f"checkpoint not found: {src}")
    state = read_checkpoint(src)  # weights_only, every value type-checked: one line for a bad file
    if not any(k.startswith("_model.") for k in state):
        raise MimicKitError(f"{src}: not a MimicKit agent checkpoint (no _model.* keys)")
    train_state = state.pop(TRAIN_STATE_KEY, None)
    if train_state is not None and not reference:
        state[TRAIN_STATE_KEY] = {k: v for k, v in train_state.items() if k != "optimizers"}
    write_checkpoint(dst, state)  # atomic; a full disk or read-only folder is one line
    return {"source_bytes": src.stat().st_size, "exported_bytes": dst.stat().st_size}
