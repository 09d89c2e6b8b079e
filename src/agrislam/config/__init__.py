"""Configuration: the field schema (which semantic attributes a plant has) and the
parameters of every stage of the pipeline, as pydantic models.

Everything a run can be told lives here; the parts of the pipeline are built from
these models (DESIGN.md "Package layout"). `AgrislamConfig` is the root.
"""

from __future__ import annotations

import json
import math
import tomllib
import warnings
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, model_validator

from agrislam.config.gnss import GnssConfig
from agrislam.config.limits import InputLimits, first_error
from agrislam.config.limits import StrictModel as _Strict
from agrislam.config.season import SeasonConfig

SECONDS_PER_DAY = 86_400.0
# association keys renamed since 0.1: old -> new (read with a FutureWarning)
RENAMED_ASSOCIATION_KEYS = {"detection_covariance": "innovation_gate"}
# keys that are gone, with what took their place
REMOVED_ASSOCIATION_KEYS = {
    "weak_tentative": "young objects are tentative while maintenance.existence confirms them"
}


# --------------------------------------------------------------------------- schema


class GrowthModel(_Strict):
    """Asymptotic growth dx/dt = rate (l_max - x) of App. B, for a size-like attribute.

    For a discrete attribute the values are read as `n` equal cells of [0, l_max]
    (smallest first); for a continuous one the mean follows the same ODE.
    """

    kind: Literal["growth"] = "growth"
    rate_per_day: float = Field(0.04, gt=0.0, description="alpha of App. B, in 1/day")
    l_max: float = Field(..., gt=0.0, description="maximum length the plant grows to")
    process_noise: float = Field(
        0.0, ge=0.0, le=1.0, description="probability mass per day leaked uniformly (discrete)"
    )
    variance_per_day: float = Field(
        0.0, ge=0.0, description="variance added per day to a continuous attribute"
    )


class DiscreteAttribute(_Strict):
    kind: Literal["discrete"] = "discrete"
    values: list[str]
    prior: list[float] | None = Field(None, description="initial distribution; uniform if absent")
    time_model: GrowthModel | None = None

    @model_validator(mode="after")
    def _check(self) -> DiscreteAttribute:
        if len(self.values) < 2:
            raise ValueError(f"needs at least 2 values, got {self.values!r}")
        dup = sorted({v for v in self.values if self.values.count(v) > 1})
        if dup:
            raise ValueError(f"duplicate values {dup!r}")
        if self.prior is not None:
            p = self.prior
            if len(p) != len(self.values):
                raise ValueError(f"prior has {len(p)} entries for {len(self.values)} values")
            if any((not math.isfinite(x)) or x < 0 for x in p) or not math.isclose(sum(p), 1.0):
                raise ValueError(f"prior {p!r} is not a probability distribution")
        return self

    @property
    def n_values(self) -> int:
        return len(self.values)


class ContinuousAttribute(_Strict):
    kind: Literal["continuous"] = "continuous"
    min: float
    max: float
    prior_mean: float | None = Field(None, description="initial mean; mid-range if absent")
    prior_var: float | None = Field(
        None, gt=0.0, description="initial variance; that of a uniform over [min, max] if absent"
    )
    time_model: GrowthModel | None = None

    @model_validator(mode="after")
    def _check(self) -> ContinuousAttribute:
        if not (math.isfinite(self.min) and math.isfinite(self.max)):
            raise ValueError("min and max must be finite (they normalise the entropy, sec. 2.1.2)")
        if self.min >= self.max:
            raise ValueError(f"min {self.min} must be below max {self.max}")
        return self

    @property
    def initial_mean(self) -> float:
        return 0.5 * (self.min + self.max) if self.prior_mean is None else self.prior_mean

    @property
    def initial_var(self) -> float:
        # variance of a uniform distribution over [min, max]: an uninformed start
        return (self.max - self.min) ** 2 / 12.0 if self.prior_var is None else self.prior_var


Attribute = Annotated[DiscreteAttribute | ContinuousAttribute, Field(discriminator="kind")]


