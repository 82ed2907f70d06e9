"""The accuracy of a pose model as the service serves it: for every held-out scan of its category
(the same seeded views as ``itnet eval``), one ``AnytimeRun`` per setting (K fused runs, 0: the
card's default) under one ``budget_ms``, the finishing stages as the card and the switches say.
Accuracy at (10 deg, 0.1 r) with its standard error, the gain over the first setting on the same
scans (paired), where the misses are, the median iterations and elapsed time.

    served = measure(Path("itnet/models/chair.onnx"), "paper", [1, 8], 50.0, 5, cache, data)
    served["8"]["accuracy"], served["8"]["gain"]

``benchmarks/bench_ensemble.py`` runs it from the command line; ``itnet build`` measures the
model it builds with it (the card's measurements).
"""

from __future__ import annotations

import os
import platform
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np


def machine() -> str:
    """Where a measurement runs, as the cards say it: 'x86_64, 2 cores'."""
    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores"


def known_ups(poses: np.ndarray, error_deg: float, seed: int = 0) -> np.ndarray:
    """Each scan's up direction in its own frame, as a caller would give it: the truth (the
    canonical +y taken back by T_canonical_from_input (S, 4, 4)) tilted by ``error_deg`` about a
    random horizontal axis (a gravity sensor's error) -> (S, 3) unit vectors."""
    from itnet.upright import sensed_ups

    return sensed_ups(poses, error_deg, np.random.default_rng(seed))


def misses(rot_deg: np.ndarray, trans: np.ndarray) -> dict[str, float]:
    """Where the misses are, % of all scans: near misses in rotation (10–20°), wrong basins
    (over 20°; of them, turned by more than 135°: a front-back swap where up is given), and the
    centre over 0.1 r with the rotation right. (S,), (S,) -> shares."""
    share = lambda mask: round(100.0 * float(np.mean(mask)), 1)  # noqa: E731
    return {
        "rot_10_20": share((rot_deg >= 10) & (rot_deg < 20)),
        "rot_over_20": share(rot_deg >= 20),
        "rot_over_135": share(rot_deg > 135),
        "centre_only": share((rot_deg < 10) & (trans >= 0.1)),
    }


