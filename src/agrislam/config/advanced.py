"""The `advanced:` section: every knob a user rarely sets, by the part of the method it
tunes. A value left out (none) where the description says so is chosen from the survey
(config/effective.py)."""

from __future__ import annotations

import warnings
from typing import Any, ClassVar, Literal

from pydantic import Field, PositiveFloat, model_validator

from agrislam.config.gnss import AdvancedGnss
from agrislam.config.limits import InputLimits, StrictModel
from agrislam.config.live import AdvancedLive
from agrislam.config.season import SeasonConfig

# association keys renamed since 0.1: old -> new (read with a FutureWarning)
RENAMED_ASSOCIATION_KEYS = {"detection_covariance": "innovation_gate"}
# keys that are gone, with what took their place
REMOVED_ASSOCIATION_KEYS = {
    "weak_tentative": "young objects are tentative while maintenance.existence confirms them"
}


class SemanticsConfig(StrictModel):
    """Belief updates and the interest heuristic (sec. 2.5, 2.7)."""

    heuristic_alpha: float = Field(2.0, gt=0.0, description="sigmoid steepness, sec. 2.7")
    heuristic_beta: float = Field(0.2, description="sigmoid midpoint, sec. 2.7")
    probability_floor: float = Field(
        1e-9, gt=0.0, lt=0.01, description="smallest probability a belief may hold (no dead zeros)"
    )
    surface_resolution: float = Field(0.1, gt=0.0, description="interest surface cell size, m")
    surface_sigma: float = Field(0.25, gt=0.0, description="spread of one object's interest, m")


class CalibrationConfig(StrictModel):
    """Noise that calibrates itself (estimation/noise_calibration.py): the scales of the
    detection, odometry translation and heading noise, estimated from the run's own pairs of
    sightings of an object; the configured noise is the start."""

    enabled: bool = Field(True, description="estimate the noise scales online and use them")
    min_pairs: int = Field(200, ge=10, description="pairs of sightings before a first estimate")
    update_every: int = Field(200, ge=1, description="new pairs between estimates")
    max_pairs: int = Field(20_000, ge=100, description="the latest pairs an estimate uses")
    tie_odometry: bool = Field(
        True,
        description="one factor on the odometry's translation and heading noise: from "
        "re-sightings alone the two drifts are hard to tell apart, and estimated apart "
        "one of them takes the other's share",
    )
    ratio: float = Field(
        0.25,
        gt=0.0,
        le=1.0,
        description="a pair counts only if every other object around lies 1/ratio times "
        "farther from the detection than the pair's two sightings from each other (or, "
        "for a pair with an older sighting, than the detection from its object in the map)",
    )
    sigma_bounds: tuple[PositiveFloat, PositiveFloat] = Field(
        (1.0, 30.0),
        description="the smallest and largest sigma factor an estimate may take; by default "
        "a record's or the configured noise is a floor: noise found smaller is not used, "
        "since a model too sure of itself splits objects and a safe one does not",
    )

    @model_validator(mode="after")
    def _ordered(self) -> CalibrationConfig:
        if self.sigma_bounds[0] > self.sigma_bounds[1]:
            raise ValueError(f"sigma_bounds {self.sigma_bounds} must be (low, high)")
        return self


class AdvancedSensor(StrictModel):
    """The sensor model's defaults, the bounds of what a record may carry, and what the run
    learns of its sensors."""

    odom_cov_diag: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = Field(
        (1e-4, 1e-4, 4e-6), description="odometry covariance (x, y, heading) a record lacks"
    )
    depth_bias: float = Field(
        0.0, description="m a detection lies nearer than the plant's centre (initial value)"
    )
    estimate_depth_bias: bool = Field(
        True, description="learn the depth bias from multi-view residuals (sec. 2.3)"
    )
    depth_bias_min_views: int = Field(
        4, ge=1, description="detections of an object before its residuals count"
    )
    estimate_biases: bool = Field(
        True,
        description="learn each range-bearing sensor's off-axis range term, bearing offset "
        "and clock offset against the odometry from pairs of its sightings, and take them "
        "off its detections (estimation/sensor_calibration.py)",
    )
    limits: InputLimits = Field(
        default_factory=InputLimits,
        description="bounds of what a source accepts from a record (io/sources/validate.py)",
    )
    calibration: CalibrationConfig = Field(
        default_factory=CalibrationConfig,
        description="noise scales estimated from the run's own re-observations",
    )