class FieldSchema(_Strict):
    """The semantic attributes every object of the map carries (sec. 2.1)."""

    attributes: dict[str, Attribute] = Field(default_factory=dict)

    @model_validator(mode="before")
    @classmethod
    def _name_the_bad_attribute(cls, data: Any) -> Any:
        """Validate each attribute on its own so that the error names it."""
        if not isinstance(data, dict) or not isinstance(data.get("attributes"), dict):
            return data
        for name, spec in data["attributes"].items():
            if isinstance(spec, BaseModel):
                continue
            if not isinstance(spec, dict):
                raise ValueError(f"attribute {name!r}: expected a mapping, got {spec!r}")
            kind = spec.get("kind")
            models = {"discrete": DiscreteAttribute, "continuous": ContinuousAttribute}
            model = models.get(kind) if isinstance(kind, str) else None
            if model is None:
                raise ValueError(
                    f"attribute {name!r}: unknown kind {kind!r} (expected 'discrete' or "
                    "'continuous')"
                )
            try:
                model.model_validate(spec)
            except ValueError as err:
                raise ValueError(f"attribute {name!r}: {first_error(err)}") from None
        return data

    @property
    def discrete(self) -> dict[str, DiscreteAttribute]:
        return {k: v for k, v in self.attributes.items() if isinstance(v, DiscreteAttribute)}

    @property
    def continuous(self) -> dict[str, ContinuousAttribute]:
        return {k: v for k, v in self.attributes.items() if isinstance(v, ContinuousAttribute)}

    @classmethod
    def load(cls, path: str | Path) -> FieldSchema:
        """Read a schema from YAML, TOML or JSON; a top-level `schema` key is accepted too."""
        data = load_mapping(path)
        return cls.model_validate(data.get("schema", data))

    @classmethod
    def preset(cls, name: str) -> FieldSchema:
        try:
            return cls.model_validate(SCHEMA_PRESETS[name])
        except KeyError:
            raise ValueError(
                f"unknown schema preset {name!r}; known: {', '.join(sorted(SCHEMA_PRESETS))}"
            ) from None


COLOURS = ["blue", "cyan", "green", "orange", "pink", "red", "yellow"]
SIZES = ["small", "medium", "big"]
HEALTH = ["healthy", "diseased"]
# the paper's simulated plants are 0.12-0.57 m long (sec. 3.1.2)
LENGTH_RANGE = (0.0, 0.6)

# The paper's attribute tables (Tables 1 and 2).
SCHEMA_PRESETS: dict[str, dict[str, Any]] = {
    "colour_size": {
        "attributes": {
            "colour": {"kind": "discrete", "values": COLOURS},
            "size": {"kind": "discrete", "values": SIZES},
        }
    },
    "colour_length": {
        "attributes": {
            "colour": {"kind": "discrete", "values": COLOURS},
            "length": {"kind": "continuous", "min": LENGTH_RANGE[0], "max": LENGTH_RANGE[1]},
        }
    },
    "intercropping": {
        "attributes": {
            "type": {"kind": "discrete", "values": ["A", "B"]},
            "size": {"kind": "discrete", "values": SIZES},
            "health": {"kind": "discrete", "values": HEALTH},
        }
    },
    "crops_weeds": {
        "attributes": {
            "type": {"kind": "discrete", "values": ["crop", "weed"]},
            "size": {"kind": "discrete", "values": SIZES},
            "health": {"kind": "discrete", "values": HEALTH},
        }
    },
}


# --------------------------------------------------------------------- pipeline parts


class SemanticsConfig(_Strict):
    """Belief updates and the interest heuristic (sec. 2.5, 2.7)."""

    heuristic_alpha: float = Field(2.0, gt=0.0, description="sigmoid steepness, sec. 2.7")
    heuristic_beta: float = Field(0.2, description="sigmoid midpoint, sec. 2.7")
    probability_floor: float = Field(
        1e-9, gt=0.0, lt=0.01, description="smallest probability a belief may hold (no dead zeros)"
    )
    surface_resolution: float = Field(0.1, gt=0.0, description="interest surface cell size, m")
    surface_sigma: float = Field(0.25, gt=0.0, description="spread of one object's interest, m")


