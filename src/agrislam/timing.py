"""The time each stage of a pipeline step took, for every step (the run's step times)."""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np

from agrislam.growing import GrowingRows


class StageTimer:
    """`with timer(stage):` adds the block's time to the stage's time of this step;
    `close_step` files the step away as one row (no float object each)."""

    def __init__(self, stages: Sequence[str]) -> None:
        self.stages = tuple(stages)
        self.step: dict[str, float] = {}
        self._history = GrowingRows((len(self.stages),), np.float32)  # us precision

    @property
    def history(self) -> dict[str, np.ndarray]:
        """Each stage's time of every step so far (s)."""
        steps = self._history.array
        if not len(steps):
            return {}
        return {stage: steps[:, n].copy() for n, stage in enumerate(self.stages)}

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        self.step[stage] = self.step.get(stage, 0.0) + time.perf_counter() - start

    def close_step(self) -> dict[str, float]:
        done, self.step = self.step, {}
        self._history.append([done.get(stage, 0.0) for stage in self.stages])
        return done
