"""One factory for the tiny models the tests serve: a small IT-Net with random weights and random
BatchNorm statistics (fast, and not the identity), exported to ONNX with any model card.

Exporting a step with torch takes seconds, so each network is exported once per process and its
graph written again with each card (``save_with_card``, as ``itnet card`` rewrites a card): a
file identical to what ``export_step`` writes for that network and card.
"""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path
from typing import Any

TINY_POINT_CHANNELS = (16, 32, 64)


def make_tiny_net(
    seed: int = 0,
    point_channels: tuple[int, ...] = TINY_POINT_CHANNELS,
    rotation: str = "quaternion",
) -> Any:
    """A small ITNet with random weights and random BatchNorm statistics (eval mode)."""
    import torch

    from itnet.model.network import ITNet, NetworkConfig

    torch.manual_seed(seed)
    config = NetworkConfig(point_channels=point_channels, head_channels=(32, 16), rotation=rotation)
    net = ITNet(config)
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm1d):
                m.running_mean.normal_(0, 0.1)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.normal_(1, 0.1)
                m.bias.normal_(0, 0.1)
        net.regressor.out.weight.normal_(0, 0.01)  # small but not the identity
    return net.eval()


@functools.cache
def _step_graph(seed: int, point_channels: tuple[int, ...], rotation: str) -> bytes:
    """The ONNX step of ``make_tiny_net(seed, point_channels, rotation)``, exported once."""
    from itnet.export.onnx_export import export_step
    from itnet.model_card import ModelCard

    with tempfile.TemporaryDirectory() as tmp:
        card = ModelCard(name="tiny", category="chair")
        net = make_tiny_net(seed, point_channels, rotation)
        return export_step(net, card, Path(tmp) / "tiny.onnx").read_bytes()


def export_tiny(
    card: Any,
    path: Path,
    *,
    seed: int = 0,
    point_channels: tuple[int, ...] = TINY_POINT_CHANNELS,
    rotation: str = "quaternion",
) -> Path:
    """Write ``path`` (.onnx): the step of ``make_tiny_net(seed, point_channels, rotation)`` with
    ``card`` as its model card. Returns the path."""
    import onnx

    from itnet.export.onnx_export import save_with_card

    graph = onnx.load_model_from_string(_step_graph(seed, tuple(point_channels), rotation))
    return save_with_card(graph, card, path)
