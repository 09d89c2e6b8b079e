"""Configuration of what a real robot's sensors add to the textbook models, as measured on a
real multi-robot log against its motion-capture truth (`benchmarks/real_statistics.py`):
a camera that reads depth rather than range, noise that grows with range, heavy-tailed and
offset bearings, misread labels, blind spells; odometry stamped ahead of the camera and
turning by a scale of its own. Shared by the arena's camera and odometry and the field's
detector and odometry. Every effect is off by default, so a scenario's defaults stay as
they were; `CameraEffects.mrclam()` and `OdometryEffects.mrclam()` give the measured ones."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class CameraEffects(_Strict):
    """How a real camera's range and bearing differ from the truth beyond white Gaussian
    noise. The range model is r_meas = s r - k r (1 - cos b), s the robot's range scale and
    k = `off_axis_depth` x s: k = s reads the depth along the optical axis, s r cos b."""

    range_scale: float = Field(
        1.0, gt=0.0, description="mean of the robots' range scales s (a calibration error)"
    )
    range_scale_spread: float = Field(
        0.0, ge=0.0, description="std of each robot's range scale around range_scale"
    )
    off_axis_depth: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="k / s: the share of the off-axis shortening r (1 - cos b) the range "
        "suffers; 0 reads the true range, 1 the depth along the camera's axis",
    )
    sigma_range_per_m: float = Field(
        0.0,
        ge=0.0,
        description="m of range noise std per m of range, added in quadrature to the "
        "sensor's fixed range std: a stereo or barcode-size range worsens with distance",
    )
    bearing_dof: float | None = Field(
        None,
        gt=1.0,
        description="degrees of freedom of a Student-t bearing noise scaled so its robust "
        "sigma (1.4826 x median absolute deviation) is the sensor's bearing std: heavy "
        "tails; None keeps it Gaussian",
    )
    bearing_offset_spread: float = Field(
        0.0,
        ge=0.0,
        description="rad, std of each robot's constant bearing offset (a camera mounted a "
        "little askew), drawn once per robot",
    )
    misread_rate: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="share of detections labelled as another object than the one measured "
        "(the barcode misread): the geometry is the object in view's, the label and so the "
        "truth_id a random other's",
    )
    blind_per_minute: float = Field(
        0.0,
        ge=0.0,
        description="blind spells starting per minute per robot, Poisson: the camera sees "
        "nothing for a while (view blocked, lens turned to a wall, detector stalled)",
    )
    blind_duration_s: tuple[float, float] = Field(
        (20.0, 40.0), description="s, length of a blind spell, uniform"
    )

    @model_validator(mode="after")
    def _check(self) -> CameraEffects:
        lo, hi = self.blind_duration_s
        if not 0.0 <= lo <= hi:
            raise ValueError(f"blind_duration_s: need 0 <= low <= high, got ({lo}, {hi})")
        return self

    @classmethod
    def mrclam(cls) -> CameraEffects:
        """The camera of the real multi-robot log (MRCLAM) as measured against its truth
        (docs/decisions.md): a depth-like range a little long per robot, noise
        growing with range, Student-t bearings with a per-robot offset, rare misreads."""
        return cls(
            range_scale=1.028,
            range_scale_spread=0.012,
            off_axis_depth=0.95,
            sigma_range_per_m=0.011,
            bearing_dof=2.5,
            bearing_offset_spread=0.007,
            misread_rate=6e-4,
            blind_per_minute=0.15,
            blind_duration_s=(10.0, 60.0),
        )


class OdometryEffects(_Strict):
    """How real odometry's timing and turning differ from the truth, beyond its noise and
    the scenario's own scale and heading biases."""

    clock_offset_s: float = Field(
        0.0,
        description="s the odometry is stamped ahead of the camera and the truth: its record "
        "at t carries the motion the robot makes by t + this (commanded velocities are "
        "logged before the wheels follow them); negative: stamped late",
    )
    turn_scale_spread: float = Field(
        0.0,
        ge=0.0,
        description="std of each robot's relative turn error: it reports (1 + e) x every "
        "angle turned, e drawn once per robot (a miscalibrated wheel base)",
    )

    @classmethod
    def mrclam(cls) -> OdometryEffects:
        """The odometry of the real multi-robot log: integrated commanded velocities that
        lead the truth, each robot turning by a scale of its own."""
        return cls(clock_offset_s=0.25, turn_scale_spread=0.08)
