"""The base of every configuration model and its errors as 'where: what', and the bounds
of what a source accepts from a record (`InputLimits`, the config's `sensor.limits`;
io/sources/validate.py applies them)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class StrictModel(BaseModel):
    """Base for every config model: unknown keys are an error, not silently ignored."""

    # NaN or infinity in a setting is a mistake, never a value (a NaN gate accepts nothing)
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)


def first_error(err: ValueError) -> str:
    """The first error of a pydantic ValidationError as 'where: what' (else the text)."""
    errors = getattr(err, "errors", None)
    if callable(errors):
        first = errors()[0]
        where = ".".join(str(p) for p in first.get("loc", ()))
        msg = str(first.get("msg", err)).removeprefix("Value error, ")
        return f"{where}: {msg}" if where else msg
    return str(err)


class InputLimits(StrictModel):
    """What a source accepts as a physical value: a record outside these bounds is a bad
    record (named in strict mode, skipped and counted in lenient mode) and never reaches
    the map. Each default lies far beyond any real robot's, detector's or driver's values;
    they exist to stop numbers that are not measurements at all (1e308 m, a 400-digit
    integer, a frame of 100,000 detections) before they break or stall the solver."""

    max_coordinate: float = Field(
        1e7,
        gt=0.0,
        description="m, largest |x| or |y| of a position or pose (an odometry-frame pose, a "
        "start pose, a detection, truth): 10,000 km, above any projected coordinate "
        "(UTM northings stay below 1e7)",
    )
    max_motion: float = Field(
        1e4,
        gt=0.0,
        description="m, largest translation of one odometry delta (10 km between two "
        "records of one robot)",
    )
    max_angle: float = Field(
        1e6,
        gt=0.0,
        description="rad, largest |angle| (heading, delta heading, bearing): unwrapped yaw "
        "of any survey stays far below; beyond, float rounding makes an angle meaningless",
    )
    max_abs_time: float = Field(
        4e9,
        gt=0.0,
        description="s, largest |t|: Unix time of the year 2096; stamps in nanoseconds still "
        "fit a signed 64-bit integer (ROS time)",
    )
    min_variance: float = Field(
        1e-16,
        gt=0.0,
        description="smallest variance on a covariance's diagonal (a sigma of 1e-8 m or "
        "rad): below it a number is no measurement; the mapper raises what it takes to "
        "1e-12 at least, and to what the data show",
    )
    max_variance: float = Field(
        1e12,
        gt=0.0,
        description="largest variance on a covariance's diagonal (a sigma of 1,000 km); "
        "ROS's 'unknown' conventions (99999, 1e6, 1e9) stay below",
    )
    max_condition: float = Field(
        1e12,
        gt=1.0,
        description="largest ratio of a covariance's largest to smallest eigenvalue; a "
        "covariance that is symmetric and positive definite within a driver's rounding "
        "(entries rounded to 6 digits) stays far below; an all-zero or indefinite one fails",
    )
    symmetry_tolerance: float = Field(
        1e-6,
        gt=0.0,
        lt=0.1,
        description="largest |c_ij - c_ji| relative to the largest entry; within it a "
        "covariance is made exactly symmetric",
    )
    max_attribute_value: float = Field(
        1e9, gt=0.0, description="largest |value| of a continuous attribute measurement"
    )
    max_field_spacing: float = Field(
        100.0,
        gt=0.0,
        description="m, largest row spacing or minimum plant distance of a field prior",
    )
    max_detections_per_frame: int = Field(
        1000,
        ge=1,
        description="a frame with more detections is refused whole (a bad record, "
        "'too_many_detections'): real detectors give tens per image, and a step's cost grows "
        "with the frame (10,000 detections took 34 s); keeping an arbitrary first part of a "
        "broken frame would put that part in the map",
    )
    max_line_bytes: int = Field(
        16 * 2**20,
        ge=1024,
        description="bytes; a longer line of a survey log is skipped unparsed "
        "('line_too_long'): 1,000 detections with every attribute take about 1 MB",
    )
    time_jump_s: float = Field(
        10.0,
        gt=0.0,
        description="s; a record this much (or time_jump_factor x the robot's median record "
        "interval, whichever is more) ahead of its robot's previous one is held until the "
        "robot's next record: if that continues from it, the clock jumped (a pause), else "
        "the held record is a time spike and is rejected alone ('time_jump')",
    )
    time_jump_factor: float = Field(
        50.0, ge=1.0, description="see time_jump_s: the interval factor"
    )
