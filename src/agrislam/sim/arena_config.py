"""Configuration of the arena scenario (`sim/arena.py`): robots driving random paths among
point landmarks in a small indoor arena, shaped like the UTIAS multi-robot dataset (MRCLAM).
Every noise and probability is a value here, with the reasoning behind its default."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from agrislam.config.loading import merged
from agrislam.sim.effects_config import CameraEffects, OdometryEffects


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class ArenaLayout(_Strict):
    """A small indoor arena with point landmarks, some in tight clusters. Its shape follows the
    UTIAS multi-robot dataset (MRCLAM): a 15 m x 8 m room, 15 landmark tubes."""

    size: tuple[float, float] = Field(
        (15.0, 8.0),
        description="m, x by y, centred on the map origin: MRCLAM's robots drive to random "
        "waypoints in a 15 m x 8 m room",
    )
    single_landmarks: int = Field(
        10, ge=0, description="landmarks standing alone, at least `separation` from any other"
    )
    clusters: list[int] = Field(
        default_factory=lambda: [3, 2, 2],
        description="sizes of the landmark clusters: a triple and two pairs, so 7 of the 17 "
        "landmarks have a neighbour within 0.2 m, as MRCLAM's clustered landmarks do",
    )
    cluster_spacing: tuple[float, float] = Field(
        (0.15, 0.2),
        description="m, distance of each clustered landmark to its nearest neighbour, uniform: "
        "about the range sigma, so one object can easily swallow two landmarks",
    )
    separation: float = Field(
        1.0,
        gt=0.0,
        description="m, least distance between landmarks of different clusters (or singles): "
        "5 range sigmas, so only the clusters are hard to tell apart",
    )
    wall_margin: float = Field(
        0.8, ge=0.0, description="m landmarks stand inside the walls, room to drive round them"
    )

    @model_validator(mode="after")
    def _check(self) -> ArenaLayout:
        lo, hi = self.cluster_spacing
        if not 0.0 < lo <= hi:
            raise ValueError(f"cluster_spacing: need 0 < low <= high, got ({lo}, {hi})")
        if any(n < 2 for n in self.clusters):
            raise ValueError(f"a cluster has at least 2 landmarks, got {self.clusters}")
        if self.single_landmarks + sum(self.clusters) == 0:
            raise ValueError("the arena needs at least one landmark")
        if min(self.size) <= 2 * self.wall_margin:
            raise ValueError(f"wall_margin {self.wall_margin} leaves no room in {self.size}")
        return self


class ArenaDriving(_Strict):
    """How the robots move: each drives straight legs to random waypoints, its gentle corners
    rounded into arcs, its sharp ones turned on the spot (a differential drive, like
    MRCLAM's iRobot Creates), at a speed drawn per segment."""

    n_robots: int = Field(5, ge=1, description="MRCLAM's team of five")
    duration_s: float = Field(900.0, gt=0.0, description="s, 15 minutes")
    speed: tuple[float, float] = Field(
        (0.1, 0.3),
        description="m/s, drawn uniformly per path segment; a turn on the spot goes at "
        "speed / turn_radius rad/s",
    )
    turn_radius: float = Field(
        0.3, gt=0.0, description="m, radius of a rounded corner (a small robot turns tightly)"
    )
    spin_turn_deg: float = Field(
        120.0,
        ge=0.0,
        le=180.0,
        description="corners turning more than this are turned on the spot, the others are "
        "driven as arcs: between random waypoints about one corner in three is a turn in place",
    )
    min_leg: float = Field(
        1.0, gt=0.0, description="m, shortest leg between waypoints (nearer ones are redrawn)"
    )
    wall_margin: float = Field(
        0.4, ge=0.0, description="m the waypoints (and so the legs) keep from the walls"
    )
    landmark_clearance: float = Field(
        0.4,
        ge=0.0,
        description="m every leg keeps from every landmark: the robots drive round them, and "
        "the camera's 0.3 m minimum range never hides the landmark in front",
    )
    start_poses: Literal["all", "first"] = Field(
        "all",
        description="which robots' start poses the meta gives: 'all' (motion capture knows "
        "them, as in MRCLAM) or 'first' (the others must be placed from shared landmarks)",
    )
    start_sigma: tuple[float, float, float] = Field(
        (0.01, 0.01, 0.005),
        description="std of a start-pose prior in meta (m, m, rad): motion capture at the start",
    )

    @model_validator(mode="after")
    def _check(self) -> ArenaDriving:
        lo, hi = self.speed
        if not 0.0 < lo <= hi:
            raise ValueError(f"speed: need 0 < low <= high, got ({lo}, {hi})")
        return self


class ArenaOdometry(_Strict):
    """Wheel odometry at tens of Hz. Its white noise is a random walk: each variance grows
    with the metres driven, the radians turned and the seconds passed, so the drift does not
    depend on the rate (a std per step in proportion to the step, as `OdometryNoise` has,
    would shrink the drift as the rate grows). On top, each robot has its own distance scale
    error and heading bias per metre (wheels of slightly different size), which the reported
    covariance leaves out, as real odometry does. The defaults drift about 1 m RMS in 5 minutes."""

    rate_hz: float = Field(
        50.0, gt=0.0, description="records per second: tens of Hz (MRCLAM logs at 67 Hz)"
    )
    sigma_x_per_sqrt_m: float = Field(
        0.02, ge=0.0, description="m per sqrt(m) driven, along the motion: wheel slip"
    )
    sigma_y_per_sqrt_m: float = Field(
        0.01, ge=0.0, description="m per sqrt(m) driven, across the motion"
    )
    sigma_theta_per_sqrt_m: float = Field(
        0.01, ge=0.0, description="rad per sqrt(m) driven: uneven floor"
    )
    sigma_theta_per_sqrt_rad: float = Field(
        0.02, ge=0.0, description="rad per sqrt(rad) turned: the wheels skid when turning"
    )
    sigma_per_sqrt_s: tuple[float, float, float] = Field(
        (1e-3, 1e-3, 1e-3),
        description="(m, m, rad) per sqrt(s): a floor, so standing still or turning in place "
        "is not perfectly certain (a zero variance would be singular in the graph)",
    )
    heading_bias_per_m: float = Field(
        4e-3,
        ge=0.0,
        description="rad per m driven, size of each robot's heading bias, its sign drawn per "
        "robot (one wheel a little larger): most of the drift",
    )
    scale_bias: float = Field(
        0.01, ge=0.0, description="std of each robot's relative distance error (wheel radius)"
    )
    report_sigma_factor: tuple[float, float, float] = Field(
        (1.0, 1.0, 0.25),
        description="reported std = this x the white noise std actually added, per x, y, "
        "heading: the heading 4 times too confident, as real drivers report it (with the "
        "unreported bias, more than that); the mapper has to estimate the scales itself",
    )
    report_covariance: bool = Field(
        True,
        description="write each record's covariance; False: none, as a converted real log "
        "that has none, so the mapper's configured default applies",
    )
    effects: OdometryEffects = Field(
        default_factory=OdometryEffects,
        description="a real robot's clock offset and turn scale (off by default)",
    )

    @model_validator(mode="after")
    def _check(self) -> ArenaOdometry:
        if min(self.report_sigma_factor) <= 0.0 or min(self.sigma_per_sqrt_s) <= 0.0:
            raise ValueError("report_sigma_factor and sigma_per_sqrt_s must be positive")
        return self


class RangeBearingCamera(_Strict):
    """A camera aligned with the robot body frame that reads range and bearing off each
    landmark in view (as MRCLAM's barcode reader does). Range and field of view hide a
    landmark, and `p_detect` if below 1; a few ranges are gross outliers."""

    frame_rate_hz: float = Field(
        3.0,
        gt=0.0,
        description="frames per second, unsynchronised with the odometry (a random phase per "
        "robot): a few Hz",
    )
    fov_deg: float = Field(60.0, gt=0.0, le=360.0, description="horizontal field of view")
    min_range: float = Field(0.3, ge=0.0, description="m; nearer landmarks are out of focus")
    max_range: float = Field(5.0, gt=0.0, description="m; farther barcodes cannot be read")
    p_detect: float = Field(
        1.0,
        gt=0.0,
        le=1.0,
        description="chance a landmark in range and view is read in a frame, each frame on its "
        "own: a real barcode reader misses most of them",
    )
    sigma_range: float = Field(0.13, ge=0.0, description="m, range noise std, reported as it is")
    sigma_bearing: float = Field(
        0.015, ge=0.0, description="rad, bearing noise std, reported as it is"
    )
    outlier_rate: float = Field(
        0.02,
        ge=0.0,
        le=1.0,
        description="share of detections whose range is a gross error, uniform over "
        "[min_range, max_range], still reported with sigma_range",
    )
    empty_frames: bool = Field(
        False,
        description="also write frames that see nothing; a converted real log lists "
        "measurements only, so by default a frame without a landmark in view is not written",
    )
    reported_sigmas: tuple[float, float] | None = Field(
        None,
        description="(m, rad) range and bearing std written with every detection, whatever "
        "the noise: a real log's nominal data-sheet figures; None: sigma_range and "
        "sigma_bearing, as they are",
    )
    effects: CameraEffects = Field(
        default_factory=CameraEffects,
        description="a real camera's depth-like range, range-dependent noise, heavy-tailed "
        "and offset bearings, misreads and blind spells (off by default)",
    )

    @model_validator(mode="after")
    def _check(self) -> RangeBearingCamera:
        if self.min_range >= self.max_range:
            raise ValueError(f"min_range {self.min_range} must be below max_range")
        return self


class LandmarkAttribute(_Strict):
    """An optional noisy discrete attribute per landmark: the identity read off its barcode,
    sometimes wrong. The meta then carries a schema with this one attribute, its values the
    landmark ids."""

    enabled: bool = Field(False, description="off: pure geometric mapping, no schema")
    name: str = Field("landmark", description="the attribute's name in the schema")
    error_rate: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="chance a read reports a wrong id, uniform over the other landmarks",
    )
    p: float = Field(
        0.9,
        ge=0.0,
        le=1.0,
        description="the p each read reports: 1 - error_rate by default, a calibrated reader",
    )


