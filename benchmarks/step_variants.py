"""What a network variant costs at serving time, before anyone trains it: one step of the
served graph (int8 point layers, as shipped, and float32) for the paper's network, the 6D
rotation and wider backbones, each exported with random weights (the time does not depend on
them).

    python -m benchmarks.step_variants [--repeats 300] [--points 256]

Issue 11 allows a wider backbone "if its step still fits ten iterations in 10 ms on 2 cores".
Prints a markdown table of the median step (ms, batch 1, 2 onnxruntime threads; the median of
three interleaved rounds) and the machine. Run it as ``bash scripts/quiet.sh python -m
benchmarks.step_variants`` when a training job shares the machine.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

VARIANTS: dict[str, dict] = {
    "paper (64,128,1024 / 512,256), quaternion": {},
    "6D rotation": {"rotation": "6d"},
    "wider points (128,256,1024)": {"point_channels": (128, 256, 1024)},
    "wider points (128,256,2048)": {"point_channels": (128, 256, 2048)},
    "wider head (1024,512)": {"head_channels": (1024, 512)},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=300)
    parser.add_argument("--points", type=int, default=256)
    args = parser.parse_args()

    import torch

    from itnet.cpu import cpu_description
    from itnet.export.onnx_export import export_step
    from itnet.export.quantize import quantize_point_layers
    from itnet.model.network import ITNet, NetworkConfig
    from itnet.model_card import ModelCard
    from itnet.service.benchmark import time_step_ms

    print(f"machine: {cpu_description()}; batch 1 x {args.points} points, 2 threads")
    with tempfile.TemporaryDirectory() as folder:
        paths: dict[tuple[str, str], Path] = {}
        for i, (name, switches) in enumerate(VARIANTS.items()):
            torch.manual_seed(i)
            net = ITNet(NetworkConfig(**switches)).eval()
            card = ModelCard(name=f"v{i}", category="chair", points=args.points)
            fp32 = export_step(net, card, Path(folder) / f"v{i}.onnx")
            paths[name, "float32"] = fp32
            paths[name, "int8"] = quantize_point_layers(fp32, Path(folder) / f"v{i}-int8.onnx")
        times: dict[tuple[str, str], list[float]] = {key: [] for key in paths}
        for _ in range(3):  # interleaved, so that drift of the machine hits every row alike
            for key, path in paths.items():
                times[key].append(time_step_ms(path, 1, args.points, 2, args.repeats // 3))
    print("| network | int8 step (ms) | float32 step (ms) | 10 int8 iterations (ms) |")
    print("|---|---|---|---|")
    for name in VARIANTS:
        int8, fp32 = (statistics.median(times[name, p]) for p in ("int8", "float32"))
        print(f"| {name} | {int8:.2f} | {fp32:.2f} | {10 * int8:.1f} |")


if __name__ == "__main__":
    main()
