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
import struct
from pathlib import Path

import numpy as np

SHARED_ADMISSION_ENV = "ITNET_SHARED_ADMISSION"  # the file, where several processes serve
SLOTS = 256  # processes one file can hold
_RECORD = struct.Struct("<qqd")  # pid, runs, work_ms
_DTYPE = np.dtype([("pid", "<i8"), ("runs", "<i8"), ("work", "<f8")])


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
        size = SLOTS * _RECORD.size
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            if os.fstat(fd).st_size < size:
                os.ftruncate(fd, size)
            self._map = mmap.mmap(fd, size)
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
        for slot in range(SLOTS):
            pid, _, _ = _RECORD.unpack_from(self._map, slot * _RECORD.size)
            if pid == self.pid or not _alive(pid):
                _RECORD.pack_into(self._map, slot * _RECORD.size, self.pid, 0, 0.0)
                return slot
        raise RuntimeError(f"all {SLOTS} shared admission records are held by live processes")

    def publish(self, runs: int, work_ms: float) -> None:
        """This process's admitted runs and the work they still need."""
        _RECORD.pack_into(self._map, self.slot * _RECORD.size, self.pid, runs, work_ms)

    def others(self) -> tuple[int, float]:
        """(runs, work_ms) admitted by the other live processes."""
        records = np.frombuffer(self._map, dtype=_DTYPE)
        busy = np.flatnonzero(
            (records["pid"] != 0) & ((records["runs"] != 0) | (records["work"] != 0))
        )
        runs, work = 0, 0.0
        for slot in busy:
            pid, n, ms = records[slot]
            if slot != self.slot and _alive(int(pid)):
                runs, work = runs + int(n), work + float(ms)
        return runs, work

    def close(self) -> None:
        """Give the record back (the process stops serving)."""
        _RECORD.pack_into(self._map, self.slot * _RECORD.size, 0, 0, 0.0)
        self._map.close()
