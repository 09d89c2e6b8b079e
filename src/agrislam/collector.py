"""The cyclic garbage collector kept off the step path (issue 14).

CPython's full collection scans every object it tracks, so with a large map's state it
stops the run for as long as that takes: 30-130 ms on a 10,000-plant survey, at a step
no one chooses. During a run, what has survived so far is moved every `every` frames to
the collector's permanent generation (`gc.freeze`): reference counting frees it as
always, and a full collection scans only what is newer. The run's end hands it back
(`gc.unfreeze`), so a cycle that died frozen is collected then."""

from __future__ import annotations

import gc
from types import TracebackType

FREEZE_EVERY = 500  # frames


class PacedCollector:
    """`with PacedCollector() as collector:` around a run; `collector.frame()` per frame."""

    def __init__(self, every: int = FREEZE_EVERY) -> None:
        self.every = every
        self._frames = 0

    def __enter__(self) -> PacedCollector:
        gc.freeze()
        return self

    def frame(self) -> None:
        self._frames += 1
        if self._frames % self.every == 0:
            gc.freeze()

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        gc.unfreeze()
