"""A cloud file's pose row: what ``itnet pose --json`` prints and ``itnet batch pose`` writes."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from itnet.pose.loop import AnytimeRun


def pose_row(path: Path, start: Callable[[NDArray[np.float64]], AnytimeRun]) -> dict[str, Any]:
    """One cloud file -> the row that ``itnet pose --json`` prints and ``itnet batch pose``
    writes: file, the pose fields, iterations, stopped_by, elapsed_ms, model. ``start`` sets up
    the run on the cloud (N, 3). Raises CloudReadError or BadCloudError (a file or cloud that
    cannot be used), or what ``start`` raises."""
    from itnet.cloud_io import read_cloud

    run = start(read_cloud(path))
    run.run_to_end()
    return {"file": str(path), **run.result()}
