"""GNSS fixes as factors on the robot pose (estimation/gnss.py): the antenna a user sets,
the weights and gates in `advanced.gnss`, and both together as the estimator takes them."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, PositiveFloat

from agrislam.config.limits import StrictModel as _Strict

# a fix's type, as records.FIX_TYPES names them (the config imports no records)
FixType = Literal["none", "single", "dgps", "rtk_float", "rtk_fixed"]


class GnssSection(_Strict):
    """Where the GNSS antenna sits on the robot."""

    antenna: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="m, antenna in the robot frame when a fix does not say"
    )


class AdvancedGnss(_Strict):
    """How fixes are weighted and gated."""

    enabled: bool = True
    # sigma floor per fix type (m, horizontal): a receiver's covariance is trusted no lower
    fix_sigma: dict[FixType, PositiveFloat] = Field(
        default_factory=lambda: {"rtk_fixed": 0.01, "rtk_float": 0.2, "dgps": 0.5, "single": 1.5},
        description="m, the least horizontal sigma each fix type is taken with; a type not "
        "named here (none) is never used",
    )
    robust_kernel: Literal["huber", "cauchy", "none"] = "cauchy"
    robust_k: float = Field(
        2.0,
        gt=0.0,
        description="kernel width in standard deviations of the fix's innovation (its own "
        "noise, the predicted pose's and any drift the gate found), so a fix that pulls a "
        "pose the odometry let wander is not taken for an outlier",
    )
    gate_chi2: float = Field(
        18.42,
        ge=0.0,
        description="a fix farther from the predicted antenna than this squared Mahalanobis "
        "distance (2 dof, 18.42 = p 1e-4) is rejected; 0 = no gate",
    )
    gate_consistent: int = Field(
        3,
        ge=0,
        description="this many fixes in a row beyond the gate that agree with each other "
        "(each one's offset from the predicted antenna within its own and the previous "
        "one's noise and the odometry's between them) say the pose drifted, not the fixes: "
        "the last is taken and the gate widened by the offset until a fix passes it again; "
        "0 = never (a multipath jump is a lone fix, it agrees with no other)",
    )
    gate_reacquire: int = Field(
        10, ge=0, description="after this many fixes in a row beyond the gate, take the next"
    )
    drift_floor: float = Field(
        5.0,
        ge=0.0,
        description="m: the farthest fixes beyond the gate (taken as agreeing, or on "
        "reacquiring) may put a robot from where its start pose or its last fix taken held "
        "it, before it drives (a start marker's, an anchor's error)...",
    )
    drift_per_m: float = Field(
        0.1,
        ge=0.0,
        description="...and farther by this per metre driven since: odometry drifts a few "
        "per cent of the distance; fixes farther off are wrong, not the pose",
    )
    reject_whole_after: int = Field(
        20,
        ge=1,
        description="a robot whose fixes were refused this many times, and four times as "
        "often as taken, has its GNSS rejected as a whole: the map stays the odometry's and "
        "the plants'",
    )


class GnssConfig(GnssSection, AdvancedGnss):
    """Both parts, as the GNSS estimator is configured."""
