"""The sections of a configuration a user sets: the sensors' noise, the association's weight
and distance (sec. 2.4), the rows (sec. 2.6.2), the back end, the GNSS antenna, the farm's
map files and checkpoints. Every other knob is in `advanced:` (config/advanced.py)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, PositiveFloat

from agrislam.config.limits import StrictModel


class SensorSection(StrictModel):
    """What a detection and an odometry increment are worth when a record does not say."""

    detection_sigma_depth: float = Field(0.10, gt=0.0, description="m, along the viewing ray")
    detection_sigma_lateral: float = Field(0.03, gt=0.0, description="m, across the ray")
    odom_sigma_scale: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = Field(
        (1.0, 1.0, 1.0),
        description="factors on every odometry sigma (x, y, heading), the record's or the "
        "default: for wheel odometry whose stated covariance is overconfident",
    )
    max_range: float = Field(
        2.5, gt=0.0, description="detections farther away are dropped (App. A)"
    )


class AssociationSection(StrictModel):
    """Data association (sec. 2.4)."""

    w_sem: float = Field(0.3, ge=0.0, le=1.0, description="semantic weight w_sem")
    d_inter: float | None = Field(
        None,
        gt=0.0,
        description="m, the distance scale of sec. 2.4 and the merge distance of sec. 2.6.3; "
        "none: half the field prior's minimum plant distance, else three times the first "
        "detections' median sharpest sigma when mapped as landmarks, else 0.2",
    )


class RowsSection(StrictModel):
    """Row prior knowledge (sec. 2.6.2)."""

    enabled: bool | None = Field(
        None,
        description="none: rows are fitted unless the survey is mapped as landmarks (no field "
        "prior), or GNSS fixes hold the map before the first row fit",
    )
    row_spacing: float = Field(1.0, gt=0.0, description="m between neighbouring rows")
    row_angle_deg: float | None = Field(None, description="known row direction, if any")


class SlamSection(StrictModel):
    """The graph back end (sec. 2.6)."""

    backend: Literal["incremental", "batch"] = Field(
        "incremental",
        description="incremental: iSAM2 with keyframes, a step's cost bounded on any field; "
        "batch: the paper's whole-graph solve every step (the baseline)",
    )
    robust_kernel: Literal["huber", "cauchy", "none"] = Field(
        "huber", description="the kernel on detection factors"
    )


class OutputsConfig(StrictModel):
    """Map files for the farm; the weeds prescription of ISOXML and shapefile."""

    formats: list[Literal["geojson", "gpkg", "isoxml", "shapefile"]] | None = Field(
        None, description="georeferenced map files; none: geojson and gpkg when anchored"
    )
    weed_attribute: str = Field("type", description="the attribute that tells weeds")
    weed_value: str = Field("weed", description="its value for a weed")
    weed_min_p: float = Field(0.5, ge=0.0, le=1.0, description="least p to treat a plant")
    rate_l_ha: float = Field(200.0, gt=0.0, description="spray rate on a weed, l/ha")
    cell_m: float = Field(0.25, gt=0.0, le=100.0, description="ISOXML grid cell size, m")


class CheckpointConfig(StrictModel):
    """Checkpoints of a run in its map.sqlite, for `agrislam run --resume`."""

    every_frames: int = Field(
        1000,
        ge=0,
        description="frames between checkpoints at least (0 = none); a checkpoint rebuilds the "
        "back end's iSAM2 from its saved state, so the interval is part of the run's config "
        "and a resumed run ends with the same map as one never stopped",
    )
