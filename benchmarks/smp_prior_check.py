"""What an SMP prior has learned (issue 38): its SDS losses on real windows of its clips against Gaussian
noise and against real windows with their features shuffled (the reward's signal: lower is "more like
the data"), and how far its generated windows (what GSI starts episodes from) stray from the data, per
sampler, as the largest |normalised feature| of each window (the data's own: median, 99th percentile, max).

    python benchmarks/smp_prior_check.py --prior data/models/smp_priors/smp_prior_locomotion \\
        --data_dir ../shared/data
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mimickit.learning.tinymdm.prior_dataset import MotionPriorData  # noqa: E402
from mimickit.learning.tinymdm.tinymdm_model import load_prior  # noqa: E402
from mimickit.util.paths import DataPaths  # noqa: E402

STEPS = [22, 15, 8]  # the SMP agent yamls' diffusion_steps


def quantiles(x: torch.Tensor) -> str:
    q = [float(x.quantile(p)) for p in (0.5, 0.99, 1.0)]
    return " / ".join(f"{v:.1f}" for v in q)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prior", required=True, help="path without suffix: PRIOR.yaml and PRIOR.pt")
    ap.add_argument("--data_dir", default=None)
    ap.add_argument("--windows", type=int, default=1024)
    ap.add_argument("--samples", type=int, default=256)
    args = ap.parse_args()
    paths = DataPaths(args.data_dir)
    prior = load_prior(f"{args.prior}.yaml", f"{args.prior}.pt", data_paths=paths)
    torch.manual_seed(0)
    data = MotionPriorData(prior.config, paths, torch.device("cpu"))
    n, steps = args.windows, data.num_disc_obs_steps
    real = prior.normalize(data.fetch_obs_demo(n).reshape(n, steps, -1)).reshape(n, -1)
    print(f"SDS loss at t = {STEPS} (mean over {n} windows)")
    for name, x in (
        ("real windows", real),
        ("Gaussian noise", torch.randn_like(real)),
        ("real, features shuffled", real[:, torch.randperm(real.shape[1])]),
    ):
        print(f"  {name:24s} " + "  ".join(f"{v:.3f}" for v in prior.ESM_SDS_loss(x, STEPS).mean(0).tolist()))
    print("largest |normalised feature| per window: median / 99th percentile / max")
    print(f"  {'real windows':24s} {quantiles(real.abs().amax(dim=1))}")
    sample = prior.sample_ema if prior.model_ema else prior.sample
    for sampler, k in (("ddpm", None), ("ddim", 50), ("ddim", 10)):
        torch.manual_seed(0)
        x = sample(real.shape[1:], args.samples, "cpu", sampler=sampler, num_inference_steps=k)
        label = f"{sampler} {k or prior.T} steps"
        print(f"  {'generated, ' + label:24s} {quantiles(x.abs().amax(dim=1))}")


if __name__ == "__main__":
    main()
