"""Memory housekeeping kept off the step path: CPython's full collection scans every object
it tracks, at a step no one chooses, and a large map's state is many objects.

Every `every` frames what has survived so far is moved to the collector's permanent
generation (`gc.freeze`): reference counting frees it as always, and a full collection
scans only what is newer; the run's end hands it back (`gc.unfreeze`), so a cycle that died
frozen is collected then. At the same frames the C heap's free pages, freed by GTSAM and
numpy between live blocks, go back to the system (`release_free_heap`)."""

from __future__ import annotations

import ctypes
import functools
import gc
from collections.abc import Callable
from types import TracebackType

FREEZE_EVERY = 500  # frames


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's malloc_trim, or None where the C library has none (macOS, musl)."""
    try:
        return getattr(ctypes.CDLL(None), "malloc_trim", None)  # the process's own symbols
    except OSError:
        return None


def release_free_heap() -> bool:
    """Hand the C heap's free pages back to the system; False where that cannot be done."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True


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
            release_free_heap()

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        gc.unfreeze()