def measure(model_path: Path, scanner: str, ensembles: list[int], budget_ms: float,
            views: int, cache: Path, data: Path, split: str = "test",
            mirror: bool | None = None, centre: bool | None = None,
            baseline: dict | None = None, viewpoint: bool = False,
            up_error_deg: float | None = None, verify: bool | None = None,
            verifier: str = "beside", recheck: bool | None = None,
            halving: tuple[int, int] | None = None,
            points: int | None = None,
            coarse: tuple[int, int] | None = None,
            full: bool = False,
            strip: bool | None = None,
            log: Callable[[str], None] = print) -> dict:  # fmt: skip
    from itnet.metrics import is_correct, paired_accuracy
    from itnet.model.categories import category
    from itnet.model.category_set import test_scans, validation_scans
    from itnet.model.evaluate import report
    from itnet.model.scanner import named_views
    from itnet.pose.cloud import Limits, cut_out
    from itnet.pose.loop import AnytimeRun
    from itnet.pose.plan import plan
    from itnet.pose.request import PoseRequest
    from itnet.pose.runtime import (
        LoadedVerifier,
        attach_verifiers,
        load_any,
        load_beside,
        load_model,
    )

    model = load_model(model_path)
    if verifier == "beside":  # as the service loads the model's folder
        found = load_beside(model_path.parent, skip=frozenset({model_path.resolve()}))[1]
        attach_verifiers({model.card.name: model}, found, model_path.parent)
    elif verifier != "none":  # verify then anchors on the run it finds likeliest
        model.verifier = load_any(Path(verifier))
        assert isinstance(model.verifier, LoadedVerifier), f"{verifier}: not a verifier"
    cat = category(model.card.category, model.card.symmetry)
    config = named_views(scanner, cat.name)
    if split == "val":  # where a choice is made; the test split measures it once
        scans = validation_scans(data, cat, views, scan=config, cache=cache)
    else:
        scans, _ = test_scans(data, cat, views, 2024, config, cache)
    ups = None if up_error_deg is None else known_ups(scans.poses, up_error_deg)
    out, first = {}, None
    for k in ensembles:
        poses, iterations, elapsed, mirrored, runs, verified = [], [], [], [], [], []
        rechecked, point_steps = [], []
        for i, cloud in enumerate(scans.clouds):
            request = PoseRequest(
                budget_ms=budget_ms,
                ensemble=k or None,  # 0: the plan's default (the card's, as the budget holds)
                mirror=mirror,
                centre=centre,
                viewpoint=[0.0, 0.0, 0.0] if viewpoint else None,  # the scanner's camera
                up=None if ups is None else [float(v) for v in ups[i]],
                verify=verify if k != 1 else None,
                recheck=recheck if k == 1 else None,
                points_per_run=points,
                strip=strip,
            )
            planned = plan(model, request)
            if full:  # every run on all its points every step, whatever the card's plan says
                planned = replace(planned, coarse=None, halving=None)
            if halving is not None:  # the runs the verifier likes best go on after halving[0]
                planned = replace(planned, halving=halving)
            if coarse is not None:  # the first coarse[0] steps on at most coarse[1] points
                planned = replace(planned, coarse=coarse)
            kept, stripped = cut_out(cloud, request, Limits())  # as served
            run = AnytimeRun(planned, kept, stripped=stripped)
            last = run.run_to_end()
            result = run.result()
            verified.append(result.get("verified"))
            rechecked.append(result.get("rechecked"))
            poses.append(last.pose)
            iterations.append(run.iteration)
            elapsed.append(run.elapsed_ms())
            mirrored.append(result.get("mirror"))
            runs.append(result["ensemble"])
            point_steps.append(run.point_steps)
        _, rot, trans = report(np.stack(poses)[:, None], scans, cat.symmetry)  # symmetry-aware
        correct = is_correct(rot[:, -1], trans[:, -1]).astype(float)
        first = correct if first is None else first
        # against another run of this benchmark on the same scans (--baseline): paired
        before = (baseline or {}).get(scanner, {}).get(str(k), {}).get("correct")
        versus = (
            {"versus_baseline": paired_accuracy(correct, [c == "1" for c in before])}
            if before is not None and len(before) == len(correct)
            else {}
        )
        out[str(k)] = {
            # gain: against the first setting on the same scans (paired), with its s.e.
            **paired_accuracy(correct, first),
            "misses": misses(rot[:, -1], trans[:, -1]),
            **versus,
            "median_iterations": float(np.median(iterations)),
            # the network's work a pose took: points stepped over runs and steps, stages too
            "mean_point_steps": round(float(np.mean(point_steps)), 1),
            **({"runs": {str(r): runs.count(r) for r in sorted(set(runs))}} if k == 0 else {}),
            "median_elapsed_ms": round(float(np.median(elapsed)), 2),
            "p99_elapsed_ms": round(float(np.percentile(elapsed, 99)), 2),
            # where the model's mirror planes were on: the share of runs they finished in time
            **(
                {"mirror_finished": round(float(np.mean([m is True for m in mirrored])), 3)}
                if any(m is not None for m in mirrored)
                else {}
            ),
            # where recheck was on: the share of runs the verifier doubted, and rechecked in time
            **(
                {
                    "doubted": round(float(np.mean([r is not None for r in rechecked])), 3),
                    "rechecked": round(float(np.mean([r is True for r in rechecked])), 3),
                }
                if "recheck" in run.plan.stage_names
                else {}
            ),
            # where verify was on: the share of runs whose probes the budget held
            **(
                {"verified": round(float(np.mean([v is True for v in verified])), 3)}
                if any(v is not None for v in verified)
                else {}
            ),
        }
        log(f"{scanner} K={k} {out[str(k)]}")
        out[str(k)]["correct"] = "".join("1" if c else "0" for c in correct)  # per scan, in order
    return out
