"""When objects were started: ids are row numbers, never reused, so the number of objects
at each time says which ids are older than a time
(association/rejoin.py, association/loop_closure.py)."""

from __future__ import annotations

from collections import deque


class Births:
    """(time, objects so far) at each change, kept for `keep_s` seconds."""

    def __init__(self, keep_s: float) -> None:
        self.keep_s = keep_s
        self._started: deque[tuple[float, int]] = deque()

    def record(self, t: float, n_objects: int) -> None:
        """`n_objects` objects exist at time `t` (called as objects are started)."""
        if self._started and self._started[-1][1] == n_objects:
            return
        self._started.append((t, n_objects))
        while len(self._started) > 1 and self._started[1][0] <= t - self.keep_s:
            self._started.popleft()

    def started(self, object_id: int) -> float:
        """When the object was started (-inf if before the times kept)."""
        for started, n_objects in self._started:
            if n_objects > object_id:
                return started
        raise ValueError(f"object {object_id} was not started yet")

    def below(self, t: float) -> int:
        """Ids below this were started at or before `t` (0 before the first record, or
        for a `t` more than `keep_s` before the last)."""
        for started, n_objects in reversed(self._started):
            if started <= t:
                return n_objects
        return 0
