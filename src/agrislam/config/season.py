"""The settings of a survey that continues a saved map (`advanced.season`)."""

from __future__ import annotations

from pydantic import Field, PositiveFloat

from agrislam.config.limits import StrictModel as _Strict


class SeasonConfig(_Strict):
    """A survey that continues a saved map: re-localisation in it and the
    changes found against it."""

    cluster_radius: float = Field(
        0.12, gt=0.0, description="m: detections of the first frames closer than this are one plant"
    )
    inlier_radius: float = Field(
        0.1, gt=0.0, description="m: a first-frames plant this near a saved one matches it"
    )
    score_sigma: float = Field(
        0.04,
        gt=0.0,
        description="m: the Gaussian kernel a match scores with (plant spacing "
        "jitter is a few cm, so a hypothesis shifted by one plant scores far lower)",
    )
    min_landmarks: int = Field(12, ge=3, description="first-frames plants before a first try")
    min_inlier_fraction: float = Field(
        0.6, gt=0.0, le=1.0, description="share of the first-frames plants the map must explain"
    )
    newcomer_inlier_fraction: float = Field(
        0.4,
        gt=0.0,
        le=1.0,
        description="the same for a robot without a start pose placed in the map being built: "
        "less, as that map may not yet reach all its first frames saw",
    )
    max_ambiguity: float = Field(
        0.7,
        gt=0.0,
        lt=1.0,
        description="refuse when the second-best distinct hypothesis scores above this share "
        "of the best (periodic rows)",
    )
    attempt_every_s: float = Field(1.0, gt=0.0, description="s of driving between two tries")
    window_s: float = Field(
        10.0,
        gt=0.0,
        description="s of the latest frames a try registers: dead reckoning drifts (most in "
        "a headland turn), so a longer stretch no longer fits one rigid transform",
    )
    give_up_after_s: float = Field(
        300.0, gt=0.0, description="s of driving without a fix: map the survey as a new field"
    )
    start_tolerance: tuple[PositiveFloat, PositiveFloat] = Field(
        (0.5, 0.2), description="(m, rad) a given start pose may differ from the fix"
    )
    gone_prior: float = Field(
        0.5, gt=0.0, lt=1.0, description="P(gone) of a plant before it is looked for"
    )
    stray_rate: float = Field(
        0.05,
        gt=0.0,
        lt=0.5,
        description="chance per frame in view that a detection of something else is "
        "associated to a plant that is not there (clutter, a neighbour)",
    )
    gone_threshold: float = Field(
        0.95, gt=0.5, lt=1.0, description="P(gone) from which a plant is marked gone"
    )
    view_margin: float = Field(
        0.2,
        ge=0.0,
        description="m a plant must be inside the far edge and the sides of the camera's "
        "seen area to count as looked at (the near edge has none: the detection rate is "
        "highest there)",
    )
