"""Configuration as pydantic models: the field schema, the sections a user sets, the
`advanced` knobs, and the effective settings of one survey that the stages are built from.
`AgrislamConfig` is the root."""

from agrislam.config.advanced import (
    AdvancedConfig,
    CalibrationConfig,
    MaintenanceConfig,
    SemanticsConfig,
)
from agrislam.config.effective import (
    AssociationConfig,
    RowsConfig,
    SensorDefaults,
    Settings,
    SlamConfig,
    effective,
)
from agrislam.config.gnss import GnssConfig
from agrislam.config.limits import InputLimits
from agrislam.config.loading import load_mapping
from agrislam.config.root import AgrislamConfig
from agrislam.config.schema import (
    COLOURS,
    HEALTH,
    LENGTH_RANGE,
    SCHEMA_PRESETS,
    SECONDS_PER_DAY,
    SIZES,
    Attribute,
    ContinuousAttribute,
    DiscreteAttribute,
    FieldSchema,
    GrowthModel,
)
from agrislam.config.season import SeasonConfig
from agrislam.config.sections import CheckpointConfig, OutputsConfig

__all__ = [
    "COLOURS",
    "HEALTH",
    "LENGTH_RANGE",
    "SCHEMA_PRESETS",
    "SECONDS_PER_DAY",
    "SIZES",
    "AdvancedConfig",
    "AgrislamConfig",
    "AssociationConfig",
    "Attribute",
    "CalibrationConfig",
    "CheckpointConfig",
    "ContinuousAttribute",
    "DiscreteAttribute",
    "FieldSchema",
    "GnssConfig",
    "GrowthModel",
    "InputLimits",
    "MaintenanceConfig",
    "OutputsConfig",
    "RowsConfig",
    "SeasonConfig",
    "SemanticsConfig",
    "SensorDefaults",
    "Settings",
    "SlamConfig",
    "effective",
    "load_mapping",
]
