"""The reference's named MLPs (the `*_net` names of its agent yamls).

Each hidden layer is Linear → ReLU (the last one too), so in the `nn.Sequential` the Linears sit at
even indices (0, 2, 4) and checkpoint keys read `<net>.0.weight`, `<net>.2.bias`, ... Biases start at
zero; weights keep PyTorch's default init.
"""

from __future__ import annotations

from torch import nn

NET_HIDDEN_SIZES: dict[str, tuple[int, ...]] = {
    "fc_2layers_128units": (128, 64),
    "fc_2layers_256units": (256, 128),
    "fc_2layers_512units": (512, 256),
    "fc_2layers_1024units": (1024, 512),
    "fc_3layers_1024units": (1024, 1024, 512),
}


def build_net(name: str, input_dim: int) -> tuple[nn.Sequential, int]:
    """The MLP `name` taking [B, input_dim]; returns (net, output size)."""
    if name not in NET_HIDDEN_SIZES:
        raise ValueError(f"unknown net '{name}'; known: {', '.join(NET_HIDDEN_SIZES)}")
    layers: list[nn.Module] = []
    in_size = input_dim
    for size in NET_HIDDEN_SIZES[name]:
        linear = nn.Linear(in_size, size)
        nn.init.zeros_(linear.bias)
        layers += [linear, nn.ReLU()]
        in_size = size
    return nn.Sequential(*layers), in_size
