"""The SMP motion prior (TinyMDM): schedules, loss and SDS loss against the reference's formulas written
out here, its state-dict keys against the reference's (read from its tinymdm/arch.py and modules.py),
sampling shapes, and `mimickit train-prior` (a short CPU training on one clip, reloaded).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import pytest
import torch
import yaml

pytest.importorskip("diffusers")

from mimickit import cli  # noqa: E402
from mimickit.learning.tinymdm.prior_config import PriorConfig  # noqa: E402
from mimickit.learning.tinymdm.tinymdm_model import TinyMDMModel, load_prior  # noqa: E402
from mimickit.tools.train_prior import train_prior  # noqa: E402  (imports the envs, which probe GL, at collection)
from mimickit.util.paths import PROJECT_DATA_DIR, DataPaths  # noqa: E402

SINGLE_CLIP_YAML = PROJECT_DATA_DIR / "priors" / "tinymdm_single_clip.yaml"
STEPS, CHANNELS = 10, 4  # a window of 10 frames of 4 features


def prior_config(**overrides: object) -> PriorConfig:
    raw = yaml.safe_load(SINGLE_CLIP_YAML.read_text())
    raw.update({"num_layers": 1, "num_attention_heads": 2, "attention_head_dim": 8})
    raw.update(overrides)
    return PriorConfig.model_validate(raw)


def tiny_model(**overrides: object) -> TinyMDMModel:
    torch.manual_seed(3)
    model = TinyMDMModel(prior_config(**overrides), STEPS * CHANNELS, STEPS)
    return model.eval()


def squaredcos_alphas_cumprod(T: int) -> torch.Tensor:
    """diffusers' squaredcos_cap_v2 (the reference's schedule): β_i = min(1 − ā((i+1)/T) / ā(i/T), 0.999)."""

    def abar(t: float) -> float:
        return math.cos((t + 0.008) / 1.008 * math.pi / 2) ** 2

    betas = torch.tensor([min(1 - abar((i + 1) / T) / abar(i / T), 0.999) for i in range(T)], dtype=torch.float32)
    return torch.cumprod(1.0 - betas, dim=0)


def test_schedule_and_add_noise_follow_the_formulas() -> None:
    model = tiny_model()
    ac = squaredcos_alphas_cumprod(50)
    torch.testing.assert_close(model.diffusion_scheduler.alphas_cumprod, ac)
    torch.testing.assert_close(model.ddim_scheduler.alphas_cumprod, ac)
    g = torch.Generator().manual_seed(0)
    x, noise = torch.randn(6, 40, generator=g), torch.randn(6, 40, generator=g)
    t = torch.tensor([0, 1, 10, 25, 40, 49])
    expected = ac[t].sqrt().unsqueeze(-1) * x + (1 - ac[t]).sqrt().unsqueeze(-1) * noise
    torch.testing.assert_close(model.diffusion_scheduler.add_noise(x, noise, t), expected)
    linear = tiny_model(noise_schedule_mode="linear")  # diffusers' defaults: β from 1e-4 to 0.02
    betas = torch.linspace(1e-4, 0.02, 50)
    torch.testing.assert_close(linear.diffusion_scheduler.alphas_cumprod, torch.cumprod(1 - betas, 0))


@pytest.mark.parametrize("loss_type", ["l1", "l2"])
def test_training_loss_is_the_reference_formula(loss_type: str) -> None:
    model = tiny_model(loss_type=loss_type)
    x = torch.randn(5, 40, generator=torch.Generator().manual_seed(1))
    t = torch.tensor([0, 3, 17, 30, 49])
    torch.manual_seed(7)
    loss = model(x, t)
    torch.manual_seed(7)
    noise = torch.randn_like(x)
    ac = squaredcos_alphas_cumprod(50)[t].unsqueeze(-1)
    pred = model.dmodel(ac.sqrt() * x + (1 - ac).sqrt() * noise, t)
    expected = (pred - noise).abs().mean() if loss_type == "l1" else (pred - noise).square().mean()
    torch.testing.assert_close(loss, expected)


@pytest.mark.parametrize("mode", ["epsilon", "sample", "v_prediction"])
def test_sds_loss_is_the_reference_formula(mode: str) -> None:
    model = tiny_model(estimate_mode=mode)
    x = torch.randn(7, 40, generator=torch.Generator().manual_seed(2))
    t_lst = [2, 10, 30]
    torch.manual_seed(11)
    losses = model.ESM_SDS_loss(x, t_lst)
    assert losses.shape == (7, 3)

    torch.manual_seed(11)
    ac_all = squaredcos_alphas_cumprod(50)
    expected = []
    for t_value in t_lst:
        noise = torch.randn_like(x)
        a = ac_all[t_value]
        x_t = a.sqrt() * x + (1 - a).sqrt() * noise
        pred = model.ema_dmodel.ema_model(x_t, torch.full((7,), t_value))  # model_ema: the EMA copy scores
        if mode == "epsilon":
            x0 = (x_t - (1 - a).sqrt() * pred) / a.sqrt()
        elif mode == "sample":
            x0 = pred
        else:
            x0 = a.sqrt() * x_t - (1 - a).sqrt() * pred
        eps = (x_t - a.sqrt() * x0) / (1 - a).sqrt()
        expected.append((eps - noise).square().mean(dim=1))
    torch.testing.assert_close(losses, torch.stack(expected, dim=1), rtol=1e-4, atol=1e-5)


def reference_keys(num_layers: int) -> set[str]:
    """The reference's TinyMDMModel state dict with model_ema, read from its arch.py / modules.py / EMA.py
    (diffusers' Attention(bias=False): to_q/k/v without bias, to_out.0 with; TimestepEmbedding: linear_1/2)."""
    block = [
        "scale_shift_table",
        "attn1.to_q.weight", "attn1.to_k.weight", "attn1.to_v.weight", "attn1.to_out.0.weight", "attn1.to_out.0.bias",
        "ff.net.0.proj.weight", "ff.net.0.proj.bias", "ff.net.2.weight", "ff.net.2.bias",
    ]  # fmt: skip
    dit = [
        "scale_shift_table",
        "adaln_single.emb.timestep_embedder.linear_1.weight", "adaln_single.emb.timestep_embedder.linear_1.bias",
        "adaln_single.emb.timestep_embedder.linear_2.weight", "adaln_single.emb.timestep_embedder.linear_2.bias",
        "adaln_single.linear.weight", "adaln_single.linear.bias",
        "preprocess_conv.weight", "proj_in.weight", "proj_out.weight", "postprocess_conv.weight",
        "sequence_pos_encoder.pe",
    ] + [f"transformer_blocks.{i}.{k}" for i in range(num_layers) for k in block]  # fmt: skip
    keys = {"ema_dmodel.step", "obs_normalizer._count", "obs_normalizer._mean", "obs_normalizer._std"}
    for prefix in ("dmodel.", "ema_dmodel.model.", "ema_dmodel.ema_model."):
        keys |= {prefix + k for k in dit}
    return keys


def test_state_dict_keys_and_shapes_are_the_reference_ones() -> None:
    cfg = prior_config(num_layers=2, num_attention_heads=4, attention_head_dim=64)
    state = TinyMDMModel(cfg, 1420, 10).state_dict()
    assert set(state) == reference_keys(2)
    d, c = 256, 142
    shapes = {
        "dmodel.scale_shift_table": (1, 1, 2, d),
        "dmodel.transformer_blocks.1.scale_shift_table": (1, 1, 6, d),
        "dmodel.transformer_blocks.0.attn1.to_q.weight": (d, d),
        "dmodel.transformer_blocks.0.ff.net.0.proj.weight": (8 * d, d),
        "dmodel.transformer_blocks.0.ff.net.2.weight": (d, 4 * d),
        "dmodel.adaln_single.emb.timestep_embedder.linear_1.weight": (d, 256),
        "dmodel.adaln_single.linear.weight": (6 * d, d),
        "dmodel.preprocess_conv.weight": (c, c, 1),
        "dmodel.proj_in.weight": (d, c),
        "dmodel.proj_out.weight": (c, d),
        "dmodel.sequence_pos_encoder.pe": (1, 32, d),
        "ema_dmodel.step": (),
        "obs_normalizer._count": (1,),
        "obs_normalizer._mean": (c,),
        "obs_normalizer._std": (c,),
    }
    assert {k: tuple(state[k].shape) for k in shapes} == shapes
    no_ema = TinyMDMModel(prior_config(model_ema=False), 40, 10).state_dict()
    assert not any(k.startswith("ema_dmodel.") for k in no_ema)


@pytest.mark.parametrize("sampler", ["ddpm", "ddim"])
def test_sample_shapes(sampler: str) -> None:
    model = tiny_model()
    for fn in (model.sample, model.sample_ema):
        out = fn(shape=(40,), batch_size=3, device="cpu", sampler=sampler, num_inference_steps=5)
        assert out.shape == (3, 40) and torch.isfinite(out).all()
    assert model.unnormalize(out.reshape(3, STEPS, CHANNELS)).shape == (3, STEPS, CHANNELS)


def test_normalizer_std_is_clipped_below() -> None:
    model = tiny_model()
    x = torch.randn(500, STEPS, CHANNELS) * torch.tensor([0.01, 1.0, 2.0, 0.1]) + 3.0
    model.update_normalizer(x)
    std = model.obs_normalizer.get_std()
    assert std[0].item() == pytest.approx(0.2) and std[3].item() == pytest.approx(0.2)
    assert std[2].item() == pytest.approx(2.0, rel=0.15)
    torch.testing.assert_close(model.unnormalize(model.normalize(x)), x)


def test_ema_copies_then_averages() -> None:
    model = tiny_model(model_ema_steps=2, model_ema_update_after=2, model_ema_decay=0.9)
    ema, p = model.ema_dmodel, model.dmodel.proj_in.weight
    q = dict(ema.ema_model.named_parameters())["proj_in.weight"]
    with torch.no_grad():
        p.add_(1.0)
    ema.update()  # step 0: copy
    torch.testing.assert_close(q, p)
    with torch.no_grad():
        p.add_(1.0)
    ema.update()  # step 1: not an update step
    ema.update()  # step 2 <= update_after: copy
    torch.testing.assert_close(q, p)
    old = q.detach().clone()
    with torch.no_grad():
        p.add_(1.0)
    ema.update()  # step 3: skipped
    ema.update()  # step 4: average
    torch.testing.assert_close(q, 0.9 * old + 0.1 * p)


def write_config(path: Path, **overrides: object) -> Path:
    raw = yaml.safe_load(SINGLE_CLIP_YAML.read_text())
    raw.update(overrides)
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.mark.parametrize(
    ("override", "named"), [({"foo": 1}, "unknown key 'foo'"), ({"loss_type": "l3"}, "key 'loss_type'")]
)
def test_bad_config_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], override: dict, named: str) -> None:
    cfg = write_config(tmp_path / "bad.yaml", **override)
    # The subcommand's own parser: `mimickit`'s full one imports more tools, some of which start a process.
    parser = argparse.ArgumentParser(prog="mimickit")
    cli._add_train_prior_parser(parser.add_subparsers(dest="command", required=True))
    rc = cli.run_cli(parser, ["train-prior", "--config", str(cfg), "--out_dir", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("error: ") and named in err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_train_prior_on_one_clip_lowers_loss_and_reloads(
    tmp_path: Path, test_data: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = write_config(tmp_path / "prior.yaml", batch_size=32, lr=1e-3, num_samples_stat=1000, output_iter=10)
    out = tmp_path / "prior"
    result = train_prior(cfg, out, DataPaths(test_data), max_iterations=50, device="cpu", seed=0)
    assert result["iterations"] == 50
    losses = result["losses"]
    assert len(losses) == 5 and losses[-1] < losses[0], losses
    assert "iteration 49: loss" in capsys.readouterr().out

    state = torch.load(out / "model.pt", weights_only=True)
    assert set(state) == reference_keys(2)
    saved = yaml.safe_load((out / "diffusion_config.yaml").read_text())
    assert saved["input_dim"] == 1140 and saved["input_channel"] == 114 and saved["num_iterations"] == 50
    assert Path(saved["env_config"]) == out / "env_config.yaml" and (out / "env_config.yaml").is_file()

    trained = result["model"]
    loaded = load_prior(out / "diffusion_config.yaml", out / "model.pt")
    x = torch.randn(16, 1140, generator=torch.Generator().manual_seed(4))
    torch.manual_seed(5)
    a = trained.ESM_SDS_loss(trained.normalize(x), [5, 20, 40])
    torch.manual_seed(5)
    b = loaded.ESM_SDS_loss(loaded.normalize(x), [5, 20, 40])
    torch.testing.assert_close(a, b)
