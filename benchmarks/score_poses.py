"""Score `itnet pose --json` output against the labels written by `itnet eval --dump-scans`.

itnet eval --onnx itnet/models/chair.onnx --dump-scans runs/scans
itnet pose runs/scans/*.npy --json --max-iterations 10 > runs/poses.jsonl
python benchmarks/score_poses.py runs/scans/labels.json runs/poses.jsonl
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from itnet.metrics import is_correct, pose_errors


def main(labels_path: str, poses_path: str) -> None:
    labels = json.loads(Path(labels_path).read_text())
    lines = [json.loads(line) for line in Path(poses_path).read_text().splitlines() if line]
    est = np.array([line["T_canonical_from_input"] for line in lines])
    truth = np.array([labels[Path(line["file"]).name]["T_canonical_from_input"] for line in lines])
    radii = np.array([labels[Path(line["file"]).name]["radius"] for line in lines])
    rot, trans = pose_errors(est, truth, radii)
    ok = is_correct(rot, trans)
    print(
        f"{len(lines)} scans: accuracy {ok.mean():.3f} at (10 deg, 0.1 radius); median rotation "
        f"{np.median(rot):.2f} deg, median translation {np.median(trans):.4f} radius; "
        f"median iterations {np.median([line['iterations'] for line in lines]):.0f}"
    )


if __name__ == "__main__":
    main(*sys.argv[1:3])
