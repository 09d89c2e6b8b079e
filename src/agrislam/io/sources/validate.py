"""The checks every source makes on a record before it reaches the map: numbers finite and
within physical bounds (`config.InputLimits`), covariances symmetric positive definite
within a driver's rounding, frames of a bounded size, a field prior that describes a field.
A record that fails raises `BadRecordError` (a reason of `REASONS`, a message naming the
field), which its source turns into a bad line or a bag issue: the core trusts its records."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from agrislam.config.limits import InputLimits
from agrislam.records import (
    FIX_TYPES,
    Anchor,
    ContinuousMeasurement,
    Detection,
    Detections,
    FieldPrior,
    GnssFix,
    Meta,
    Odometry,
    Record,
    RobotStart,
    TruthObject,
    TruthPose,
)

# why a record (or a line of a log) was rejected: the spec's "Bad input" list, the ways a
# line can be malformed, and the bounds this project adds (docs/log-format.md)
REASONS = {
    "not_json": "not a JSON object",
    "truncated": "the file ends in the middle of this line, or a .gz file before it",
    "bad_compression": "a .gz file's data is damaged (found here)",
    "bad_encoding": "not UTF-8",
    "line_too_long": "a line longer than sensor.limits.max_line_bytes",
    "unknown_type": "unknown record type",
    "missing_field": "a required field is missing",
    "bad_value": "a field has the wrong type or shape",
    "non_finite": "a number is missing, NaN or infinite",
    "out_of_bounds": "a number outside its physical bounds (sensor.limits)",
    "bad_covariance": "a covariance is not symmetric positive definite",
    "too_many_detections": "a frame with more detections than sensor.limits allows",
    "p_out_of_range": "a probability p outside [0, 1]",
    "not_in_schema": "an attribute or value not in the schema",
    "time_backwards": "time goes backwards for this robot",
    "time_jump": "a time spike: far ahead of its robot's clock, which did not follow it",
    "before_odometry": "detections read before their robot's first odometry, stamped after it",
    "repeated": "the robot's previous record of its type again, same t: a re-sent message",
    "meta_not_first": "a meta record after other records",
    "unsupported_version": "a log format version this reader does not know",
    "bad_schema": "the meta schema is invalid",
    "bad_meta": "the meta record is invalid",
}
FIELD_ANGLE_DEG = 360.0  # largest |row_angle_deg| or |yaw_deg| of a meta record
MIN_DETECTION_RANGE = 1e-3  # m: nearer to the robot origin a detection has no bearing


class BadRecordError(ValueError):
    """A record a source must not pass on: `reason` (a key of REASONS) and a message
    naming the field."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(f"{reason}: {message}")
        self.reason, self.message = reason, message


@contextmanager
def within(where: str) -> Iterator[None]:
    """Name the part of a record a bad value was found in ('objects[3]: ...')."""
    try:
        yield
    except BadRecordError as bad:
        raise BadRecordError(bad.reason, f"{where}: {bad.message}") from None


def check_record(record: Record, limits: InputLimits) -> Record:
    """`record` if every value is sane (covariances made exactly symmetric), else
    `BadRecordError`."""
    check = _Checker(limits)
    if isinstance(record, Odometry):
        return check.odometry(record)
    if isinstance(record, Detections):
        return check.detections(record)
    if isinstance(record, GnssFix):
        return check.gnss(record)
    if isinstance(record, TruthPose):
        check.time(record.t)
        check.pose(record.pose, "pose")
        return record
    if isinstance(record, TruthObject):
        check.coordinates(record.xy, "xy")
        return record
    if isinstance(record, Meta):
        check.meta(record)
    return record


