"""The effective configuration of one survey: every section as its stage takes it (the
user's fields and the advanced ones together), with each choice the config leaves to the
survey made from what the survey says of its field. One pure function, `effective`.

A survey with a field prior (plant and row spacing in its meta) is the crop field the
paper's defaults are for. One without is mapped as point landmarks, unless
`advanced.association.landmark_defaults` is off: gated on the whole innovation at
`landmark_gate_chi2` over `landmark_sigma_max`, `d_inter` three times the first detections'
median sharpest sigma (nearer, a detection cannot tell two apart), no rows, no confirmation
of young objects, and the association's safeguards on (rejoin, loop closure, range
outliers). Every value the config sets is kept.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

from pydantic import Field

from agrislam.config.advanced import (
    AdvancedAssociation,
    AdvancedRows,
    AdvancedSensor,
    AdvancedSlam,
    MaintenanceConfig,
    SemanticsConfig,
)
from agrislam.config.gnss import GnssConfig
from agrislam.config.limits import StrictModel
from agrislam.config.season import SeasonConfig
from agrislam.config.sections import AssociationSection, RowsSection, SensorSection, SlamSection

if TYPE_CHECKING:
    from agrislam.config.root import AgrislamConfig

# the paper's gate (sec. 2.4): a one-sigma Mahalanobis term over the object's covariance
PAPER_GATE_CHI2 = 1.0
PAPER_SIGMA_MAX = 1.0  # m, the largest object sigma the spatial gate allows for
DEFAULT_D_INTER = 0.2  # m, without a field prior or detections to take it from


class FieldKnowledge(Protocol):
    """What a survey's meta says of its field (records.FieldPrior)."""

    row_spacing: float | None
    min_plant_distance: float | None
    row_angle_deg: float | None


class SensorDefaults(SensorSection, AdvancedSensor):
    """The sensor model as the front end and the noise calibration take it."""


class AssociationConfig(AssociationSection, AdvancedAssociation):
    """The association as the associator takes it: every choice made."""

    d_inter: float | None = Field(  # type: ignore[assignment]
        DEFAULT_D_INTER,
        gt=0.0,
        description="m, the distance scale of sec. 2.4; none: estimated from the survey's "
        "first detections (estimation/point_spacing.py)",
    )
    innovation_gate: bool = False  # type: ignore[assignment]
    gate_chi2: float = Field(PAPER_GATE_CHI2, gt=0.0)  # type: ignore[assignment]
    gate_sigma_max: float = Field(PAPER_SIGMA_MAX, gt=0.0)  # type: ignore[assignment]


class SlamConfig(SlamSection, AdvancedSlam):
    """The graph back end as it is built (backend/)."""


class RowsConfig(RowsSection, AdvancedRows):
    """The rows as the row tracker fits them."""

    enabled: bool = True  # type: ignore[assignment]
    give_way_to_gnss: bool = Field(
        False, description="no rows once GNSS fixes arrive before the first row fit"
    )


class Settings(StrictModel):
    """A survey's configuration with every choice made: what the world model's stages are
    built from (`effective`)."""

    landmarks: bool = Field(False, description="mapped as point landmarks (no field prior)")
    semantics: SemanticsConfig = Field(default_factory=SemanticsConfig)
    sensor: SensorDefaults = Field(default_factory=SensorDefaults)
    association: AssociationConfig = Field(default_factory=AssociationConfig)
    slam: SlamConfig = Field(default_factory=SlamConfig)
    rows: RowsConfig = Field(default_factory=RowsConfig)
    maintenance: MaintenanceConfig = Field(default_factory=MaintenanceConfig)
    gnss: GnssConfig = Field(default_factory=GnssConfig)
    season: SeasonConfig = Field(default_factory=SeasonConfig)


def effective(config: AgrislamConfig, field: FieldKnowledge | None) -> Settings:
    """The settings of a survey whose meta says `field` of its field (None: nothing)."""
    advanced, gate = config.advanced, config.advanced.association
    landmarks = field is None and gate.landmark_defaults
    d_inter = _d_inter(config.association.d_inter, field, landmarks)
    association = {
        **config.association.model_dump(),
        **gate.model_dump(),
        "d_inter": d_inter,
        "innovation_gate": _chosen(gate.innovation_gate, landmarks),
        "gate_chi2": _chosen(
            gate.gate_chi2, gate.landmark_gate_chi2 if landmarks else PAPER_GATE_CHI2
        ),
        "gate_sigma_max": _chosen(
            gate.gate_sigma_max, gate.landmark_sigma_max if landmarks else PAPER_SIGMA_MAX
        ),
    }
    maintenance = advanced.maintenance.model_dump()
    maintenance["existence"] = _chosen(advanced.maintenance.existence, not landmarks)
    return Settings(
        landmarks=landmarks,
        semantics=advanced.semantics,
        sensor=SensorDefaults(**config.sensor.model_dump(), **advanced.sensor.model_dump()),
        association=AssociationConfig(**association),
        slam=SlamConfig(**config.slam.model_dump(), **advanced.slam.model_dump()),
        rows=_rows(config.rows, advanced.rows, field, landmarks),
        maintenance=MaintenanceConfig(**maintenance),
        gnss=GnssConfig(**config.gnss.model_dump(), **advanced.gnss.model_dump()),
        season=advanced.season,
    )


def _d_inter(
    configured: float | None, field: FieldKnowledge | None, landmarks: bool
) -> float | None:
    """The configured d_inter; else half the field prior's plant spacing (a detection
    nearer than that is this plant, not its neighbour); else, for landmarks, None: three of
    the first detections' sharpest sigmas (estimation/point_spacing.py)."""
    spacing = field.min_plant_distance if field is not None else None
    if configured is not None:
        return configured
    if spacing is not None and spacing > 0.0:
        return 0.5 * spacing
    return None if landmarks else DEFAULT_D_INTER


def _chosen(configured: object, otherwise: object) -> object:
    """The configured value if the config sets one, else the survey's choice."""
    return otherwise if configured is None else configured


def _rows(
    rows: RowsSection, advanced: AdvancedRows, field: FieldKnowledge | None, landmarks: bool
) -> RowsConfig:
    """Rows unless mapped as landmarks, at the field prior's spacing and angle (a configured
    angle first); left to the survey, they give way to GNSS fixes."""
    spacing, angle = rows.row_spacing, rows.row_angle_deg
    if field is not None:
        spacing = spacing if field.row_spacing is None else float(field.row_spacing)
        angle = _chosen(angle, field.row_angle_deg)
    return RowsConfig(
        **advanced.model_dump(),
        enabled=_chosen(rows.enabled, not landmarks),
        row_spacing=spacing,
        row_angle_deg=angle,
        give_way_to_gnss=rows.enabled is None,
    )
