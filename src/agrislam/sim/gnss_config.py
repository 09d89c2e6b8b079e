"""Configuration of what the simulator adds for georeferenced surveys: a GNSS receiver with
fix types, outages and multipath jumps, and odometry drift over distance: the yaw-rate bias
calibrated on the 400-plant survey relaxes over a long one."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class DistanceDrift(_Strict):
    """The odometry's yaw-rate bias over distance: it starts at the calibrated
    `heading_bias` (random sign) and relaxes towards a smaller random one over
    `bias_length` metres (an Ornstein-Uhlenbeck process in distance), so a long survey's
    heading error grows like a random walk instead of without bound; and a distance scale
    error per robot (wheel radius). `bias_length = 0`: the calibrated bias stays constant."""

    bias_length: float = Field(
        600.0,
        ge=0.0,
        description="m over which the yaw-rate bias decorrelates; the 400-plant survey "
        "drives 184 m, so it keeps most of its calibrated bias",
    )
    bias_spread: float = Field(
        1.0e-4, ge=0.0, description="rad/s, the std the bias relaxes to (0.34 deg/min)"
    )
    scale_sigma: float = Field(
        0.003, ge=0.0, description="std of the distance scale error per robot (0.3 %)"
    )


class GnssSimConfig(_Strict):
    """A GNSS receiver on the robot. Sigmas are horizontal, per axis; the receiver reports
    them truthfully except in a multipath jump."""

    rate_hz: float = Field(1.0, gt=0.0, description="fixes per second (at odometry times)")
    antenna: tuple[float, float, float] = Field(
        (0.3, 0.0, 1.0), description="m, antenna in the robot frame (ahead of the base, up)"
    )
    sigma: dict[str, float] = Field(
        default_factory=lambda: {
            "rtk_fixed": 0.02,
            "rtk_float": 0.3,
            "dgps": 0.7,
            "single": 2.0,
        },
        description="m, horizontal std of each fix type",
    )
    fraction: dict[str, float] = Field(
        default_factory=lambda: {"rtk_fixed": 0.9, "rtk_float": 0.1},
        description="share of fixes of each type outside outages, in runs of `run_s`",
    )
    run_s: float = Field(30.0, gt=0.0, description="s a fix type lasts before it may change")
    outage_fraction: float = Field(
        0.0, ge=0.0, lt=1.0, description="share of the survey without any fix"
    )
    outage_s: float = Field(180.0, gt=0.0, description="s each outage lasts (minutes)")
    multipath_fraction: float = Field(
        0.0, ge=0.0, le=1.0, description="share of fixes thrown off by multipath"
    )
    multipath_m: tuple[float, float] = Field(
        (2.0, 8.0), description="m, range of a multipath jump's size (reported as before)"
    )

    @model_validator(mode="after")
    def _known_types(self) -> GnssSimConfig:
        unknown = set(self.fraction) - set(self.sigma)
        if unknown:
            raise ValueError(f"fraction names fix types without a sigma: {sorted(unknown)}")
        if sum(self.fraction.values()) <= 0.0:
            raise ValueError("fraction: at least one fix type needs a share > 0")
        return self
