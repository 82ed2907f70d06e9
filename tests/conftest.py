"""Shared fixtures: a tiny random IT-Net exported to ONNX (fast, and not the identity)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


def make_tiny_net(seed: int = 0):  # type: ignore[no-untyped-def]
    """A small ITNet with random weights and random BatchNorm statistics (eval mode)."""
    import torch

    from itnet.model.network import ITNet, NetworkConfig

    torch.manual_seed(seed)
    net = ITNet(NetworkConfig(point_channels=(16, 32, 64), head_channels=(32, 16)))
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm1d):
                m.running_mean.normal_(0, 0.1)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.normal_(1, 0.1)
                m.bias.normal_(0, 0.1)
        net.regressor.out.weight.normal_(0, 0.01)  # small but not the identity
    return net.eval()


@pytest.fixture(scope="session")
def tiny_model_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with ``tiny.onnx`` (model name 'tiny', category 'chair', 256 points)."""
    from itnet.export.onnx_export import export_step
    from itnet.model_card import ModelCard

    folder = tmp_path_factory.mktemp("models")
    card = ModelCard(name="tiny", category="chair", points=256, recommended_iterations=5)
    export_step(make_tiny_net(), card, folder / "tiny.onnx")
    return folder


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
