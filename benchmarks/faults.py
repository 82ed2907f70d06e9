"""Fault injection against a real ``itnet serve`` on loopback; prints what each fault did.

    python -m benchmarks.faults                  # every fault, about a minute
    python -m benchmarks.faults --storm 200

1. A storm of faulty clients at once: POSTs abandoned after 20 ms, streams cancelled at once,
   streams dropped mid-run without a close frame, slow stream readers (2 s before reading),
   silent sockets (slowloris), oversize headers, bodies trickled and abandoned. Afterwards: no
   slot held, nothing in flight, no 5xx counted, a good request answered, RSS before/after.
2. SIGTERM while long requests run: new connections refused, the requests in flight answered in
   full, the exit status and how long the drain took.
3. Start-up with a missing, empty or corrupt model: exit status and the first line said.
"""

from __future__ import annotations

import json
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import typer
from websockets.exceptions import WebSocketException
from websockets.sync.client import connect

from benchmarks.harness import Server, model_dir, sample_cloud, serve

LONG = {"budget_ms": 3000, "max_iterations": 200}


def faulty_client(
    server: Server, kind: str, body: str, outcomes: dict[str, dict[str, int]]
) -> None:
    """One faulty client of the storm; records what happened to it."""
    host, port = server.url.removeprefix("http://").split(":")
    outcome = "ok"
    try:
        if kind == "abandoned POST":
            httpx.post(f"{server.url}/v1/estimate", content=body, timeout=0.02,
                       headers={"content-type": "application/json"})  # fmt: skip
            outcome = "answered within 20 ms"
        elif kind.startswith("stream"):
            with connect(server.ws_url, open_timeout=20) as ws:
                ws.send(body)
                if kind == "stream cancelled":
                    ws.send('{"type": "cancel"}')
                elif kind == "stream slow reader":
                    time.sleep(2.0)
                first = json.loads(ws.recv(timeout=20))
                if kind == "stream dropped" and first["type"] == "estimate":
                    ws.socket.close()
                    outcome = "dropped mid-run"
                else:
                    while first["type"] == "estimate":
                        first = json.loads(ws.recv(timeout=20))
                    outcome = first.get("stopped_by") or first.get("kind")
        else:
            sock = socket.create_connection((host, int(port)), timeout=20)
            head = b"POST /v1/estimate HTTP/1.1\r\nHost: x\r\n"
            if kind == "oversize headers":
                sock.sendall(head + b"X-Pad: " + b"a" * 100_000 + b"\r\n\r\n")
            elif kind == "trickled body":
                sock.sendall(head + b"content-type: application/json\r\ncontent-length: 99999"
                             b"\r\n\r\n" + body.encode()[:100])  # fmt: skip
                time.sleep(random.uniform(0.1, 1.0))
            else:  # silent socket: part of a request line, then nothing
                sock.sendall(b"GET /heal")
            sock.settimeout(20 if kind == "silent socket" else 2)
            reply = sock.recv(200)
            outcome = reply.split(b"\r\n")[0].decode() if reply else "closed by the server"
            sock.close()
    except httpx.TimeoutException:
        outcome = "client gave up"
    except (WebSocketException, OSError, TimeoutError) as err:
        outcome = type(err).__name__
    counts = outcomes.setdefault(kind, {})
    counts[outcome] = counts.get(outcome, 0) + 1


KINDS = ["abandoned POST", "stream cancelled", "stream dropped", "stream slow reader",
         "silent socket", "oversize headers", "trickled body"]  # fmt: skip


