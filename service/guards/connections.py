"""The open connections of one server, HTTP and WebSocket alike, and who gives way when full.

A connection is in one phase at a time:

* ``HEAD``: waiting for (the rest of) a request line and headers;
* ``BUSY``: a request is being read or answered, or a WebSocket runs its request;
* ``IDLE``: a kept-alive HTTP connection between requests;
* ``WS_WAIT``: an upgraded WebSocket that has not yet sent its request.

At most ``cap`` connections are open. A connection that arrives when the table is full takes
the place of the one that has waited longest in an *evictable* phase (``HEAD``, ``IDLE``,
``WS_WAIT``: it holds nothing and has sent nothing the service would lose), which is closed.
Slow senders and idle sockets therefore cannot keep a client that completes its request out:
each arrival evicts the stalest of them. When every connection is ``BUSY`` the newcomer goes
into the *probe lane* (``probe_lane`` more connections) where only ``GET /healthz`` and
``GET /readyz`` are served (anything else gets the JSON 503), so an orchestrator's probes are
answered when every slot is taken. Beyond that the newcomer is refused at once.

Used from the event loop only (no locks). Connections are keyed by their transport, which an
HTTP connection hands over to its WebSocket when it upgrades.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Hashable
from dataclasses import dataclass


class Phase(enum.Enum):
    HEAD = "head"
    BUSY = "busy"
    IDLE = "idle"
    WS_WAIT = "ws_wait"


EVICTABLE = frozenset({Phase.HEAD, Phase.IDLE, Phase.WS_WAIT})


class Admission(enum.Enum):
    OPEN = "open"  # a regular slot
    PROBE_LANE = "probe_lane"  # probes only
    REFUSED = "refused"  # close at once


@dataclass
class _Entry:
    phase: Phase
    evict: Callable[[], None]
    lane: bool


class ConnectionTable:
    """``cap`` regular connections plus ``probe_lane`` for probes; see the module docstring."""

    def __init__(self, cap: int, probe_lane: int) -> None:
        self.cap, self.probe_lane = cap, probe_lane
        # Insertion order is the order in which each entry entered its phase: the first
        # evictable entry is the stalest.
        self._entries: dict[Hashable, _Entry] = {}
        self.evicted = 0
        self.refused = 0

    def __len__(self) -> int:
        return len(self._entries)

    def open(self, key: Hashable, evict: Callable[[], None]) -> Admission:
        """Admit a new connection in ``HEAD``, evicting the stalest idle one if the table is
        full; ``evict`` closes this connection should it be chosen later."""
        lane = self._regular() >= self.cap and not self._evict_one(lane=False)
        if lane and self.lanes() >= self.probe_lane and not self._evict_one(lane=True):
            self.refused += 1
            return Admission.REFUSED
        self._entries[key] = _Entry(Phase.HEAD, evict, lane=lane)
        return Admission.PROBE_LANE if lane else Admission.OPEN

    def adopt(self, key: Hashable, evict: Callable[[], None], phase: Phase) -> None:
        """The connection under ``key`` changes hands (HTTP -> WebSocket): new closer, phase."""
        entry = self._entries.pop(key, None)
        self._entries[key] = _Entry(phase, evict, lane=entry.lane if entry else False)

    def set_phase(self, key: Hashable, phase: Phase) -> None:
        entry = self._entries.pop(key, None)
        if entry is not None:
            entry.phase = phase
            self._entries[key] = entry  # to the end: its phase starts now

    def in_lane(self, key: Hashable) -> bool:
        entry = self._entries.get(key)
        return entry is not None and entry.lane

    def close(self, key: Hashable) -> None:
        """Forget a closed connection; a regular slot it frees goes to the oldest lane entry."""
        entry = self._entries.pop(key, None)
        if entry is not None and not entry.lane:
            for other in self._entries.values():
                if other.lane:
                    other.lane = False
                    return

    def lanes(self) -> int:
        return sum(entry.lane for entry in self._entries.values())

    def phases(self) -> dict[str, int]:
        counts = {phase.value: 0 for phase in Phase}
        for entry in self._entries.values():
            counts[entry.phase.value] += 1
        return counts

    def _evict_one(self, lane: bool) -> bool:
        """Close the stalest evictable connection of the regular slots (or of the lane)."""
        for key, entry in self._entries.items():
            if entry.phase in EVICTABLE and entry.lane == lane:
                del self._entries[key]  # freed now; its connection_lost finds nothing left
                self.evicted += 1
                entry.evict()
                return True
        return False

    def _regular(self) -> int:
        return len(self._entries) - self.lanes()