class CalibrationConfig(_Strict):
    """Noise that calibrates itself (estimation/noise_calibration.py): the scales of the detection,
    odometry translation and odometry heading noise, estimated from the run's own pairs of
    sightings of an object and used from then on; the configured noise is the start."""

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


class SensorDefaults(_Strict):
    """Uncertainties used when a record does not carry its own, and the bounds of what a
    record may carry (`limits`)."""

    odom_cov_diag: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = (1e-4, 1e-4, 4e-6)
    odom_sigma_scale: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = Field(
        (1.0, 1.0, 1.0),
        description="factors on every odometry sigma (x, y, heading), the record's or the "
        "default: for wheel odometry whose stated covariance is overconfident",
    )
    detection_sigma_depth: float = Field(0.10, gt=0.0, description="m, along the viewing ray")
    detection_sigma_lateral: float = Field(0.03, gt=0.0, description="m, across the ray")
    depth_bias: float = Field(
        0.0, description="m a detection lies nearer than the plant's centre (initial value)"
    )
    estimate_depth_bias: bool = Field(
        True, description="learn the depth bias from multi-view residuals (sec. 2.3)"
    )
    depth_bias_min_views: int = Field(
        4, ge=1, description="detections of an object before its residuals count"
    )
    max_range: float = Field(
        2.5, gt=0.0, description="detections farther away are dropped (App. A)"
    )
    limits: InputLimits = Field(
        default_factory=InputLimits,
        description="bounds of what a source accepts from a record (io/sources/validate.py)",
    )
    calibration: CalibrationConfig = Field(
        default_factory=CalibrationConfig,
        description="noise scales estimated from the run's own re-observations (issue 11)",
    )


class AssociationConfig(_Strict):
    """Data association (sec. 2.4)."""

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
                    f"association.{old} is now association.{new}; please rename it",
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

    w_sem: float = Field(0.3, ge=0.0, le=1.0, description="semantic weight w_sem")
    d_inter: float = Field(
        0.2,
        gt=0.0,
        description="m, the distance scale of sec. 2.4 and the merge distance of sec. 2.6.3; "
        "a survey's field prior sets it to half its minimum plant distance, the midpoint "
        "between neighbours, unless given here",
    )
    use_semantics: bool = True
    innovation_gate: bool = Field(
        False,
        description="compare e against its whole covariance instead of the paper's K_n "
        "alone: the tighter of K_n + R_m + the robot pose marginal (DESIGN step 3) and "
        "R_m + the robot's drift since it last saw the object (association/gnn.py); "
        "formerly `detection_covariance`",
    )
    gate_chi2: float = Field(
        1.0,
        gt=0.0,
        description="the Mahalanobis term is divided by this (the paper: 1, a one-sigma "
        "gate); e.g. 9.21 accepts 99 % of true associations of a 2D position",
    )
    landmark_defaults: bool = Field(
        True,
        description="a survey without a field prior is not the crop field the paper's "
        "defaults are for: unless set here, it is gated on the whole innovation (at "
        "landmark_gate_chi2, over landmark_sigma_max), d_inter is three of its first "
        "detections' median sharpest sigma, rows are off, the crop camera's confirmation of "
        "young objects (maintenance.existence) is off, and a lost robot rejoins "
        "(association/rejoin.py)",
    )
    landmark_gate_chi2: float = Field(
        9.21, gt=0.0, description="the gate without a field prior: 99 % of a 2D position"
    )
    landmark_sigma_max: float = Field(
        3.0, gt=0.0, description="m, gate_sigma_max without a field prior"
    )
    gate_sigma_max: float = Field(
        1.0, gt=0.0, description="m; largest object position sigma the spatial gate allows for"
    )
    index_margin: float = Field(
        0.3, ge=0.0, description="m an estimate may move between spatial index rebuilds"
    )
    index_rebuild_steps: int = Field(50, ge=1, description="steps between index rebuilds")
    index_sweep_steps: int = Field(
        100,
        ge=1,
        description="steps over which every object's position in the index is read again "
        "once (a slice each step): objects not seen move only with the map's keyframes, "
        "and reading all at once would stall a step on a large field",
    )