def storm(server: Server, clients: int, body: str) -> None:
    rss_before = server.rss_mb()
    outcomes: dict[str, dict[str, int]] = {}
    threads = [threading.Thread(target=faulty_client, args=(server, KINDS[i % len(KINDS)],
                                                             body, outcomes))
               for i in range(clients)]  # fmt: skip
    start = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    seconds = time.perf_counter() - start
    metrics = ""
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:  # until the last cancelled run has stopped
        metrics = httpx.get(f"{server.url}/metrics").text
        if "itnet_in_flight 0.0" in metrics:
            break
        time.sleep(0.1)
    errors = [line for line in metrics.splitlines()
              if line.startswith("itnet_requests_total") and not line.endswith(" 0.0")
              and ('status="5' in line or "1011" in line) and 'status="503"' not in line]  # fmt: skip
    good = httpx.post(f"{server.url}/v1/estimate", content=body, timeout=30,
                      headers={"content-type": "application/json"})  # fmt: skip
    typer.echo(f"storm: {clients} faulty clients in {seconds:.1f} s")
    typer.echo("| fault | clients | outcomes |\n|---|---|---|")
    for kind in KINDS:
        counts = outcomes.get(kind, {})
        typer.echo(f"| {kind} | {sum(counts.values())} | {json.dumps(counts)} |")
    typer.echo(f"after: in flight 0: {'itnet_in_flight 0.0' in metrics}; 5xx (but 503 busy) or "
               f"1011 counted: "
               f"{errors or 'none'}; good request: {good.status_code} "
               f"({good.json().get('iterations')} iterations); RSS {rss_before:.0f} -> "
               f"{server.rss_mb():.0f} MiB")  # fmt: skip


def sigterm(folder: Path, body: str, log: Path, requests: int = 4) -> None:
    replies: list[tuple[int, str, float]] = []
    with serve(folder, log) as server:

        def post() -> None:
            try:
                reply = httpx.post(f"{server.url}/v1/estimate", content=body, timeout=30,
                                   headers={"content-type": "application/json"})  # fmt: skip
                replies.append((reply.status_code, reply.json()["stopped_by"], time.perf_counter()))
            except httpx.HTTPError as err:
                replies.append((0, type(err).__name__, time.perf_counter()))

        threads = [threading.Thread(target=post) for _ in range(requests)]
        for thread in threads:
            thread.start()
        time.sleep(1.0)
        sent = time.perf_counter()
        server.process.send_signal(signal.SIGTERM)
        time.sleep(0.2)
        try:
            httpx.get(f"{server.url}/healthz", timeout=2)
            new = "accepted (wrong)"
        except httpx.ConnectError:
            new = "refused"
        for thread in threads:
            thread.join(timeout=40)
        status = server.process.wait(timeout=40)
        exited = time.perf_counter() - sent
    late = [r for r in replies if r[2] > sent]
    typer.echo(f"SIGTERM with {requests} requests of 3 s in flight: new connection {new}; "
               f"replies {[(s, why) for s, why, _ in replies]} ({len(late)} finished after the "
               f"signal); exit status {status} {exited:.1f} s after the signal")  # fmt: skip


def startup(folder: Path, tmp: Path) -> None:
    broken = {"missing folder": tmp / "nowhere", "empty folder": tmp / "empty",
              "corrupt file": tmp / "corrupt", "truncated file": tmp / "truncated"}  # fmt: skip
    for path in list(broken.values())[1:]:
        path.mkdir(parents=True, exist_ok=True)
    (broken["corrupt file"] / "chair.onnx").write_bytes(bytes(range(256)) * 64)
    data = (folder / "chair.onnx").read_bytes()
    (broken["truncated file"] / "chair.onnx").write_bytes(data[: len(data) // 3])
    for name, path in broken.items():
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-c", "from itnet.cli import app; app()", "serve",
                               "--model-dir", str(path)], capture_output=True, text=True,
                              timeout=60)  # fmt: skip
        said = (done.stderr.strip().splitlines() or [""])[-1][:110]
        typer.echo(f"start-up, {name}: exit {done.returncode} in "
                   f"{time.perf_counter() - start:.1f} s: {said}")  # fmt: skip


def main(
    storm_clients: int = typer.Option(140, "--storm", help="Faulty clients in the storm."),
    models: Path | None = typer.Option(None, help="Model folder (default: shipped or stand-in)."),
    log: Path = typer.Option(Path("/tmp/itnet-faults-server.log"), help="Server log file."),
) -> None:
    """Inject every fault and print what happened."""
    folder = model_dir(models)
    body = json.dumps({"points": sample_cloud(2048).tolist(), **LONG})
    with serve(folder, log, {"ITNET_SERVER__HEADER_TIMEOUT_S": "2",
                             "ITNET_LIMITS__BODY_TIMEOUT_S": "2"}) as server:  # fmt: skip
        storm(server, storm_clients, body)
    sigterm(folder, body, log)
    startup(folder, Path("/tmp/itnet-faults"))


if __name__ == "__main__":
    typer.run(main)
