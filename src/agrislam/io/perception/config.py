"""Parameters of the RGB-D front end (sec. 2.3, App. A, sec. 3.1.2)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from agrislam.config import AgrislamConfig


class PerceptionConfig(BaseModel):
    """How a 2D detection plus depth becomes an object position, covariance and length."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    max_range: float = Field(
        2.5, gt=0.0, description="m from the camera; farther is dropped (App. A)"
    )
    min_depth: float = Field(0.05, ge=0.0, description="m; smaller depth values are invalid")
    depth_scale: float = Field(
        0.001, gt=0.0, description="m per unit of an integer (16UC1) depth image"
    )
    min_pixels: int = Field(5, ge=1, description="valid depth pixels needed for a position")
    outlier_mad: float = Field(
        3.0, gt=0.0, description="keep depths within this many robust sigmas (MAD) of the median"
    )
    outlier_band: float = Field(
        0.03, ge=0.0, description="m; the keep band is never narrower than this"
    )
    box_core: float = Field(
        0.5, gt=0.0, le=1.0, description="fraction of a box (per side) used when there is no mask"
    )
    green_filter: bool = Field(False, description="intersect the mask with green pixels (sec. 2.3)")
    green_threshold: float = Field(
        0.05, description="excess green 2g - r - b (chromaticity) above which a pixel is green"
    )
    sigma_depth: float = Field(0.10, gt=0.0, description="m, along the viewing ray")
    sigma_lateral: float = Field(0.03, gt=0.0, description="m, across the viewing ray")
    length_attribute: str | None = Field(
        None, description="continuous attribute filled from the box size (sec. 3.1.2)"
    )
    length_axis: Literal["height", "width", "max"] = "height"
    length_sigma_at_1m: float = Field(
        0.05, gt=0.0, description="m; length std at 1 m, growing linearly with distance"
    )

    @model_validator(mode="after")
    def _depth_over_lateral(self) -> PerceptionConfig:
        # sec. 2.6: the range to the object is less certain than the direction to it
        if self.sigma_depth < self.sigma_lateral:
            raise ValueError(
                f"sigma_depth ({self.sigma_depth}) must not be below sigma_lateral "
                f"({self.sigma_lateral}): depth is the less certain direction (sec. 2.6)"
            )
        return self

    @classmethod
    def from_config(cls, config: AgrislamConfig, **overrides: Any) -> PerceptionConfig:
        """Range cut-off and detection sigmas from the run's sensor defaults."""
        sensor = config.sensor
        values: dict[str, Any] = {
            "max_range": sensor.max_range,
            "sigma_depth": sensor.detection_sigma_depth,
            "sigma_lateral": sensor.detection_sigma_lateral,
        }
        values.update(overrides)
        return cls(**values)