class AdvancedAssociation(StrictModel):
    """The association's gate (sec. 2.4 and beyond it)."""

    # keys an older config may still give (config/legacy.py)
    LEGACY_KEYS: ClassVar[tuple[str, ...]] = (*RENAMED_ASSOCIATION_KEYS, *REMOVED_ASSOCIATION_KEYS)

    @model_validator(mode="before")
    @classmethod
    def _renamed_keys(cls, data: Any) -> Any:
        """Configs written before a key was renamed, or removed, keep working, with a
        warning."""
        if not isinstance(data, dict):
            return data
        for old, new in RENAMED_ASSOCIATION_KEYS.items():
            if old in data:
                warnings.warn(
                    f"association.{old} is now advanced.association.{new}; please rename it",
                    FutureWarning,
                    stacklevel=2,
                )
                data = {**data, new: data[old]}
                del data[old]
        for old, instead in REMOVED_ASSOCIATION_KEYS.items():
            if old in data:
                warnings.warn(f"association.{old} is ignored: {instead}", FutureWarning, 2)
                data = {k: v for k, v in data.items() if k != old}
        return data

    use_semantics: bool = True
    innovation_gate: bool | None = Field(
        None,
        description="compare e against its whole covariance instead of the paper's K_n "
        "alone: the tighter of K_n + R_m + the robot pose marginal and R_m + the robot's drift "
        "since it last saw the object; none: on when mapped as landmarks (no field prior)",
    )
    gate_chi2: float | None = Field(
        None,
        gt=0.0,
        description="the Mahalanobis term is divided by this (the paper: 1, a one-sigma gate; "
        "9.21 accepts 99 % of true associations of a 2D position); none: 1, or "
        "landmark_gate_chi2 when mapped as landmarks",
    )
    landmark_defaults: bool = Field(
        True,
        description="a survey without a field prior is not the crop field the paper's "
        "defaults are for: it is mapped as point landmarks (config/effective.py)",
    )
    landmark_gate_chi2: float = Field(
        9.21, gt=0.0, description="the gate without a field prior: 99 % of a 2D position"
    )
    landmark_sigma_max: float = Field(
        3.0, gt=0.0, description="m, gate_sigma_max without a field prior"
    )
    gate_sigma_max: float | None = Field(
        None,
        gt=0.0,
        description="m; largest object position sigma the spatial gate allows for; none: 1, "
        "or landmark_sigma_max when mapped as landmarks",
    )


class AdvancedSlam(StrictModel):
    """The solver and the keyframes that bound a step's cost (sec. 2.6)."""

    batch_optimizer: Literal["lm", "dogleg"] = "lm"
    robust_k: float = Field(1.345, gt=0.0, description="kernel width in standard deviations")
    relinearize_threshold: float = Field(
        0.05, gt=0.0, description="iSAM2 relinearises a node that moved more than this (m, rad)"
    )
    relinearize_skip: int = Field(1, ge=1, description="iSAM2 checks that every n-th step")
    factorization: Literal["qr", "cholesky"] = Field(
        "qr",
        description="iSAM2's linear solver: QR keeps working where a survey's uncertainty "
        "spans many orders of magnitude and Cholesky finds the system indeterminate",
    )
    window: int = Field(
        100,
        ge=0,
        description="steps between keyframes; older poses and objects are folded onto the "
        "keyframes so a step's cost stays bounded; 0 = plain iSAM2 over the whole graph",
    )
    keyframes_kept: int = Field(
        100,
        ge=0,
        description="keyframes the graph keeps, shared equally by the robots (at most "
        "`keyframes_per_robot` each); older ones are folded away and held where they stand, "
        "with what hangs on them, so the graph stays bounded however long the survey; "
        "0 = every keyframe stays",
    )
    keyframes_per_robot: int = Field(
        30,
        ge=1,
        description="the most keyframes one robot keeps: the kept keyframes are tied together "
        "in the Bayes tree's top clique, which every marginal read for association goes through",
    )
    refine_turn_deg: float = Field(
        3.0,
        ge=0.0,
        description="with keyframes: refine by itself once a keyframe has turned this much "
        "since history was folded onto it (a large loop closure); 0 = never",
    )
    refine_max_factors: int = Field(
        50_000,
        ge=0,
        description="with keyframes: a refine solves the whole recorded graph in one batch "
        "only up to this many factors (a batch costs memory in proportion); beyond, it "
        "relinearises the keyframe graph the history is folded onto",
    )