class ArenaConfig(_Strict):
    """Root of the arena scenario; `ArenaSimulator(ArenaConfig())` is the default 15-minute,
    5-robot, 17-landmark run."""

    seed: int = Field(1, description="everything random follows from it")
    arena: ArenaLayout = Field(default_factory=ArenaLayout)
    driving: ArenaDriving = Field(default_factory=ArenaDriving)
    odometry: ArenaOdometry = Field(default_factory=ArenaOdometry)
    camera: RangeBearingCamera = Field(default_factory=RangeBearingCamera)
    attribute: LandmarkAttribute = Field(default_factory=LandmarkAttribute)

    @classmethod
    def realistic(cls, changes: dict[str, Any] | None = None) -> ArenaConfig:
        """The arena as the real multi-robot log (MRCLAM dataset 6) measured against its
        truth: its layout of six tight clusters, slow drives, odometry of commanded
        velocities without covariance, a longer and wider camera with the real one's effects,
        nominal sigmas reported (docs/decisions.md). `changes` go on top, section
        by section, as `model_validate` would read them."""
        return cls.model_validate(merged(_realistic(), changes or {}))


def _realistic() -> dict[str, Any]:
    """The realistic profile's values, section by section."""
    return {
        "arena": {
            "size": (5.0, 9.5),
            "single_landmarks": 0,
            "clusters": [3, 2, 3, 2, 3, 2],
            "cluster_spacing": (0.18, 0.25),
            "wall_margin": 0.5,
        },
        "driving": {"duration_s": 888.0, "speed": (0.06, 0.08), "wall_margin": 0.8},
        "odometry": {
            "rate_hz": 10.0,
            "sigma_per_sqrt_s": (3e-3, 3e-3, 0.05),
            "scale_bias": 0.03,
            "report_covariance": False,
            "effects": OdometryEffects.mrclam().model_dump(),
        },
        "camera": {
            "frame_rate_hz": 4.2,
            "p_detect": 0.25,
            "fov_deg": 66.0,
            "min_range": 0.9,
            "max_range": 8.5,
            "sigma_range": 0.01,
            "sigma_bearing": 0.011,
            "outlier_rate": 0.0,
            "reported_sigmas": (0.15, 0.02),
            "effects": CameraEffects.mrclam().model_dump(),
        },
    }
