"""The Ray Data workers of ``itnet batch``: actors that load the models once each, then turn
batches of cloud files (pairs, scenes) into rows, a bad file becoming a row with an ``error``.

A batch goes in as a column of paths and comes out as a column of JSON rows (``row``): the rows
are exactly what ``itnet pose --json`` / ``itnet align --json`` / ``itnet scene --json`` print,
whatever their shape, and the driver writes them as they are. A ``worker`` column (the actor's process id) and a ``done_at``
column (when the worker finished the batch) let the driver tell when every worker is up and
how fast they go; neither is written.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from itnet.request_fields import parse_xyz
from itnet.scale.inputs import InputError


def _load(model: str, model_dir: str | None, threads: int):  # type: ignore[no-untyped-def]
    """The folder's models (with what lies beside them: the classifier, the verifiers) as the
    pose pipeline serves them, with ``threads`` onnxruntime threads (one step at a time), and
    the named model."""
    from itnet.pose.catalog import Catalog
    from itnet.pose.runtime import default_model_dir, load_all

    folder = Path(model_dir) if model_dir else default_model_dir()
    models, classifier = load_all(folder, threads, True, 1)
    if model != "auto" and model not in models:  # 'auto': the classifier names each cloud's
        raise InputError(f"unknown model {model!r} (available: {', '.join(sorted(models))})")
    return Catalog(models, classifier), models.get(model)


def _error_row(fields: dict[str, Any], model: str, err: Exception) -> dict[str, Any]:
    return {**fields, "model": model, "error": str(err)}


def _batch(rows: list[str]) -> dict[str, np.ndarray]:
    """The batch's rows, the worker that made them and when it finished them (``time.time()``:
    the driver's steady rate is counted by the workers' clocks, not by when Ray hands the
    batches over, which may be all at once)."""
    return {"row": np.array(rows, dtype=object), "worker": np.full(len(rows), os.getpid()),
            "done_at": np.full(len(rows), time.time())}  # fmt: skip


class PoseWorker:
    """``{"file": [...]}`` -> ``{"row": [json, ...]}``, one ``itnet pose --json`` row a file."""

    def __init__(
        self, model: str, model_dir: str | None, threads: int, request: dict[str, Any]
    ) -> None:  # fmt: skip
        from itnet.pose.request import PoseRequest

        self.catalog, _ = _load(model, model_dir, threads)
        self.request = PoseRequest.model_validate({**request, "model": model})
        self.model = model

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        from itnet.cloud_io import CloudReadError
        from itnet.pose.errors import PoseError
        from itnet.pose.files import pose_row
        from itnet.pose.loop import AnytimeRun

        def start(cloud: np.ndarray) -> AnytimeRun:
            return self.catalog.start(cloud, self.request)

        rows = []
        for file in batch["file"]:
            try:
                row = pose_row(Path(str(file)), start)
            except (CloudReadError, PoseError) as err:
                row = _error_row({"file": str(file)}, self.model, err)
            rows.append(json.dumps(row))
        return _batch(rows)


class AlignWorker:
    """``{"cloud_a": [...], "cloud_b": [...]}`` (and ``up_a``, ``up_b``: 'x,y,z' or '') ->
    ``{"row": [json, ...]}``, one ``itnet align --json`` row a pair (without ``output``: the
    batch writes no moved clouds)."""

    def __init__(self, model: str, model_dir: str | None, threads: int,
                 request: dict[str, Any]) -> None:  # fmt: skip
        from itnet.alignment.estimators import in_process_estimator
        from itnet.alignment.request import AlignRequest

        catalog, loaded = _load(model, model_dir, threads)
        self.name = loaded.card.name
        asked = AlignRequest.model_validate({**request, "model": loaded.card.name})
        self.estimate = in_process_estimator(catalog, asked.pose_request())
        self.options = asked.options(loaded.card, bool(asked.refine))
        self.asked = asked

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        from itnet.alignment.pipeline import CloudEstimateError, align_clouds
        from itnet.cloud_io import CloudReadError, read_cloud

        rows = []
        for i, (a, b) in enumerate(zip(batch["cloud_a"], batch["cloud_b"])):
            fields = {"cloud_a": str(a), "cloud_b": str(b)}
            # which way is up in each cloud ('x,y,z', '' where the manifest does not say)
            given = {k: str(batch[k][i]) if k in batch else "" for k in ("up_a", "up_b")}
            ups = {k: parse_xyz(u) if u else getattr(self.asked, k) for k, u in given.items()}
            try:
                points_a, points_b = read_cloud(str(a)), read_cloud(str(b))
                result = align_clouds(points_a, points_b, self.estimate, self.options,
                                      ups["up_a"], ups["up_b"])  # fmt: skip
                row = {**fields, "model": self.name, "symmetry": self.options.symmetry,
                       **result.to_dict(), **{k: u for k, u in ups.items() if u is not None}}  # fmt: skip
            except CloudReadError as err:
                row = _error_row(fields, self.name, err)
            except CloudEstimateError as err:
                cloud = fields["cloud_a"] if err.cloud == "A" else fields["cloud_b"]
                row = _error_row(fields, self.name, ValueError(f"{cloud}: {err.__cause__}"))
            rows.append(json.dumps(row))
        return _batch(rows)


class SceneWorker:
    """``{"file": [...]}`` -> ``{"row": [json, ...]}``, one ``itnet scene --json`` row a depth
    image or scene cloud, and one a frame of a recording (with its ``topic``, ``frame`` and
    ``header``; ``selection``: ``itnet.recordings.Selection``'s fields) (``arguments``:
    ``find_objects``' keywords, as ``itnet.commands.scene.scene_arguments`` makes them from a ``SceneRequest``); a file
    or frame that cannot be used becomes a row with ``file`` and ``error``."""

    def __init__(
        self, model_dir: str | None, threads: int, arguments: dict[str, Any], indices: bool,
        selection: dict[str, Any] | None = None,
    ) -> None:  # fmt: skip
        from itnet.recordings import Selection
        from itnet.scene.posing import scene_catalog
        from itnet.scene.warm_up import warm_up

        self.catalog = scene_catalog(Path(model_dir) if model_dir else None, threads)
        warm_up(self.catalog)  # no frame's budget is spent on one-time work
        self.arguments, self.indices = arguments, indices
        self.selection = Selection(**(selection or {}))

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        from itnet.recordings import is_recording
        from itnet.scene import SceneInputError, find_objects
        from itnet.scene.result import scene_row

        rows = []
        for file in batch["file"]:
            if is_recording(Path(str(file))):
                rows.extend(json.dumps(row) for row in self._recording(Path(str(file))))
                continue
            try:
                result = find_objects(Path(str(file)), catalog=self.catalog, **self.arguments)
                row = scene_row(str(file), result, self.indices)
            except SceneInputError as err:
                row = {"file": str(file), "error": str(err)}
            rows.append(json.dumps(row))
        return _batch(rows)

    def _recording(self, path: Path) -> list[dict[str, Any]]:
        """A row a frame of the recording (a row with the error for a frame that cannot be used,
        or for the whole recording where it cannot be read)."""
        from itnet.recordings import RecordingError, SceneAnswer, scene_answers
        from itnet.recordings.answer import scene_finder

        find = scene_finder(self.catalog, self.arguments)
        rows: list[dict[str, Any]] = []
        try:
            for item in scene_answers(path, self.selection, find, self.arguments["intrinsics"],
                                      self.arguments["depth_scale"]):  # fmt: skip
                if isinstance(item, SceneAnswer):
                    rows.append(item.row(self.indices))
                else:
                    rows.append({"file": str(path), "topic": item.topic, "frame": item.index,
                                 "error": item.reason})  # fmt: skip
        except RecordingError as err:
            rows.append({"file": str(path), "error": str(err)})
        return rows
