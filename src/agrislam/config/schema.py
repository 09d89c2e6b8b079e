"""The field schema (sec. 2.1): which semantic attributes every plant of a map carries,
discrete or continuous, with their priors and time models (App. B); and the paper's
attribute tables as presets."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field, model_validator

from agrislam.config.limits import StrictModel as _Strict
from agrislam.config.limits import first_error
from agrislam.config.loading import load_mapping

SECONDS_PER_DAY = 86_400.0


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
