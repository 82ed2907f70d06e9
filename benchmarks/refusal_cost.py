"""What a refused estimate costs the server: its CPU time per 503.

    python -m benchmarks.refusal_cost                  # 3,000 refusals, by the protocol and by the app
    python -m benchmarks.refusal_cost --refusals 10000 --by protocol

The service (the shipped models, default settings) runs in this process on a loopback socket
with every estimate slot held, so each request is refused and nothing else runs; a client in a
process of its own sends ``--refusals`` binary chair requests (800 float32 points, ``budget_ms``
20) on one keep-alive connection, one after another. The server's CPU time is this process's
(``time.process_time``) over the client's run, divided by the refusals. ``--by app`` leaves out
the protocol's front gate (``service/guards/front_gate.py``) so that the app's own check refuses
each request after its middleware, router and dependencies, for comparison.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import time
from contextlib import ExitStack
from typing import Annotated

import typer

from itnet.pose.runtime import default_model_dir, load_models
from itnet.service.app import create_app
from itnet.service.guards import protocol
from itnet.service.server import serving_in_thread
from itnet.service.settings import Settings

CLIENT = """
import sys, httpx, numpy as np
body = np.random.default_rng(0).normal(size=(800, 3)).astype("<f4").tobytes()
with httpx.Client(base_url=sys.argv[1]) as client:
    for _ in range(int(sys.argv[2])):
        reply = client.post("/v1/estimate?model=chair&budget_ms=20", content=body,
                            headers={"content-type": "application/octet-stream"})
        assert reply.status_code == 503, reply.text
"""


def refusal_ms(settings: Settings, refusals: int, by_protocol: bool) -> tuple[float, float]:
    """(the server's CPU ms, the client's wall ms) per refused request."""
    app = create_app(settings, load_models(settings.model_dir, threads=1))
    front = protocol.front_gate
    if not by_protocol:
        protocol.front_gate = lambda *_: None
    try:
        with serving_in_thread(app, settings) as (url, _), ExitStack() as slots:
            gate = app.state.service.gate
            for _ in range(gate.limit):
                slots.enter_context(gate.slot())
            cpu, wall = time.process_time(), time.perf_counter()
            subprocess.run([sys.executable, "-c", CLIENT, url, str(refusals)], check=True)
            cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    finally:
        protocol.front_gate = front
    return cpu / refusals * 1e3, wall / refusals * 1e3


def main(
    refusals: Annotated[int, typer.Option(min=1)] = 3000,
    by: Annotated[str, typer.Option(help="protocol, app or both (taking turns, twice)")] = "both",
) -> None:
    """Print the server's CPU time per refused request."""
    settings = Settings(model_dir=default_model_dir(), warm_up=False)
    ways = {"protocol": [True], "app": [False], "both": [True, False, True, False]}[by]
    print(f"{platform.machine()}, {len(os.sched_getaffinity(0))} cores; "
          f"{refusals} refusals a row")  # fmt: skip
    for by_protocol in ways:
        cpu, wall = refusal_ms(settings, refusals, by_protocol)
        name = "protocol" if by_protocol else "app"
        print(f"refused by the {name:8s}: server CPU {cpu:.3f} ms, round trip {wall:.3f} ms")


if __name__ == "__main__":
    typer.run(main)
