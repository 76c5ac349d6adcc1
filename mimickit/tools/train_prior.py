"""`mimickit train-prior`: train the SMP motion prior (TinyMDM) on clips, as the reference's
`tools/diffusion_model/train_tinymdm.py` does in train mode.

The normaliser is fitted once to `num_samples_stat` windows; then each iteration draws `batch_size`
fresh windows, normalises them and takes one AdamW step on the denoising loss (gradient norm clipped to
`grad_clip_norm`), then updates the EMA copy. Every `output_iter` iterations and at the last one it prints
the mean loss since the last print and saves the model. The output folder holds `model.pt` (the
state dict, written atomically, for `torch.load(weights_only=True)`), `env_config.yaml` (a copy of the
env yaml) and `diffusion_config.yaml` (the config with env_config pointing at that copy, and the
input_dim / input_channel training found): what SMP's `smp_prior_cfg` / `smp_prior_model` name. Unlike
the reference, no sample clips or plots are written.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
import yaml

from mimickit.learning.tinymdm.prior_config import PriorConfig
from mimickit.learning.tinymdm.prior_dataset import MotionPriorData
from mimickit.learning.tinymdm.tinymdm_model import TinyMDMModel
from mimickit.util.config import load_config
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths, atomic_write_bytes

MODEL_FILE = "model.pt"
CONFIG_FILE = "diffusion_config.yaml"
ENV_CONFIG_FILE = "env_config.yaml"


def train_prior(
    cfg_file: str | Path,
    out_dir: str | Path,
    data_paths: DataPaths = PROJECT_DATA,
    max_iterations: int | None = None,
    device: str | None = None,
    seed: int | None = None,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Train a prior into out_dir; returns {"iterations", "losses": [mean loss per print], "model_file",
    "model": the trained TinyMDMModel}."""
    config = load_config(PriorConfig, data_paths.resolve(cfg_file))
    updates: dict[str, Any] = {}
    if device is not None:
        updates["device"] = device
    if max_iterations is not None:
        if max_iterations < 1:
            raise MimicKitError(f"--max_iterations must be >= 1, got {max_iterations}")
        updates["num_iterations"] = min(max_iterations, config.num_iterations)
    config = config.model_copy(update=updates)
    if seed is not None:
        torch.manual_seed(seed)
    try:
        dev = torch.device(config.device)
    except RuntimeError:
        raise MimicKitError(f"{cfg_file}: key 'device': not a torch device (got {config.device!r})") from None

    data = MotionPriorData(config, data_paths, dev)
    input_dim = data.get_obs_dim()
    model = TinyMDMModel(config, input_dim, data.num_disc_obs_steps, device=dev)
    config = config.model_copy(update={"input_dim": input_dim, "input_channel": model.input_channel})
    out_dir = Path(out_dir)
    _write_configs(config, data.env_file, out_dir)
    model_file = out_dir / MODEL_FILE

    model.update_normalizer(data.fetch_obs_demo(config.num_samples_stat))
    params = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(params, lr=config.lr)
    n_params = sum(p.numel() for p in params)
    log(f"prior: {n_params / 1e6:.2f} M parameters, windows of {data.num_disc_obs_steps} x {model.input_channel}")

    model.train()
    losses: list[float] = []
    loss_sum, loss_count, start = 0.0, 0, time.monotonic()
    for it in range(config.num_iterations):
        batch = model.normalize(data.fetch_obs_demo(config.batch_size))
        loss = model(batch)
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), config.grad_clip_norm)
        optimizer.step()
        if config.model_ema:
            model.ema_dmodel.update()
        loss_sum, loss_count = loss_sum + loss.item(), loss_count + 1
        if (it % config.output_iter == 0 and it != 0) or it == config.num_iterations - 1:
            losses.append(loss_sum / loss_count)
            log(f"iteration {it}: loss {losses[-1]:.5f} ({time.monotonic() - start:.1f} s)")
            loss_sum, loss_count = 0.0, 0
            save_prior(model, model_file)
    log(f"wrote {model_file}")
    model.eval()
    return {"iterations": config.num_iterations, "losses": losses, "model_file": str(model_file), "model": model}


def save_prior(model: TinyMDMModel, path: Path) -> None:
    buf = io.BytesIO()
    torch.save(model.state_dict(), buf)
    atomic_write_bytes(path, buf.getvalue())


def _write_configs(config: PriorConfig, env_file: Path, out_dir: Path) -> None:
    env_copy = out_dir / ENV_CONFIG_FILE
    atomic_write_bytes(env_copy, env_file.read_bytes())
    raw = config.model_dump(exclude_none=True)
    raw["env_config"] = str(env_copy)
    atomic_write_bytes(out_dir / CONFIG_FILE, yaml.safe_dump(raw, sort_keys=False).encode())
