"""Combined detector labels split into attribute values (App. A: the paper's detector was
trained on combined classes such as ``plant_small_healthy``): one measurement per attribute
with the detector's score as its p, from the config's ``label_map`` or the schema's values."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from agrislam.config import FieldSchema
from agrislam.records import Detection, DiscreteMeasurement, Measurement


class UnknownLabelError(ValueError):
    """A label the map cannot split."""


class LabelMap:
    def __init__(
        self,
        mapping: Mapping[str, Mapping[str, str]] | None = None,
        schema: FieldSchema | None = None,
        separator: str = "_",
    ) -> None:
        self.schema = schema
        self.separator = separator
        self._explicit = {label: dict(values) for label, values in (mapping or {}).items()}
        self._value_owner = _value_owners(schema) if schema is not None else {}
        for label, values in self._explicit.items():
            self._check(label, values)
        self._cache: dict[str, dict[str, str]] = dict(self._explicit)

    @classmethod
    def from_config(
        cls,
        mapping: Mapping[str, Mapping[str, str]] | None,
        schema: FieldSchema | None = None,
        separator: str = "_",
    ) -> LabelMap:
        """From `AgrislamConfig.label_map` (label -> {attribute: value}) and the schema."""
        return cls(mapping, schema, separator)

    def __bool__(self) -> bool:
        """Whether the map can split anything at all."""
        return bool(self._explicit) or bool(self._value_owner)

    def split(self, label: str) -> dict[str, str]:
        """The attribute values a combined label stands for."""
        if label in self._cache:
            return self._cache[label]
        if not self._value_owner:
            raise UnknownLabelError(f"label {label!r} is not in the label map")
        values: dict[str, str] = {}
        for part in label.split(self.separator):
            owners = self._value_owner.get(part, [])
            if len(owners) != 1:
                why = "no attribute has" if not owners else f"attributes {owners} all have"
                raise UnknownLabelError(
                    f"label {label!r}: {why} the value {part!r}; add the label to label_map"
                )
            if owners[0] in values:
                raise UnknownLabelError(
                    f"label {label!r}: two values ({values[owners[0]]!r}, {part!r}) "
                    f"for attribute {owners[0]!r}"
                )
            values[owners[0]] = part
        self._cache[label] = values
        return values

    def measurements(self, label: str, p: float) -> dict[str, Measurement]:
        """One discrete measurement per attribute of the label, each with probability p."""
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"label {label!r}: score {p} is not a probability in [0, 1]")
        return {name: DiscreteMeasurement(value, p) for name, value in self.split(label).items()}

    def apply(self, detection: Detection) -> Detection:
        """The detection with its combined label replaced by attribute measurements; an attribute
        it carries already keeps its own (a dedicated measurement beats a combined class)."""
        if detection.label is None:
            return detection
        if detection.label_p is None:
            raise ValueError(f"label {detection.label!r} has no score (label_p)")
        attributes = self.measurements(detection.label, detection.label_p)
        attributes.update(detection.attributes)
        return dataclasses.replace(detection, attributes=attributes, label=None, label_p=None)

    def _check(self, label: str, values: dict[str, str]) -> None:
        if self.schema is None:
            return
        for name, value in values.items():
            spec = self.schema.discrete.get(name)
            if spec is None:
                raise ValueError(
                    f"label_map {label!r}: {name!r} is not a discrete attribute of the schema"
                )
            if value not in spec.values:
                raise ValueError(
                    f"label_map {label!r}: value {value!r} is not one of {name!r} {spec.values}"
                )


def _value_owners(schema: FieldSchema) -> dict[str, list[str]]:
    """value -> the discrete attributes that have it."""
    owners: dict[str, list[str]] = {}
    for name, spec in schema.discrete.items():
        for value in spec.values:
            owners.setdefault(value, []).append(name)
    return owners