class AdvancedRows(StrictModel):
    """How rows are fitted and how hard they hold their plants (sec. 2.6.2)."""

    n_det_est: int = Field(12, ge=2, description="detections before the first row fit")
    min_fit_objects: int = Field(
        10, ge=2, description="objects seen in min_detections frames before the first row fit"
    )
    first_fit_ambiguity: float = Field(
        0.5,
        gt=0.0,
        le=1.0,
        description="the first row fit waits while a rival angle explains the objects this "
        "well relative to the best (a few points lie on a lattice at many angles)",
    )
    sigma_cross: float = Field(0.05, gt=0.0, description="m, plant to row line, across the row")
    sigma_spacing: float = Field(0.05, gt=0.0, description="m, between neighbouring row lines")
    max_offset: float = Field(
        0.2, gt=0.0, description="m; a plant farther from every row gets no row constraint"
    )
    min_detections: int = Field(
        3, ge=1, description="frames an object is seen in before it may join a row"
    )
    angle_prior_sigma_deg: float = Field(
        1.0,
        ge=0.0,
        description="std of a given row_angle_deg as a prior; 0 fixes the angle (an angle the "
        "plants contradict is replaced by the fitted one, and reported)",
    )


class MaintenanceConfig(StrictModel):
    """Merging and pruning (sec. 2.6.3), and the confirmation of young objects."""

    merge: bool = True
    prune: bool = True
    prune_max_meas: int = Field(2, ge=0, description="objects seen at most this often may go")
    prune_min_interest: float = Field(
        0.4,
        ge=0.0,
        le=1.0,
        description="h at or above which a rarely seen object goes; one seen once always "
        "has h >= 0.5 (eq. 2), so 0.4 prunes stray one-off detections and pairs that agree "
        "poorly",
    )
    prune_grace_s: float = Field(20.0, ge=0.0, description="s unseen before pruning")
    existence: bool = Field(
        True,
        description="a new object is tentative until the frames that had it in view confirm "
        "it (maintenance/existence.py); its detections' factors get association.d_inter of "
        "isotropic noise added meanwhile, so clutter cannot pull the poses, and it joins no "
        "row; not in the paper",
    )
    confirm_p: float = Field(
        0.999,
        gt=0.5,
        lt=1.0,
        description="posterior probability of being there (or not) that confirms (drops) a "
        "tentative object; it needs two frames' sightings at least",
    )
    stray_rate_prior: float = Field(
        0.05,
        gt=0.0,
        lt=0.5,
        description="prior chance per frame in view that a stray detection lands on a point "
        "with nothing there; the survey's own rate is learned, this holds where it has little "
        "clutter to learn from",
    )
    stray_prior_views: float = Field(
        20.0, ge=0.0, description="frames in view the stray_rate_prior weighs as"
    )


class AdvancedMaintenance(MaintenanceConfig):
    """`MaintenanceConfig` as a file sets it: the confirmation may be left to the survey."""

    existence: bool | None = Field(  # type: ignore[assignment]
        None,
        description="confirm young objects from the frames that had them in view "
        "(maintenance/existence.py); none: on, unless the survey is mapped as landmarks "
        "(seen now and then from far, they would not be confirmed)",
    )


class AdvancedConfig(StrictModel):
    """Every knob a user rarely sets, by the part of the method it tunes."""

    semantics: SemanticsConfig = Field(default_factory=SemanticsConfig)
    sensor: AdvancedSensor = Field(default_factory=AdvancedSensor)
    association: AdvancedAssociation = Field(default_factory=AdvancedAssociation)
    slam: AdvancedSlam = Field(default_factory=AdvancedSlam)
    rows: AdvancedRows = Field(default_factory=AdvancedRows)
    maintenance: AdvancedMaintenance = Field(default_factory=AdvancedMaintenance)
    gnss: AdvancedGnss = Field(default_factory=AdvancedGnss)
    season: SeasonConfig = Field(default_factory=SeasonConfig)
    live: AdvancedLive = Field(default_factory=AdvancedLive)