def check_covariance(cov: np.ndarray, what: str, limits: InputLimits) -> np.ndarray:
    """`cov` made exactly symmetric, if it is symmetric within the rounding tolerance,
    has its variances within bounds and is positive definite with a bounded condition
    number; else `BadRecordError("bad_covariance")` naming `what`."""
    c = np.asarray(cov, dtype=float)
    if not np.isfinite(c).all():
        raise BadRecordError("non_finite", f"{what} has a NaN or infinite entry: {_short(c)}")
    scale = float(np.abs(c).max(initial=0.0))
    if scale == 0.0:
        raise BadRecordError("bad_covariance", f"{what} is all zeros (no uncertainty at all)")
    if float(np.abs(c - c.T).max()) > limits.symmetry_tolerance * scale:
        raise BadRecordError("bad_covariance", f"{what} is not symmetric: {_short(c)}")
    c = 0.5 * c + 0.5 * c.T  # halves first: entries near the float limit do not overflow
    variances = np.diag(c)
    if variances.min() < limits.min_variance:
        raise BadRecordError(
            "bad_covariance",
            f"{what} has a variance {variances.min():.3g} below {limits.min_variance:g}: "
            f"{_short(c)}",
        )
    if variances.max() > limits.max_variance:
        raise BadRecordError(
            "bad_covariance",
            f"{what} has a variance {variances.max():.3g} above {limits.max_variance:g}",
        )
    eig = np.linalg.eigvalsh(c)
    if eig[0] <= eig[-1] / limits.max_condition:
        raise BadRecordError(
            "bad_covariance",
            f"{what} is not positive definite (eigenvalues {eig[0]:.3g} to {eig[-1]:.3g}): "
            f"{_short(c)}",
        )
    return c


def _short(value: Any, width: int = 120) -> str:
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= width else text[: width - 3] + "..."


