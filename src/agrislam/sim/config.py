"""Configuration of the field simulator: field layout, survey path, odometry noise, detector
model and growth. Every noise and probability is a value here, with the reasoning behind its
default; the defaults reproduce the paper's Gazebo setup (sec. 3.1.1)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from agrislam.config import FieldSchema
from agrislam.sim.arena_config import ArenaConfig  # noqa: F401 (re-exported for imports outside sim)
from agrislam.sim.effects_config import CameraEffects, OdometryEffects
from agrislam.sim.gnss_config import DistanceDrift, GnssSimConfig


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class FieldLayout(_Strict):
    """Rows of plants. Row k is the line through `origin + k * row_spacing * n`, with
    n = (-sin a, cos a) the unit normal of the row direction a = `row_angle_deg`."""

    n_plants: int | None = Field(
        400,
        ge=1,
        description="sowing positions, spread evenly over the rows (before gaps, "
        "doubles and weeds); the paper's largest real-time field has 400 (sec. 3.1.3)",
    )
    row_length: float | None = Field(
        None, gt=0.0, description="m; alternative to n_plants: fill every row to this length"
    )
    n_rows: int = Field(
        10, ge=1, description="10 rows of 40 plants: a 9 m x 18 m field for the default 400"
    )
    row_spacing: float = Field(1.0, gt=0.0, description="m between rows (sec. 3.1.1)")
    plant_spacing: tuple[float, float] = Field(
        (0.4, 0.5), description="m, plant-to-plant distance along a row, uniform (sec. 3.1.1)"
    )
    row_angle_deg: float = Field(0.0, description="row direction from the map x axis")
    origin: tuple[float, float] = Field(
        (0.0, 0.0), description="map position of the first plant of row 0"
    )
    row_jitter: float = Field(
        0.01,
        ge=0.0,
        description="m, std of a plant off its row line: sowing precision of a "
        "drill; small against the 0.2 m matching radius",
    )
    gap_probability: float = Field(
        0.0, ge=0.0, lt=1.0, description="chance a sowing position stays empty (Gazebo had none)"
    )
    double_probability: float = Field(
        0.0, ge=0.0, le=1.0, description="chance a second plant grows beside one (two seeds)"
    )
    double_offset: tuple[float, float] = Field(
        (0.05, 0.15), description="m, distance of a doubled plant from its twin, uniform"
    )
    weed_fraction: float = Field(
        0.0,
        ge=0.0,
        description="weeds per sowing position; the crops_weeds experiment had "
        "5 weeds among 62 plants (App. C.2), i.e. about 0.08",
    )
    weeds_off_row: bool = Field(
        True, description="weeds stand anywhere in the field, not on the rows (App. C.2)"
    )
    length_range: tuple[float, float] = Field(
        (0.12, 0.57),
        description="m, physical plant length, uniform: the paper's simulated "
        "plants are 0.12-0.57 m long (sec. 3.1.2)",
    )
    l_max: float = Field(
        0.6,
        gt=0.0,
        description="m; a discrete size attribute is the length binned into n "
        "equal cells of [0, l_max] (App. B); a schema growth model's l_max overrides it",
    )
    value_weights: dict[str, dict[str, float]] = Field(
        default_factory=lambda: {
            # the intercropping experiment: 57 plants of type A and 5 of type B (sec. 3.2.2)
            "type": {"A": 0.92, "B": 0.08, "crop": 1.0, "weed": 0.0},
            # 18 of 62 plants had the 'disease' tape (App. C.1)
            "health": {"healthy": 0.71, "diseased": 0.29},
        },
        description="relative frequencies of discrete truth values; values not named here are "
        "uniform among the rest. Weeds get type 'weed' whatever the weights say",
    )

    @model_validator(mode="after")
    def _check(self) -> FieldLayout:
        if (self.n_plants is None) == (self.row_length is None):
            raise ValueError("give exactly one of n_plants and row_length")
        for name in ("plant_spacing", "double_offset", "length_range"):
            lo, hi = getattr(self, name)
            if not 0.0 <= lo <= hi:
                raise ValueError(f"{name}: need 0 <= low <= high, got ({lo}, {hi})")
        if self.plant_spacing[0] <= 0.0:
            raise ValueError("plant_spacing must be positive")
        return self


class PathConfig(_Strict):
    """The predefined lawnmower survey (sec. 2.7): lanes between neighbouring rows, joined by
    round turns on the headlands; the robot drives at constant speed."""

    speed: float = Field(0.4, gt=0.0, description="m/s; Spot walks a survey at about 0.3-0.5 m/s")
    frame_rate_hz: float = Field(
        2.0,
        gt=0.0,
        description="camera frames per second. The paper processes about one "
        "frame per second (sec. 3.1.3); at 0.4 m/s, 2 Hz puts a frame every 0.2 m so a plant "
        "stays in view for about 10 frames per pass: several measurements per plant",
    )
    odom_rate_hz: float | None = Field(
        None,
        gt=0.0,
        description="odometry records per second; None: one per camera frame, "
        "at the frame's time (keeps the pose graph small)",
    )
    headland: float = Field(
        1.0, ge=0.0, description="m the lanes reach past the row ends, room for turning"
    )
    turn_radius: float = Field(
        0.5, gt=0.0, description="m; half the row spacing makes a U-turn a semicircle"
    )
    lanes: Literal["between", "all"] = Field(
        "between",
        description="'between': one lane between each pair of rows; 'all': also "
        "one outside each outer row",
    )
    n_robots: int = Field(1, ge=1, description="robots, each on its own block of lanes")
    return_to_start: bool = Field(
        False,
        description="end back at the start, seeing the first plants again: the paper's "
        "loop closure case (App. C)",
    )
    closure_length: float = Field(
        3.0,
        ge=0.0,
        description="m driven back into the first lane when the survey ends on the start headland",
    )
    revisit_waypoints: list[tuple[float, float]] = Field(
        default_factory=list,
        description="map-frame points driven after the survey (and the "
        "return), e.g. to look again at uncertain plants",
    )
    start_sigma: tuple[float, float, float] = Field(
        (0.01, 0.01, 0.005),
        description="std of the start-pose prior in meta (m, m, rad): "
        "the robot is put down at a surveyed marker",
    )


class OdometryNoise(_Strict):
    """Noise on each odometry increment (in the previous robot frame), plus a slow heading
    bias. Calibrated so the dead-reckoned trajectory of one survey of the default 400-plant
    field drifts about 0.5 m RMS, as the paper's odometry-noise simulation (0.503 m,
    sec. 3.1.2; 0.516 m in App. C)."""

    kind: Literal["delta", "pose"] = Field(
        "delta", description="write increments ('delta') or odometry-frame poses ('pose')"
    )
    sigma_x_per_m: float = Field(
        0.02,
        ge=0.0,
        description="std of the forward error per metre driven (2 %: legged odometry slips)",
    )
    sigma_y_per_m: float = Field(
        0.01, ge=0.0, description="std of the sideways error per metre driven"
    )
    # a yaw-rate bias (random sign) does most of the drift, relaxing over drift.bias_length;
    # the white heading noise adds the spread
    sigma_theta_per_m: float = Field(
        0.002, ge=0.0, description="rad of heading noise per metre driven"
    )
    sigma_theta_per_rad: float = Field(
        0.005, ge=0.0, description="rad of heading noise per radian turned (0.5 %)"
    )
    sigma_floor: tuple[float, float, float] = Field(
        (1e-4, 1e-4, 1e-4),
        description="std added to every step (m, m, rad): standing still "
        "is not perfectly certain either",
    )
    heading_bias: float = Field(
        2.8e-4,
        ge=0.0,
        description="rad/s, size of the yaw-rate bias at the start, its sign drawn per robot "
        "(legged odometry slips more to one side): 2.8e-4 rad/s = 1 deg/min",
    )
    heading_bias_walk: float = Field(
        2.0e-6, ge=0.0, description="rad/s per sqrt(s): the bias wanders slowly"
    )
    drift: DistanceDrift = Field(default_factory=DistanceDrift)  # over long surveys
    report_scale: float = Field(
        1.0,
        gt=0.0,
        description="reported covariance = report_scale^2 x the white noise "
        "actually added (the bias is not in it, as with real odometry)",
    )
    effects: OdometryEffects = Field(
        default_factory=OdometryEffects,
        description="a real robot's clock offset and turn scale (off by default); the "
        "forward scale per robot is drift.scale_sigma",
    )


class DetectorConfig(_Strict):
    """A front RGB-D camera with a segmenting detector (sec. 2.3, App. A)."""

    camera_xy: tuple[float, float] = Field(
        (0.3, 0.0), description="m, camera position in the robot base frame (Spot's front)"
    )
    fov_deg: float = Field(
        90.0, gt=0.0, le=360.0, description="horizontal field of view (two front cameras)"
    )
    min_range: float = Field(0.3, ge=0.0, description="m; closer plants are below the image")
    max_range: float = Field(
        2.5, gt=0.0, description="m, cut-off: farther objects are not considered (App. A)"
    )
    p_detect_near: float = Field(
        0.95, ge=0.0, le=1.0, description="detection probability next to the camera"
    )
    p_detect_far: float = Field(
        0.75,
        ge=0.0,
        le=1.0,
        description="detection probability at max_range (a recall in line "
        "with the Gazebo model's mAP50 of 0.71, App. A); linear in range in between",
    )
    geometry: Literal["xy", "range_bearing"] = Field(
        "xy", description="report positions as xy + cov (mask-averaged depth) or range/bearing"
    )
    sigma_depth_0: float = Field(0.02, ge=0.0, description="m, depth noise std at zero range")
    sigma_depth_per_m2: float = Field(
        0.015,
        ge=0.0,
        description="m per m^2: RGB-D depth noise grows with range squared; 0.11 m at 2.5 m",
    )
    depth_bias_fraction: float = Field(
        0.1,
        ge=0.0,
        description="depth bias towards the robot as a fraction of the plant "
        "length: averaging the mask's depth sees the near side of the plant (sec. 2.3)",
    )
    sigma_bearing: float = Field(
        0.01, ge=0.0, description="rad; the direction to a plant is certain (sec. 2.6.1)"
    )
    sigma_lateral_0: float = Field(
        0.01, ge=0.0, description="m, jitter of the mask centroid across the ray, any range"
    )
    report_sigma_scale: float = Field(
        1.5,
        gt=0.0,
        description="reported depth std = this x true noise std, bias included: "
        "the paper couples a 'relatively large depth variance' to hide the bias (sec. 2.3)",
    )
    clutter_rate: float = Field(
        0.05,
        ge=0.0,
        description="false detections of nothing per frame, Poisson: with the "
        "Gazebo model's precision of 0.83 (App. A) most false positives are doubles, below",
    )
    clutter_fraction: float = Field(
        0.0,
        ge=0.0,
        description="more false detections of nothing, as a share of the frame's plant "
        "detections (Poisson, on top of clutter_rate): a hostile scenario",
    )
    outlier_fraction: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="share of plant detections with a gross range error, reported as good "
        "ones: a hostile scenario",
    )
    outlier_range: tuple[float, float] = Field(
        (1.0, 4.0), description="m, size of a gross range error, uniform, either way along the ray"
    )
    double_detection_p: float = Field(
        0.03,
        ge=0.0,
        le=1.0,
        description="chance a plant is detected twice in one frame (split mask, sec. 2.6.3)",
    )
    double_offset_sigma: float = Field(
        0.08, ge=0.0, description="m, std of the second detection from the first"
    )
    accuracy: dict[str, tuple[float, float]] = Field(
        default_factory=lambda: {
            # colours are easy for the network (all correct in sec. 3.1.2)
            "colour": (0.97, 0.90),
            "type": (0.95, 0.85),
            # size is harder than colour or type (App. A; 44 of 50 right in sec. 3.1.2)
            "size": (0.82, 0.65),
            # 54 of 62 health states right after a survey (App. C.1)
            "health": (0.90, 0.75),
        },
        description="chance a discrete measurement is right (near camera, at max_range), "
        "linear in range in between; attributes not named use default_accuracy",
    )
    default_accuracy: tuple[float, float] = Field(
        (0.9, 0.75), description="accuracy (near camera, at max_range) of attributes not named"
    )
    ordinal_attributes: list[str] = Field(
        default_factory=lambda: ["size"],
        description="wrong values of these fall on the "
        "neighbouring values more often (a small plant is taken for medium, rarely for big)",
    )
    p_concentration: float = Field(
        20.0,
        gt=0.0,
        description="Beta concentration of a detection's true correctness "
        "probability around the accuracy: different plants are not equally easy",
    )
    p_noise: float = Field(
        0.05,
        ge=0.0,
        description="std of the reported p around that true probability: "
        "calibrated on average (sec. 2.3: the score is 'a useful estimate' of p)",
    )
    sigma_length_0: float = Field(0.02, ge=0.0, description="m, length noise std at zero range")
    sigma_length_per_m: float = Field(
        0.03,
        ge=0.0,
        description="m per m: the length std grows with distance, so its "
        "variance with distance squared (sec. 3.1.2)",
    )
    emit_label: bool = Field(
        False,
        description="also give the combined detector label ('crop_small_healthy') and "
        "its score, as the experiments' YOLO model does (App. A)",
    )
    effects: CameraEffects = Field(
        default_factory=CameraEffects,
        description="a real camera's depth-like range and range scale per robot, noise growing "
        "with range (on top of the depth noise), heavy-tailed and offset bearings, misread "
        "plants and blind spells (off by default)",
    )


class GrowthConfig(_Strict):
    """Plant growth between survey days: dx/dt = alpha (l_max - x) (App. B)."""

    survey_days: list[float] = Field(
        default_factory=lambda: [0.0], description="day of each survey; plants grow between"
    )
    rate_per_day: float = Field(
        0.04,
        gt=0.0,
        description="alpha of App. B (Fig. 13 uses 0.04/day); a schema growth model overrides it",
    )
    rate_spread: float = Field(
        0.2, ge=0.0, lt=1.0, description="per-plant relative spread of alpha, uniform +-"
    )


class AnchorConfig(_Strict):
    """Where the simulated field lies, written as the log's anchor: the WGS84 position of the
    map origin, the map x axis `yaw_deg` from east to north."""

    lat: float = 51.4488
    lon: float = 5.4905
    h: float = 20.0
    yaw_deg: float = 0.0


class SimConfig(_Strict):
    """Root of the simulator configuration; `Simulator(SimConfig())` is the paper's default
    400-plant run."""

    seed: int = Field(1, description="everything random follows from it")
    schema_: FieldSchema | str = Field("colour_size", alias="schema")
    field: FieldLayout = Field(default_factory=FieldLayout)
    path: PathConfig = Field(default_factory=PathConfig)
    odometry: OdometryNoise = Field(default_factory=OdometryNoise)
    detector: DetectorConfig = Field(default_factory=DetectorConfig)
    growth: GrowthConfig = Field(default_factory=GrowthConfig)
    anchor: AnchorConfig | None = Field(default_factory=AnchorConfig)
    gnss: GnssSimConfig | None = Field(None, description="a GNSS receiver; None: no fixes")
    announce_row_angle: bool = Field(
        False, description="put the row angle in the meta field prior (the paper estimates it)"
    )

    model_config = ConfigDict(extra="forbid", validate_assignment=True, populate_by_name=True)

    def field_schema(self) -> FieldSchema:
        if isinstance(self.schema_, str):
            return FieldSchema.preset(self.schema_)
        return self.schema_
