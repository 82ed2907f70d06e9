"""Fixtures of the scale tests: Ray is optional (``itnet[ray]``); without it they are skipped."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="session")
def local_ray() -> Iterator[None]:
    """One local Ray instance for every scale test, the 2 CPUs of this machine, shut down after
    the last (starting one takes seconds)."""
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        yield
    finally:
        ray.shutdown()
