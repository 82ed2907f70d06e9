"""Large JSON bodies parsed in worker processes, so the parse does not hold the server's GIL.

A 250,000-point JSON body takes pydantic ~0.3 s, all of it holding the GIL: in-process, every
other request of the server waits that long (replies of 50 ms budgets came back +580 ms late
beside one client looping such bodies), and the parsed Python lists left the
server's heap ~90 MiB larger afterwards. Here the body goes down a pipe to a worker process
(``service/guards/parse_worker.py``), which runs the server's own checks (so a bad body gets the same
4xx) and sends back the cloud as float64 bytes (24 bytes a point) and the request's other
fields. The server only moves bytes (pipe reads and writes release the GIL); it never holds the
parsed lists.

* At most ``workers`` processes (``json_parse_lanes``), each started on demand (a plain
  subprocess running ``python -m itnet.service.guards.parse_worker``: no ``fork`` of a threaded
  server, no re-import of its ``__main__``) and stopped after ``idle_s`` without a body, so
  their memory (~50 MiB each, mostly imports) is given back when large bodies stop.
* How many bodies wait is bounded by the caller (``Decoder``'s lanes: one parse per worker,
  another large body gets 503 at once) and their bytes by the server's byte budget.
* A worker that dies (killed for memory, say) fails its request with a 503; the next body starts
  a fresh one.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from contextlib import suppress

import numpy as np
from numpy.typing import NDArray

from itnet.service.errors import ServiceError
from itnet.service.schemas import EstimateRequest


def worker_died() -> ServiceError:
    return ServiceError(
        503,
        "overloaded",
        "the JSON parser's worker process died (out of memory?); retry, or send the cloud as "
        "binary (application/octet-stream, 12 bytes a point)",
        headers={"Retry-After": "1"},
    )


class _Worker:
    """One parser process and its pipes; used by one request at a time."""

    def __init__(self) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-m", "itnet.service.guards.parse_worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
        )
        self.last_used = time.monotonic()

    def parse(self, body: bytes | str, schema: str, max_points: int) -> tuple[bytes, dict]:
        assert self.process.stdin is not None and self.process.stdout is not None
        data = body.encode("utf-8") if isinstance(body, str) else body
        text = int(isinstance(body, str))
        try:
            self.process.stdin.write(b"%d %d %d %s\n" % (len(data), text, max_points,
                                                          schema.encode()))  # fmt: skip
            self.process.stdin.write(data)
            self.process.stdin.flush()
            del data
            head = self.process.stdout.readline().split()
            if not head:
                raise worker_died()
            if head[0] == b"error":
                detail = json.loads(self.process.stdout.readline())
                raise ServiceError(int(head[1]), head[2].decode(), detail)
            cloud = self.process.stdout.read(int(head[1]))
            fields = json.loads(self.process.stdout.readline())
        except (OSError, ValueError, IndexError):  # a broken pipe or a cut reply
            raise worker_died() from None
        finally:
            self.last_used = time.monotonic()
        return cloud, fields

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self) -> None:
        """Close its stdin (it exits at the end of the request stream) and reap it."""
        with suppress(OSError):
            if self.process.stdin is not None:
                self.process.stdin.close()
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        with suppress(OSError):
            if self.process.stdout is not None:
                self.process.stdout.close()


class ParsePool:
    """``parse(body, schema, max_points)`` -> (cloud (N, 3) float64, request without points),
    in a worker process; thread-safe, at most ``workers`` parses at once (the caller bounds it:
    one more waits for a free worker)."""

    def __init__(self, workers: int = 1, idle_s: float = 30.0) -> None:
        self.workers, self.idle_s = workers, idle_s
        self._lock = threading.Lock()
        self._free = threading.Semaphore(workers)
        self._idle: list[_Worker] = []
        self.busy: set[_Worker] = set()  # workers parsing now
        self._timer: threading.Timer | None = None
        self.started = 0  # worker processes started so far

    @property
    def running(self) -> int:
        """Idle worker processes alive now."""
        with self._lock:
            return sum(w.alive() for w in self._idle)

    def parse(
        self, body: bytes | str, schema: type[EstimateRequest], max_points: int
    ) -> tuple[NDArray[np.float64], EstimateRequest]:
        with self._free:
            worker = self._take()
            try:
                cloud, fields = worker.parse(body, schema.__name__, max_points)
            except ServiceError as err:
                if err.status >= 500:  # the worker is gone: do not keep it
                    with self._lock:
                        self.busy.discard(worker)
                    worker.stop()
                else:
                    self._give(worker)
                raise
            self._give(worker)
        points = np.frombuffer(cloud, dtype="<f8").reshape(-1, 3)
        return points, schema.model_construct(**fields, points=[])

    def close(self) -> None:
        """Stop every idle worker (at the server's shutdown)."""
        with self._lock:
            idle, self._idle = self._idle, []
            if self._timer is not None:
                self._timer.cancel()
        for worker in idle:
            worker.stop()

    def _take(self) -> _Worker:
        with self._lock:
            while self._idle:
                worker = self._idle.pop()
                if worker.alive():
                    self.busy.add(worker)
                    return worker
                worker.stop()
            self.started += 1
        worker = _Worker()
        with self._lock:
            self.busy.add(worker)
        return worker

    def _give(self, worker: _Worker) -> None:
        with self._lock:
            self.busy.discard(worker)
            self._idle.append(worker)
            if self._timer is None:
                self._schedule(self.idle_s)

    def _schedule(self, seconds: float) -> None:
        self._timer = threading.Timer(seconds, self._stop_idle)
        self._timer.daemon = True
        self._timer.start()

    def _stop_idle(self) -> None:
        """Stop the workers idle for ``idle_s``; look again later while any is left."""
        now = time.monotonic()
        with self._lock:
            stale = [w for w in self._idle if now - w.last_used >= self.idle_s]
            self._idle = [w for w in self._idle if w not in stale]
            self._timer = None
            if self._idle:
                oldest = min(w.last_used for w in self._idle)
                self._schedule(max(0.1, oldest + self.idle_s - now))
        for worker in stale:
            worker.stop()
