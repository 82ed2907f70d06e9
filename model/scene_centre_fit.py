"""Fit each pose model's scene correction (``itnet.scene.centre_along_floor``) on scenes of
training shapes.

Development scenes (``itnet.model.scenes``, desks among them) are made of the pose models'
*training* shapes (never the test shapes the scene benchmark measures), rendered at 320x240, and found by
``find_objects`` as served but without the correction. Every object matched to a scene object,
named right and with its rotation within 20 degrees (the others are in a wrong basin, where no
centre helps) gives the features of its moved points and where its true centre lies in that
frame; a ridge regression per pose model is its correction::

    itnet fit scene-centre                       # writes the shipped table
    itnet fit scene-centre --model-dir DIR --out DIR/centre_along_floor.json

The networks for objects whose base is out of view (``<category>_base_hidden``) pose only such
objects, which the usual scenes rarely hold: their corrections are fitted on scenes of a level
camera with objects cut off by the view, and added to the table as it is::

    itnet fit scene-centre --only chair_base_hidden,toilet_base_hidden \
        --draw chair,toilet,bathtub --pitch 0,0 --most 2 --cut-off

The table names each model's graph by its SHA-256, so it applies only to the graphs it was
fitted for. Choosing it and measuring it: ``benchmarks/bench_scene.py`` (``--no-along-floor``).
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from itnet.centre import fit_centre_correction
from itnet.graph_digest import graph_digest
from itnet.model.categories import MODELNET10
from itnet.model.scenes import (
    FIT_SPLIT,
    WITH_DESKS,
    SceneKind,
    make_scene,
    matched_objects,
    split_shapes,
)
from itnet.scene import find_objects, scene_catalog
from itnet.scene.centre_along_floor import (
    TABLE,
    CentreTable,
    moved_object,
    true_offset,
)
from itnet.scene.pipeline import VIEWPOINT, SceneFinishing, shipped_catalog
from itnet.symmetry import symmetric_rotation_error_deg

FIT_MAX_ROTATION_DEG = 20.0
MIN_OBJECTS = 20  # a model with fewer usable objects gets no correction


def scene_samples(
    shapes: dict, scenes: int, seed: int, catalog, budget_ms: float, **kind: Any
) -> dict[str, tuple[list[NDArray], list[NDArray]]]:
    """``scenes`` scenes of ``shapes`` (``make_scene``'s ``kind``; default: desks among the
    eight) -> per pose model, the features (F,) and true offsets (3,) of its objects found,
    named right and turned within FIT_MAX_ROTATION_DEG."""
    from itnet.scene.inputs import from_depth

    rng = np.random.default_rng(seed)
    samples: dict[str, tuple[list, list]] = defaultdict(lambda: ([], []))
    kind = {"categories": WITH_DESKS, **kind}
    for _ in range(scenes):
        scene = make_scene(shapes, rng, **kind)
        given = from_depth(scene.depth, scene.intrinsics)
        finishing = SceneFinishing(along_floor=False, recheck=False)  # each model's own poses
        result = find_objects(given, budget_ms=budget_ms, catalog=catalog, finishing=finishing)
        pairs = matched_objects([o.indices for o in result.objects], scene.labels,
                                len(scene.objects))  # fmt: skip
        for i, k in pairs:
            obj, truth = result.objects[i], scene.objects[k - 1]
            if obj.pose is None or obj.category != truth.category or obj.run is None:
                continue
            symmetry = MODELNET10[truth.category].symmetry
            turn = float(symmetric_rotation_error_deg(obj.pose[:3, :3], truth.pose[:3, :3],
                                                      symmetry))  # fmt: skip
            if turn > FIT_MAX_ROTATION_DEG:
                continue
            points = given.points[np.searchsorted(given.indices, obj.indices)]
            seen = moved_object(points, obj.pose, VIEWPOINT)
            features, offsets = samples[obj.run["model"]]
            features.append(seen.features)
            offsets.append(true_offset(seen, truth.pose))
    return dict(samples)


def fit_table(samples: dict, catalog, ridge: float) -> tuple[CentreTable, dict]:
    """Per model with at least MIN_OBJECTS samples, its correction and a line of statistics."""
    corrections, stats = {}, {}
    for name, (features, offsets) in sorted(samples.items()):
        x, y = np.array(features), np.array(offsets)
        stats[name] = {"objects": len(x)}
        if len(x) < MIN_OBJECTS:
            continue
        correction = fit_centre_correction(x, y, ridge)
        left = np.linalg.norm(y - correction.predict(x), axis=1)
        stats[name].update(
            mean_offset=[round(float(v), 4) for v in y.mean(0)],
            before_rms=round(float(np.sqrt((np.linalg.norm(y, axis=1) ** 2).mean())), 4),
            after_rms=round(float(np.sqrt((left**2).mean())), 4),
        )
        corrections[name] = (graph_digest(catalog.models[name].path), correction)
    return CentreTable(corrections), stats


class SceneCentreFit(SceneKind):
    """How the pose models' scene corrections are fitted: the scenes (``SceneKind``: which) and
    the ridge regression."""

    scenes: int = Field(default=2000, ge=1, description="scenes of training shapes")
    seed: int = Field(default=11, description="their seed")
    shapes: int = Field(default=150, ge=1, description="training shapes a category")
    ridge: float = Field(default=300.0, ge=0, description="chosen on validation scenes")
    budget_ms: float = Field(
        default=1000.0,
        gt=0,
        description="each scene's budget (generous: the fit wants the served pose's finish)",
    )
    data: Path = Field(default=Path("../shared/data/modelnet10"), description="ModelNet10 root")
    cache: Path = Field(default=Path("cache/scenes"), description="the shapes' cache")
    model_dir: Path | None = Field(
        default=None, description="the models fitted (default: the shipped ones)"
    )
    samples: Path | None = Field(
        default=None,
        description="an .npz of the scenes' samples: read where it exists, else written",
    )
    out: Path = Field(default=TABLE, description="the table written (default: the shipped one)")
    only: str | None = Field(
        default=None,
        description="fit these models (comma-separated) and keep the others' from out",
    )


def fit_centre_table(config: SceneCentreFit) -> tuple[CentreTable, dict]:
    """Fit each pose model's correction on the scenes, write the table to ``config.out`` (the
    models not in ``only`` keep theirs) and return it with each model's statistics. ValueError
    for scenes ``SceneKind`` refuses."""
    kind = config.keywords(WITH_DESKS)
    catalog = shipped_catalog() if config.model_dir is None else scene_catalog(config.model_dir)
    if config.samples is not None and config.samples.exists():
        with np.load(config.samples) as saved:
            names = {key.rsplit("/", 1)[0] for key in saved.files}
            samples = {n: (list(saved[f"{n}/x"]), list(saved[f"{n}/y"])) for n in names}
    else:
        shapes = split_shapes(config.data, FIT_SPLIT, config.cache, limit=config.shapes)
        samples = scene_samples(
            shapes, config.scenes, config.seed, catalog, config.budget_ms, **kind
        )
        if config.samples is not None:
            arrays = {f"{n}/{k}": np.array(v) for n, (x, y) in samples.items()
                      for k, v in (("x", x), ("y", y))}  # fmt: skip
            np.savez(config.samples, **arrays)
    if config.only is not None:
        only = set(config.only.split(","))
        samples = {name: got for name, got in samples.items() if name in only}
    table, stats = fit_table(samples, catalog, config.ridge)
    if config.only is not None:  # the other models keep their corrections
        kept = (
            CentreTable.from_dict(json.loads(config.out.read_text()))
            if config.out.exists()
            else None
        )
        if kept is not None:
            others = {n: c for n, c in kept.corrections.items() if n not in table.corrections}
            table = CentreTable({**others, **table.corrections})
    config.out.write_text(json.dumps(table.to_dict(), indent=1) + "\n")
    return table, stats
