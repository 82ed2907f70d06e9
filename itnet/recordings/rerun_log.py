"""A 3D log of a recording's answers for the Rerun viewer (``rerun-sdk``): per frame, on the
``frame`` and ``stamp`` timelines, the scene's points (each object's in its own colour), each
object's box labelled with its category and probability, and its pose's axes (x red, y green:
up, z blue: its front).

Entities: ``camera`` (the optical frame: x right, y down, z ahead, as ``ViewCoordinates.RDF``),
``camera/points``, ``camera/objects`` (the boxes), ``camera/objects/axes``. Open a saved log with
``rerun out.rrd``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from itnet.geometry import invert_rigid, matrix_to_quat_wxyz

MAX_LOGGED_POINTS = 60_000  # a frame's points are thinned to about this many
AXIS_LENGTH_M = 0.25
BACKGROUND = (150, 150, 150)
PALETTE = np.array(
    [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180),
     (70, 240, 240), (240, 50, 230), (210, 245, 60), (0, 128, 128), (170, 110, 40)],
    dtype=np.uint8,
)  # fmt: skip


class RerunUnavailable(RuntimeError):
    """rerun-sdk is not installed."""


class RerunLog:
    """One Rerun recording: saved to ``path`` (an .rrd file), or sent to a spawned viewer where
    ``path`` is None."""

    def __init__(self, path: Path | None, name: str = "itnet") -> None:
        try:
            import rerun as rr
        except ImportError as err:
            raise RerunUnavailable(
                f"--rerun needs rerun-sdk (pip install 'itnet[recordings]'): {err}"
            ) from None
        self.rr = rr
        self.stream = rr.RecordingStream(name)
        if path is None:
            self.stream.spawn(default_blueprint=camera_view())
        else:
            self.stream.save(path, default_blueprint=camera_view())
        self.stream.log("camera", rr.ViewCoordinates.RDF, static=True)

    def log_frame(self, index: int, stamp_ns: int, points: NDArray,
                  objects: list[dict[str, Any]], object_rows: list[NDArray]) -> None:  # fmt: skip
        """One frame: ``points`` (N, 3) of the scene, ``objects`` as ``SceneObject.as_dict``
        gives them and ``object_rows`` each object's rows into ``points``."""
        rr, stream = self.rr, self.stream
        stream.set_time("frame", sequence=index)
        stream.set_time("stamp", timestamp=stamp_ns * 1e-9)
        colours = np.tile(np.array(BACKGROUND, np.uint8), (len(points), 1))
        for i, rows in enumerate(object_rows):
            colours[rows] = PALETTE[i % len(PALETTE)]
        keep = thinned(len(points), object_rows)
        stream.log("camera/points", rr.Points3D(points[keep], colors=colours[keep], radii=0.004))
        self._log_objects(objects)

    def _log_objects(self, objects: list[dict[str, Any]]) -> None:
        rr, stream = self.rr, self.stream
        if not objects:
            stream.log("camera/objects", rr.Clear(recursive=True))
            return
        boxes = [o["box"] for o in objects]
        quats = [matrix_to_quat_wxyz(np.asarray(b["R_camera_from_box"])) for b in boxes]
        stream.log("camera/objects", rr.Boxes3D(
            centers=[b["center"] for b in boxes],
            half_sizes=[np.asarray(b["size"]) / 2 for b in boxes],
            quaternions=[rr.Quaternion(xyzw=[q[1], q[2], q[3], q[0]]) for q in quats],
            colors=PALETTE[np.arange(len(objects)) % len(PALETTE)],
            labels=[label(o) for o in objects],
        ))  # fmt: skip
        origins, vectors, colours = [], [], []
        for obj in objects:
            if obj.get("T_canonical_from_input") is None:
                continue
            pose = invert_rigid(np.asarray(obj["T_canonical_from_input"], dtype=np.float64))
            for axis, colour in enumerate(((255, 0, 0), (0, 255, 0), (0, 0, 255))):
                origins.append(pose[:3, 3])
                vectors.append(pose[:3, axis] * AXIS_LENGTH_M)
                colours.append(colour)
        stream.log("camera/objects/axes", rr.Arrows3D(origins=np.reshape(origins, (-1, 3)),
                   vectors=np.reshape(vectors, (-1, 3)), colors=np.reshape(colours, (-1, 3))))  # fmt: skip

    def close(self) -> None:
        self.stream.flush()
        self.stream.disconnect()


def camera_view() -> Any:
    """The viewer's layout: one 3D view seen from just behind and above the camera, looking
    where it looks, the side panels folded away and the timeline open."""
    import rerun.blueprint as rrb

    eye = rrb.EyeControls3D(position=[0.0, -0.9, -0.6], look_target=[0.0, 0.45, 3.2],
                            eye_up=[0.0, -1.0, 0.0])  # fmt: skip
    view = rrb.Spatial3DView(origin="/", name="camera", eye_controls=eye)
    return rrb.Blueprint(view, rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"), rrb.TimePanel(state="expanded"))  # fmt: skip


def label(obj: dict[str, Any]) -> str:
    """An object's label: its category (or 'unknown') and probability, and 'no pose' where it has none."""
    name = obj.get("category") or "unknown"
    posed = "" if obj.get("T_canonical_from_input") is not None else ", no pose"
    return f"{name} {obj.get('category_probability', 0.0):.2f}{posed}"


def thinned(count: int, object_rows: list[NDArray]) -> NDArray[np.int64]:
    """Rows to log: every object point, and the rest strided down to about MAX_LOGGED_POINTS."""
    stride = max(1, int(np.ceil(count / MAX_LOGGED_POINTS)))
    keep = np.zeros(count, dtype=bool)
    keep[::stride] = True
    for rows in object_rows:
        keep[rows[:: max(1, stride // 2)]] = True
    return np.flatnonzero(keep)
