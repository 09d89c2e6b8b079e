"""Shared fixtures: hand-built map snapshots that look like a real survey's."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from agrislam.config import COLOURS, SIZES, FieldSchema, SemanticsConfig
from agrislam.records import Anchor
from agrislam.semantics.continuous import entropy_normalised
from agrislam.semantics.heuristic import interest as heuristic_h
from agrislam.semantics.heuristic import interest_surface
from agrislam.snapshot import MapSnapshot, ObjectMap, RowLines, Trajectory

SAMPLE_SCHEMA = {
    "attributes": {
        "colour": {"kind": "discrete", "values": COLOURS},
        "size": {"kind": "discrete", "values": SIZES},
        "length": {"kind": "continuous", "min": 0.0, "max": 0.6},
    }
}
SAMPLE_ANCHOR = Anchor(lat=51.4488, lon=5.4905, h=20.0, yaw_deg=30.0)
SEMANTICS = SemanticsConfig()
STAGES = ("predict", "associate", "update", "optimise", "maintain")


@pytest.fixture
def snapshot_factory() -> Callable[..., MapSnapshot]:
    """Builds a field of `n_rows` straight rows (1 m apart, along map x) of `per_row` plants
    0.3 m apart, with peaked beliefs, two robots driving along the rows (optimised close to
    the rows, dead reckoning drifting away), an interest surface and per-stage step times."""

    def make(
        n_rows: int = 3,
        per_row: int = 10,
        seed: int = 0,
        n_steps: int = 60,
        schema: bool = True,
        anchor: bool = True,
        rows: bool = True,
        surface: bool = True,
    ) -> MapSnapshot:
        rng = np.random.default_rng(seed)
        k = n_rows * per_row
        row = np.repeat(np.arange(n_rows), per_row)
        along = np.tile(np.arange(per_row) * 0.3, n_rows)
        xy = np.column_stack([along, row * 1.0]) + rng.normal(0.0, 0.02, (k, 2))
        sx, sy = rng.uniform(0.01, 0.05, k), rng.uniform(0.01, 0.05, k)
        rho = rng.uniform(-0.5, 0.5, k)
        cov = np.empty((k, 2, 2))
        cov[:, 0, 0], cov[:, 1, 1] = sx**2, sy**2
        cov[:, 0, 1] = cov[:, 1, 0] = rho * sx * sy

        def peaked(n_values: int) -> np.ndarray:
            """A belief per object peaked on a random value with a random confidence."""
            top = rng.integers(0, n_values, k)
            conf = rng.uniform(1.0 / n_values + 0.05, 0.99, k)
            p = np.repeat(((1.0 - conf) / (n_values - 1))[:, None], n_values, axis=1)
            p[np.arange(k), top] = conf
            return p

        colour, size = peaked(len(COLOURS)), peaked(len(SIZES))
        length = (
            0.1 + 0.2 * np.argmax(size, axis=1) + rng.normal(0, 0.02, k),
            rng.uniform(1e-4, 4e-3, k),
        )
        n_meas = rng.integers(1, 12, k)
        discrete = {"colour": colour, "size": size} if schema else {}
        continuous = {"length": length} if schema else {}
        entropies = [entropy_normalised(length[1], 0.6)] if schema else []
        interest = heuristic_h(n_meas, discrete.values(), entropies, SEMANTICS)  # eq. (2)
        objects = ObjectMap(
            ids=np.arange(100, 100 + k, dtype=np.int64),
            xy=xy,
            cov=cov,
            n_meas=n_meas.astype(np.int64),
            interest=interest,
            row=row.astype(np.int64) if rows else np.full(k, -1, dtype=np.int64),
            discrete=discrete,
            continuous=continuous,
        )

        trajectories, dead_reckoning = {}, {}
        x_end = max(per_row - 1, 1) * 0.3
        for i, (robot, lane_y) in enumerate((("spot", 0.5), ("husky", n_rows - 1.5))):
            t = np.linspace(0.0, n_steps - 1.0, n_steps)
            x = np.linspace(-0.5, x_end + 0.5, n_steps)
            y = np.full(n_steps, lane_y) + 0.02 * np.sin(t / 3.0 + i)
            trajectories[robot] = Trajectory(robot, t, np.column_stack([x, y, np.zeros(n_steps)]))
            drift = np.linspace(0.0, 0.4, n_steps)  # heading drift of the odometry
            dr_theta = 0.01 * t
            dr = np.column_stack([x, y + drift * (1 + i), dr_theta])
            dead_reckoning[robot] = Trajectory(robot, t.copy(), dr)

        surface_of_h = interest_surface(xy, interest, SEMANTICS) if surface else None

        base = np.array([0.002, 0.010, 0.004, 0.060, 0.001])
        step_times = {
            stage: base[j] * (1.0 + np.linspace(0.0, 1.0, n_steps)) + rng.uniform(0, 1e-3, n_steps)
            for j, stage in enumerate(STAGES)
        }
        return MapSnapshot(
            schema=FieldSchema.model_validate(SAMPLE_SCHEMA) if schema else None,
            objects=objects,
            trajectories=trajectories,
            dead_reckoning=dead_reckoning,
            anchor=SAMPLE_ANCHOR if anchor else None,
            rows=RowLines(angle=0.0, offsets=np.arange(n_rows, dtype=float)) if rows else None,
            interest_surface=surface_of_h,
            step_times=step_times,
        )

    return make


@pytest.fixture
def sample_snapshot(snapshot_factory: Callable[..., MapSnapshot]) -> MapSnapshot:
    """3 rows x 10 plants with colour/size/length beliefs, two robots, an anchor 30 deg yawed."""
    return snapshot_factory()
