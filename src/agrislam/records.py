"""The records a survey is made of: what every source yields and the world model reads.

They mirror the survey log format (shared/spec/log-format.md) one to one, with
arrays in place of JSON lists. Sources (JSONL log, ROS bags, the simulator) produce
them; the core consumes them and never knows which source it was.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TypeAlias

import numpy as np

from agrislam.config import FieldSchema


@dataclass(frozen=True, slots=True)
class RobotStart:
    pose: np.ndarray  # (3,) x, y, theta in the map frame
    sigma: np.ndarray  # (3,) standard deviations of that prior


@dataclass(frozen=True, slots=True)
class Anchor:
    """WGS84 position of the map origin; the map x axis is `yaw_deg` from east to north."""

    lat: float
    lon: float
    h: float = 0.0
    yaw_deg: float = 0.0


@dataclass(frozen=True, slots=True)
class FieldPrior:
    row_spacing: float | None = None
    min_plant_distance: float | None = None
    row_angle_deg: float | None = None


@dataclass(frozen=True, slots=True)
class Meta:
    version: int = 1
    schema: FieldSchema | None = None
    robots: dict[str, RobotStart] = field(default_factory=dict)
    anchor: Anchor | None = None
    field: FieldPrior | None = None
    survey_start: float | None = None  # Unix time (s) of t = 0 (docs/log-format.md 1.2)


@dataclass(frozen=True, slots=True)
class Odometry:
    """Motion of one robot: either its odometry-frame `pose` or the `delta` since its last
    record (in the previous robot frame); `cov` is the 3x3 covariance of the increment."""

    t: float
    robot: str
    pose: np.ndarray | None = None
    delta: np.ndarray | None = None
    cov: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class DiscreteMeasurement:
    value: str
    p: float  # the detector's probability that `value` is right (Assumption 1)


@dataclass(frozen=True, slots=True)
class ContinuousMeasurement:
    value: float
    var: float


Measurement: TypeAlias = DiscreteMeasurement | ContinuousMeasurement


@dataclass(frozen=True, slots=True)
class Detection:
    """One detected object in the robot base frame at the frame's time (x forward, y left).

    Exactly one geometry is set: `xy` (+ optional 2x2 `cov`) or `range`/`bearing`
    (+ optional sigmas). Missing uncertainties take the configured defaults.
    """

    xy: np.ndarray | None = None
    cov: np.ndarray | None = None
    range: float | None = None
    bearing: float | None = None
    sigma_range: float | None = None
    sigma_bearing: float | None = None
    attributes: dict[str, Measurement] = field(default_factory=dict)
    label: str | None = None  # combined detector label, split by the label map
    label_p: float | None = None
    truth_id: str | None = None  # evaluation only: the mapper never reads it

    def within_schema(self, schema: FieldSchema | None) -> tuple[Detection, list[str]]:
        """This detection without the measurements the schema cannot take (unknown
        attribute, wrong kind, value not in it, p outside [0, 1], non-finite or negative
        variance), and the names of those dropped; the geometry is kept."""
        bad = [n for n, m in self.attributes.items() if not fits_schema(schema, n, m)]
        if not bad:
            return self, bad
        kept = {n: m for n, m in self.attributes.items() if n not in bad}
        return dataclasses.replace(self, attributes=kept), bad

    def position(self) -> np.ndarray:
        """The detection as x, y in the robot frame, whichever geometry it was given in."""
        if self.xy is not None:
            return self.xy
        assert self.range is not None and self.bearing is not None
        return self.range * np.array([np.cos(self.bearing), np.sin(self.bearing)])


def fits_schema(schema: FieldSchema | None, name: str, m: Measurement) -> bool:
    """Whether measurement `m` of attribute `name` is one the schema can take."""
    spec = schema.attributes.get(name) if schema is not None else None
    if spec is None or (spec.kind == "discrete") != isinstance(m, DiscreteMeasurement):
        return False
    if isinstance(m, DiscreteMeasurement):
        return m.value in spec.values and 0.0 <= m.p <= 1.0  # type: ignore[union-attr]
    return math.isfinite(m.value) and math.isfinite(m.var) and m.var >= 0.0


@dataclass(frozen=True, slots=True)
class Detections:
    t: float
    robot: str
    objects: tuple[Detection, ...] = ()
    sensor: str | None = None


# GNSS fix types, worst first (docs/log-format.md "gnss")
FIX_TYPES = ("none", "single", "dgps", "rtk_float", "rtk_fixed")


@dataclass(frozen=True, slots=True)
class GnssFix:
    """A GNSS fix of the robot's antenna: WGS84 latitude, longitude (deg) and ellipsoidal
    altitude (m), the 3x3 covariance in metres (east, north, up), the fix type (FIX_TYPES)
    and the antenna's position in the robot frame (None: the configured one)."""

    t: float
    robot: str
    lat: float
    lon: float
    alt: float
    fix: str
    cov: np.ndarray | None = None
    antenna: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class TruthPose:
    t: float
    robot: str
    pose: np.ndarray


@dataclass(frozen=True, slots=True)
class TruthObject:
    id: str
    xy: np.ndarray
    attributes: dict[str, str | float] = field(default_factory=dict)


Record: TypeAlias = Meta | Odometry | Detections | GnssFix | TruthPose | TruthObject
