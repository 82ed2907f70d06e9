"""Keep Python's garbage collector from pausing the service for tens of milliseconds.

A full (generation 2) collection walks every tracked object in the process: after importing
FastAPI, pydantic, numpy and onnxruntime that is ~77,000 objects, and a pass took 40-49 ms on
this 2-core machine. Each JSON body allocates thousands of lists and floats, so under load such
passes came about twice a second, holding the GIL: every request in flight stalled, and at 4
concurrent clients the 99th-percentile reply overran a 50 ms budget by 29 ms.

``freeze_startup_objects`` collects once after start-up and moves the survivors to the
permanent generation (``gc.freeze``), so later passes only walk what requests allocate.
``GcPauseRecorder`` times every pass for the ``itnet_gc_pause_seconds`` histogram.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable
from typing import Any


def freeze_startup_objects() -> int:
    """Collect, then exclude every surviving object from future collections. Returns how many
    objects were frozen."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


class GcPauseRecorder:
    """A ``gc.callbacks`` entry that reports each collection's duration (seconds) and
    generation to ``observe``. ``install``/``remove`` add and take it off the callback list."""

    def __init__(self, observe: Callable[[int, float], None]) -> None:
        self.observe = observe
        self._started = 0.0

    def __call__(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._started = time.perf_counter()
        else:
            self.observe(int(info["generation"]), time.perf_counter() - self._started)

    def install(self) -> None:
        if self not in gc.callbacks:
            gc.callbacks.append(self)

    def remove(self) -> None:
        if self in gc.callbacks:
            gc.callbacks.remove(self)
