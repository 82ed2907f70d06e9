"""The work admitted by every process serving on one machine, so that ``itnet serve --workers N``
admits one machine's worth, not N.

    shared = SharedWork(Path("/tmp/itnet-admission"))  # the same file in every worker
    shared.publish(runs=2, work_ms=30.0)                # this process's admitted runs and work
    shared.others()                                     # (runs, work_ms) of the other processes

A file of ``SLOTS`` fixed records (process id, runs admitted, their needed work in ms), mapped
into each process's memory. A process claims a free record once (under a lock on the file: a
record that is empty or whose process has died) and then writes only its own; reading the
others takes no lock (each record is one writer's, and admission is an estimate: a record read
while it changes is at worst a moment off). A dead process's record is ignored, so a killed
worker's runs do not hold the machine.
"""

from __future__ import annotations

import fcntl
import mmap
import os
from pathlib import Path

import numpy as np

SHARED_ADMISSION_ENV = "ITNET_SHARED_ADMISSION"  # the file, where several processes serve
SLOTS = 256  # processes one file can hold
RECORD = np.dtype([("pid", "<i8"), ("runs", "<i8"), ("work", "<f8")])  # work: ms of steps


def _alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


class SharedWork:
    """This process's record in the shared file at ``path`` (created where missing), and the
    sums of the others'. Raises OSError where the file cannot be made or mapped, RuntimeError
    where every record is held by a live process."""

    def __init__(self, path: Path, pid: int | None = None) -> None:
        self.pid = os.getpid() if pid is None else pid
        size = SLOTS * RECORD.itemsize
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            if os.fstat(fd).st_size < size:
                os.ftruncate(fd, size)
            self._map = mmap.mmap(fd, size)
            self._records = np.frombuffer(self._map, dtype=RECORD)  # the file's, in place
            self.slot = self._claim()
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)

    @classmethod
    def from_env(cls) -> SharedWork | None:
        """The shared file ``itnet serve --workers N`` names in the environment, else None."""
        path = os.environ.get(SHARED_ADMISSION_ENV)
        return cls(Path(path)) if path else None

    def _claim(self) -> int:
        """The first record that is free (or this process's, or a dead process's): taken."""
        for slot, pid in enumerate(self._records["pid"].tolist()):
            if pid == self.pid or not _alive(pid):
                self._records[slot] = (self.pid, 0, 0.0)
                return slot
        raise RuntimeError(f"all {SLOTS} shared admission records are held by live processes")

    def publish(self, runs: int, work_ms: float) -> None:
        """This process's admitted runs and the work they still need."""
        self._records[self.slot] = (self.pid, runs, work_ms)

    def others(self) -> tuple[int, float]:
        """(runs, work_ms) admitted by the other live processes."""
        records = self._records
        busy = np.flatnonzero(
            (records["pid"] != 0) & ((records["runs"] != 0) | (records["work"] != 0))
        )
        runs, work = 0, 0.0
        for slot in busy:
            pid, n, ms = records[slot].tolist()
            if slot != self.slot and _alive(pid):
                runs, work = runs + n, work + ms
        return runs, work

    def close(self) -> None:
        """Give the record back (the process stops serving)."""
        self._records[self.slot] = (0, 0, 0.0)
        del self._records  # the map closes only once no array looks into it
        self._map.close()