class SlamConfig(_Strict):
    """Graph back end (sec. 2.6)."""

    backend: Literal["incremental", "batch"] = "incremental"
    batch_optimizer: Literal["lm", "dogleg"] = "lm"
    robust_kernel: Literal["huber", "cauchy", "none"] = "huber"
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
        "with what hangs on them, so the graph stays bounded however long the survey (a loop "
        "longer than this localises against the old map); 0 = every keyframe stays",
    )
    keyframes_per_robot: int = Field(
        30,
        ge=1,
        description="the most keyframes one robot keeps: the kept keyframes are tied together "
        "in the Bayes tree's top clique, which every marginal read for association goes through",
    )
    covariance_reuse_steps: int = Field(
        10,
        ge=1,
        description="a marginal covariance read for association serves this many steps of "
        "each robot if its object was seen since, ten times as many if not (each read is a "
        "Bayes-tree traversal, backend/incremental/marginal_cache.py); 1 = read each step it "
        "is seen",
    )
    refine_turn_deg: float = Field(
        3.0,
        ge=0.0,
        description="with keyframes: refine() by itself once a keyframe has turned this much "
        "since history was folded onto it (a large loop closure); 0 = never",
    )
    refine_max_factors: int = Field(
        50_000,  # about 1.6 KB of GTSAM memory a factor in a batch: ~80 MB at most
        ge=0,
        description="with keyframes: refine() solves the whole recorded graph in one batch "
        "only up to this many factors (a batch costs memory in proportion); beyond, it "
        "relinearises the keyframe graph the history is folded onto (bounded memory)",
    )
    turn_refine_max_factors: int = Field(
        50_000,
        ge=0,
        description="the same bound for a refine that refine_turn_deg starts during the "
        "survey: that batch stalls the step it runs in (0.1-0.3 ms a factor), so a large "
        "graph relinearises its keyframe graph instead and the full batch waits for the "
        "end of the survey",
    )


class RowsConfig(_Strict):
    """Row prior knowledge (sec. 2.6.2)."""

    enabled: bool = True
    row_spacing: float = Field(1.0, gt=0.0, description="m between neighbouring rows")
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
    row_angle_deg: float | None = Field(None, description="known row direction, if any")
    sigma_cross: float = Field(0.05, gt=0.0, description="m, plant to row line, across the row")
    sigma_spacing: float = Field(0.05, gt=0.0, description="m, between neighbouring row lines")
    max_offset: float = Field(
        0.2, gt=0.0, description="m; a plant farther from every row gets no row constraint"
    )
    min_detections: int = Field(
        3, ge=1, description="frames an object is seen in before it may join a row"
    )
    angle_prior_sigma_deg: float = Field(
        1.0, ge=0.0, description="std of a given row_angle_deg as a prior; 0 fixes the angle"
    )


