"""Slow-loris attackers: sockets that dribble a request head and reconnect whenever closed.

    python -m benchmarks.slowloris PORT SOCKETS SECONDS [--head-bytes N] [--interval S]

``SOCKETS`` attackers, each sending a request head a byte every ``interval`` seconds and
reconnecting whenever the server closes it, for ``SECONDS`` after the first round of connections
is open. Prints ``ready`` once every attacker has connected, and at the end the number of
connections opened in all. The hardening test (``tests/hardening``) and the hostile-client
benchmark (``benchmarks.hostile``) both run this attack, each in a process of its own: a real
attack comes from elsewhere, and an attacker sharing the server's process would share its
interpreter lock and garbage collections.
"""

from __future__ import annotations

import asyncio
import time

import typer


def request_head(filler_bytes: int) -> bytes:
    """A GET head that never ends: a header of ``filler_bytes`` bytes, no blank line."""
    return b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * filler_bytes


async def attacker(
    port: int,
    head: bytes,
    interval_s: float,
    stop: list[float],
    opened: list[int],
    connected: asyncio.Event,
) -> None:
    """One attacker: send ``head`` a byte every ``interval_s``; reconnect when the server closes.
    Runs until ``stop`` holds a deadline (perf_counter) and it has passed; counts connections
    in ``opened[0]``; sets ``connected`` at its first connection."""
    while not stop or time.perf_counter() < stop[0]:
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
        except OSError:
            await asyncio.sleep(0.05)
            continue
        opened[0] += 1
        connected.set()
        try:
            for byte in head:
                if (stop and time.perf_counter() > stop[0]) or reader.at_eof():
                    break
                writer.write(bytes([byte]))
                await writer.drain()
                await asyncio.sleep(interval_s)
        except OSError:
            pass
        finally:
            writer.close()


async def attack(
    port: int, sockets: int, seconds: float, head: bytes, interval_s: float, ready: bool = True
) -> int:
    """``sockets`` attackers for ``seconds`` once all have connected -> connections opened."""
    stop: list[float] = []
    opened = [0]
    events = [asyncio.Event() for _ in range(sockets)]
    tasks = [
        asyncio.create_task(attacker(port, head, interval_s, stop, opened, event))
        for event in events
    ]
    await asyncio.gather(*(event.wait() for event in events))
    stop.append(time.perf_counter() + seconds)
    if ready:
        print("ready", flush=True)
    await asyncio.gather(*tasks)
    return opened[0]


def main(
    port: int,
    sockets: int,
    seconds: float,
    head_bytes: int = typer.Option(1000, help="Filler bytes of the never-ending header."),
    interval: float = typer.Option(0.1, help="Seconds between two bytes."),
) -> None:
    print(asyncio.run(attack(port, sockets, seconds, request_head(head_bytes), interval)))


if __name__ == "__main__":
    typer.run(main)
