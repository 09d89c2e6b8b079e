"""The root of a run's configuration: the fields a user sets, by section, and `advanced`
for the rest. `effective` (config/effective.py) turns it into what each stage takes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import ConfigDict, Field, model_validator

from agrislam.config.advanced import AdvancedConfig
from agrislam.config.gnss import GnssSection
from agrislam.config.legacy import moved_to_advanced
from agrislam.config.limits import StrictModel
from agrislam.config.live import LiveSection
from agrislam.config.loading import load_mapping
from agrislam.config.schema import FieldSchema
from agrislam.config.sections import (
    AssociationSection,
    CheckpointConfig,
    OutputsConfig,
    RowsSection,
    SensorSection,
    SlamSection,
)


class AgrislamConfig(StrictModel):
    """Root configuration of a run; every value has a default (`agrislam config --defaults`
    prints the user's fields, `--all` every one)."""

    schema_: FieldSchema | str | None = Field(
        None,
        alias="schema",
        description="a FieldSchema, a preset name, or none (take it from the log's meta)",
    )
    label_map: dict[str, dict[str, str]] = Field(
        default_factory=dict,
        description="combined detector label -> attribute values, e.g. "
        "{'crop_small_healthy': {'type': 'crop', 'size': 'small', 'health': 'healthy'}}",
    )
    sensor: SensorSection = Field(default_factory=SensorSection)
    association: AssociationSection = Field(default_factory=AssociationSection)
    rows: RowsSection = Field(default_factory=RowsSection)
    slam: SlamSection = Field(default_factory=SlamSection)
    gnss: GnssSection = Field(default_factory=GnssSection)
    outputs: OutputsConfig = Field(default_factory=OutputsConfig)
    checkpoint: CheckpointConfig = Field(default_factory=CheckpointConfig)
    live: LiveSection = Field(default_factory=LiveSection)
    advanced: AdvancedConfig = Field(default_factory=AdvancedConfig)

    model_config = ConfigDict(
        extra="forbid", validate_assignment=True, populate_by_name=True, allow_inf_nan=False
    )

    @model_validator(mode="before")
    @classmethod
    def _older_layout(cls, data: Any) -> Any:
        """Keys of the layout before `advanced:` are read from their old place, with a
        warning naming the new one."""
        main = {
            name: info.annotation
            for name, info in cls.model_fields.items()
            if name in AdvancedConfig.model_fields
        }
        advanced = {name: info.annotation for name, info in AdvancedConfig.model_fields.items()}
        return moved_to_advanced(data, main, advanced)

    def field_schema(self) -> FieldSchema | None:
        if isinstance(self.schema_, str):
            return FieldSchema.preset(self.schema_)
        return self.schema_

    @classmethod
    def load(cls, path: str | Path) -> AgrislamConfig:
        return cls.model_validate(load_mapping(path))
