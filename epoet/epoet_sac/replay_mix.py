"""Where ePOET-SAC's replay buffer's transitions came from (the shared replay's `replay/*`
metrics)."""

from __future__ import annotations

from collections import deque
from typing import Any


class ReplayMix:
    """Where the replay buffer's transitions came from (`es`: pool agents, `sac`: SAC's own).

    The buffer is first-in first-out, so its contents are the last `capacity` rows added."""

    SOURCES = ("es", "sac")

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.added = dict.fromkeys(self.SOURCES, 0)
        self._chunks: deque[list] = deque()  # [source, rows] in the order added
        self._held = 0

    def add(self, source: str, rows: int) -> None:
        self.added[source] += rows
        self._chunks.append([source, rows])
        self._held += rows
        while self._held > self.capacity:  # the oldest rows were overwritten
            drop = min(self._chunks[0][1], self._held - self.capacity)
            self._chunks[0][1] -= drop
            self._held -= drop
            if not self._chunks[0][1]:
                self._chunks.popleft()

    def share(self, source: str) -> float:
        """Fraction of the buffer's rows from `source`."""
        return sum(n for s, n in self._chunks if s == source) / max(self._held, 1)

    def state_dict(self) -> dict[str, Any]:
        return {"added": dict(self.added), "chunks": [list(c) for c in self._chunks]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.added = dict(state["added"])
        self._chunks = deque(list(c) for c in state["chunks"])
        self._held = sum(n for _, n in self._chunks)