class _Checker:
    def __init__(self, limits: InputLimits) -> None:
        self.limits = limits

    # ---------------------------------------------------------------- scalars

    def bounded(self, value: float, bound: float, what: str, unit: str = "") -> float:
        if not math.isfinite(value):
            raise BadRecordError("non_finite", f"{what} is {value!r}")
        if abs(value) > bound:
            raise BadRecordError(
                "out_of_bounds", f"{what} = {value:.6g} is beyond +-{bound:g}{unit}"
            )
        return value

    def time(self, t: float) -> None:
        self.bounded(t, self.limits.max_abs_time, "'t'", " s")

    def angle(self, value: float, what: str) -> None:
        self.bounded(value, self.limits.max_angle, what, " rad")

    def coordinates(self, xy: Iterable[float], what: str, bound: float | None = None) -> None:
        bound = self.limits.max_coordinate if bound is None else bound
        for k, v in enumerate(xy):
            self.bounded(float(v), bound, f"{what}[{k}]", " m")

    def pose(self, pose: np.ndarray, what: str, bound: float | None = None) -> None:
        self.coordinates(pose[:2], what, bound)
        self.angle(float(pose[2]), f"{what}[2]")

    def sigma(self, value: float | None, what: str) -> None:
        """An optional standard deviation: 0 means 'the configured default'."""
        if value is None:
            return
        limits = self.limits
        if not math.isfinite(value) or value < 0.0:
            raise BadRecordError("bad_value", f"{what} must be a finite number >= 0, got {value!r}")
        if value > 0.0 and not limits.min_variance <= value * value <= limits.max_variance:
            raise BadRecordError(
                "out_of_bounds",
                f"{what} = {value:.3g}: its square is outside [{limits.min_variance:g}, "
                f"{limits.max_variance:g}]",
            )

    # ---------------------------------------------------------------- records

    def odometry(self, odom: Odometry) -> Odometry:
        self.time(odom.t)
        if odom.pose is not None:
            self.pose(odom.pose, "'pose'")
        if odom.delta is not None:
            self.pose(odom.delta, "'delta'", self.limits.max_motion)
        if odom.cov is None:
            return odom
        return dataclasses.replace(odom, cov=check_covariance(odom.cov, "'cov'", self.limits))

    def gnss(self, fix: GnssFix) -> GnssFix:
        """Latitude and longitude on the globe, a known fix type, a positive definite ENU
        covariance, an antenna within reach of the robot."""
        self.time(fix.t)
        self.bounded(fix.lat, 90.0, "'lat'", " deg")
        self.bounded(fix.lon, 180.0, "'lon'", " deg")
        self.bounded(fix.alt, self.limits.max_coordinate, "'alt'", " m")
        if fix.fix not in FIX_TYPES:
            raise BadRecordError("bad_value", f"'fix' {_short(fix.fix)} is not one of {FIX_TYPES}")
        if fix.antenna is not None:
            self.coordinates(fix.antenna, "'antenna'", self.limits.max_motion)
        if fix.cov is None:
            return fix
        return dataclasses.replace(fix, cov=check_covariance(fix.cov, "'cov'", self.limits))

    def detections(self, frame: Detections) -> Detections:
        self.time(frame.t)
        n, most = len(frame.objects), self.limits.max_detections_per_frame
        if n > most:
            raise BadRecordError(
                "too_many_detections",
                f"{n} detections in one frame; at most {most} (sensor.limits."
                "max_detections_per_frame)",
            )
        objects = []
        for k, det in enumerate(frame.objects):
            with within(f"objects[{k}]"):
                objects.append(self.detection(det))
        if all(a is b for a, b in zip(objects, frame.objects, strict=True)):
            return frame
        return dataclasses.replace(frame, objects=tuple(objects))

    def detection(self, det: Detection) -> Detection:
        limits = self.limits
        for name, m in det.attributes.items():
            if isinstance(m, ContinuousMeasurement):
                self.bounded(m.value, limits.max_attribute_value, f"attribute {name!r} value")
                if not 0.0 <= m.var <= limits.max_variance:
                    raise BadRecordError(
                        "out_of_bounds" if m.var > 0 else "bad_value",
                        f"attribute {name!r}: var {m.var!r} outside [0, {limits.max_variance:g}]",
                    )
        if det.xy is None:
            if det.range is not None and det.range < 0.0:
                raise BadRecordError("bad_value", f"'range' {det.range} < 0")
            rng = self.bounded(det.range, limits.max_coordinate, "'range'", " m")  # type: ignore[arg-type]
            self.angle(det.bearing, "'bearing'")  # type: ignore[arg-type]
            self.sigma(det.sigma_range, "'sigma_range'")
            self.sigma(det.sigma_bearing, "'sigma_bearing'")
        else:
            self.coordinates(det.xy, "'xy'")
            rng = float(np.hypot(*det.xy))
        if rng < MIN_DETECTION_RANGE:
            raise BadRecordError(
                "out_of_bounds",
                f"a detection {rng:.3g} m from the robot origin has no bearing "
                f"(nearest: {MIN_DETECTION_RANGE:g} m)",
            )
        if det.cov is None:
            return det
        return dataclasses.replace(det, cov=check_covariance(det.cov, "'cov'", limits))

    def meta(self, meta: Meta) -> None:
        for name, start in meta.robots.items():
            self.start(name, start)
        if meta.anchor is not None:
            self.anchor(meta.anchor)
        if meta.field is not None:
            self.field(meta.field)

    def start(self, name: str, start: RobotStart) -> None:
        what = f"robots.{name}"
        self.pose(np.asarray(start.pose, dtype=float), f"{what}.start_pose")
        for k, s in enumerate(np.asarray(start.sigma, dtype=float).tolist()):
            if s == 0.0:
                raise BadRecordError(
                    "bad_value", f"{what}.start_sigma[{k}] is 0: a prior needs an uncertainty"
                )
            self.sigma(s, f"{what}.start_sigma[{k}]")

    def anchor(self, anchor: Anchor) -> None:
        self.bounded(anchor.lat, 90.0, "anchor.lat", " deg")
        self.bounded(anchor.lon, 180.0, "anchor.lon", " deg")
        self.bounded(anchor.h, self.limits.max_coordinate, "anchor.h", " m")
        self.bounded(anchor.yaw_deg, FIELD_ANGLE_DEG, "anchor.yaw_deg", " deg")

    def field(self, prior: FieldPrior) -> None:
        most = self.limits.max_field_spacing
        for key in ("row_spacing", "min_plant_distance"):
            value = getattr(prior, key)
            if value is None:
                continue
            if not (math.isfinite(value) and 0.0 < value <= most):
                raise BadRecordError(
                    "out_of_bounds", f"field.{key} = {value!r} must be in (0, {most:g}] m"
                )
        if prior.row_angle_deg is not None:
            self.bounded(prior.row_angle_deg, FIELD_ANGLE_DEG, "field.row_angle_deg", " deg")
