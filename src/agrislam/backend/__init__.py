"""The graph back end (sec. 2.6): the protocol the world model calls, and `make_backend`,
which builds the configured one (the paper's batch solve, or incremental iSAM2)."""

from __future__ import annotations

from agrislam.backend.protocol import GraphBackend
from agrislam.config import RowsConfig, SlamConfig
from agrislam.geometry.noise import (
    Measurement,
    RangeBearing,
    RelativePosition,
    detection_covariance,
)

__all__ = [
    "GraphBackend",
    "Measurement",
    "RangeBearing",
    "RelativePosition",
    "detection_covariance",
    "make_backend",
]


def make_backend(slam: SlamConfig, rows: RowsConfig) -> GraphBackend:
    """The back end `slam.backend` names: "incremental" (windowed iSAM2, the default) or
    "batch" (the paper's whole-graph LM/Dogleg every step)."""
    if slam.backend == "batch":
        from agrislam.backend.batch import BatchBackend

        return BatchBackend(slam, rows)
    from agrislam.backend.incremental.backend import IncrementalBackend

    return IncrementalBackend(slam, rows)
