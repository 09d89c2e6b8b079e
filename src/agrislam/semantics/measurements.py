"""Which of a detection's semantic measurements carry information (sec. 2.3)."""

from __future__ import annotations

from collections.abc import Mapping

from agrislam.config import FieldSchema
from agrislam.records import DiscreteMeasurement, Measurement


def informative_measurements(
    schema: FieldSchema | None, measurements: Mapping[str, Measurement]
) -> dict[str, Measurement]:
    """The measured attributes Y of a detection: a discrete one with p < 1/n carries no
    information (sec. 2.3) and takes no part in association either."""
    if schema is None:
        return {}
    kept: dict[str, Measurement] = {}
    for name, m in measurements.items():
        spec = schema.attributes.get(name)
        if spec is None:
            continue
        if isinstance(m, DiscreteMeasurement) and m.p < 1.0 / len(spec.values):  # type: ignore[union-attr]
            continue
        kept[name] = m
    return kept