class MaintenanceConfig(_Strict):
    """Merging and pruning (sec. 2.6.3)."""

    merge: bool = True
    prune: bool = True
    prune_max_meas: int = Field(2, ge=0, description="objects seen at most this often may go")
    prune_min_interest: float = Field(
        0.4,
        ge=0.0,
        le=1.0,
        description="h at or above which a rarely seen object goes; one seen once always "
        "has h >= 0.5 (eq. 2), so 0.4 prunes stray one-off detections and pairs that agree "
        "poorly (measured on the default simulation: 0.6 left 1 % false objects)",
    )
    prune_grace_s: float = Field(20.0, ge=0.0, description="s unseen before pruning")
    existence: bool = Field(
        True,
        description="a new object is tentative until the frames that had it in view confirm "
        "it (detected in enough of them, with the detection and stray rates learned from the "
        "survey: maintenance.Existence); until then its detections' factors get "
        "association.d_inter of isotropic noise added, so clutter cannot pull the poses, and "
        "it joins no row; it is dropped once they say it is not there, or at the end of the "
        "survey if it is more likely not there than there: not in the paper (it replaces "
        "association.weak_tentative)",
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


class OutputsConfig(_Strict):
    """Map files for the farm (issue 13); the weeds prescription of ISOXML and shapefile."""

    formats: list[Literal["geojson", "gpkg", "isoxml", "shapefile"]] | None = Field(
        None, description="georeferenced map files; None: geojson and gpkg when anchored"
    )
    weed_attribute: str = Field("type", description="the attribute that tells weeds")
    weed_value: str = Field("weed", description="its value for a weed")
    weed_min_p: float = Field(0.5, ge=0.0, le=1.0, description="least p to treat a plant")
    rate_l_ha: float = Field(200.0, gt=0.0, description="spray rate on a weed, l/ha")
    cell_m: float = Field(0.25, gt=0.0, le=100.0, description="ISOXML grid cell size, m")


class CheckpointConfig(_Strict):
    """Checkpoints of a run in its map.sqlite, for `agrislam run --resume`."""

    every_frames: int = Field(
        1000,
        ge=0,
        description="frames between checkpoints at least (0 = none); a checkpoint rebuilds the "
        "back end's iSAM2 from its saved state, so the interval is part of the run's config "
        "and a resumed run ends with the same map as one never stopped",
    )
    frames_per_mb: float = Field(
        250.0,
        ge=0.0,
        description="and at least this many frames per MB of the saved state: saving "
        "grows with the map, so checkpoints grow apart and keep costing the same share of "
        "the run (250: about 2 %)",
    )


class AgrislamConfig(_Strict):
    """Root configuration of a run; every value has a default (`agrislam config --defaults`)."""

    schema_: FieldSchema | str | None = Field(
        None,
        alias="schema",
        description="a FieldSchema, a preset name, or none (take it from the log's meta)",
    )
    semantics: SemanticsConfig = Field(default_factory=SemanticsConfig)
    sensor: SensorDefaults = Field(default_factory=SensorDefaults)
    association: AssociationConfig = Field(default_factory=AssociationConfig)
    slam: SlamConfig = Field(default_factory=SlamConfig)
    rows: RowsConfig = Field(default_factory=RowsConfig)
    maintenance: MaintenanceConfig = Field(default_factory=MaintenanceConfig)
    gnss: GnssConfig = Field(default_factory=GnssConfig)
    outputs: OutputsConfig = Field(default_factory=OutputsConfig)
    checkpoint: CheckpointConfig = Field(default_factory=CheckpointConfig)
    season: SeasonConfig = Field(default_factory=SeasonConfig)
    label_map: dict[str, dict[str, str]] = Field(
        default_factory=dict,
        description="combined detector label -> attribute values, e.g. "
        "{'crop_small_healthy': {'type': 'crop', 'size': 'small', 'health': 'healthy'}}",
    )

    model_config = ConfigDict(
        extra="forbid", validate_assignment=True, populate_by_name=True, allow_inf_nan=False
    )

    def field_schema(self) -> FieldSchema | None:
        if isinstance(self.schema_, str):
            return FieldSchema.preset(self.schema_)
        return self.schema_

    @classmethod
    def load(cls, path: str | Path) -> AgrislamConfig:
        return cls.model_validate(load_mapping(path))


def load_mapping(path: str | Path) -> dict[str, Any]:
    """Read a YAML, TOML or JSON file into a dict, choosing the parser by extension."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    suffix = path.suffix.lower()
    parsers = {".toml": tomllib.loads, ".json": json.loads, ".yaml": yaml.safe_load}
    parse = parsers.get(".yaml" if suffix == ".yml" else suffix)
    if parse is None:
        raise ValueError(f"{path}: unknown config format {suffix!r} (use .yaml, .toml or .json)")
    try:
        data = parse(text)
    except (ValueError, yaml.YAMLError) as err:  # TOML and JSON errors are ValueErrors
        where = getattr(err, "problem_mark", None)
        at = f" at line {where.line + 1}, column {where.column + 1}" if where else ""
        what = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ValueError(f"{path}: not valid {suffix[1:].upper()}{at}: {what}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping at the top level")
    return data
