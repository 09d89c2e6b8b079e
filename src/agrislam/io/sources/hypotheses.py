"""vision_msgs hypotheses in any layout (4.x ``hypothesis.class_id``, Foxy/Noetic ``id``) as
agrislam measurements: ``attr=value`` class ids (ros.conventions) are attribute
measurements, any other class id is a combined detector label, the best-scoring one wins."""

from __future__ import annotations

import math
from typing import Any

from agrislam.io.ros.conventions import is_measurement_class_id, measurement_of_class_id
from agrislam.io.sources.bag_report import SkipError
from agrislam.records import Measurement


def hypotheses(results: Any) -> list[tuple[str, float, Any]]:
    """(class_id, score, PoseWithCovariance) of vision_msgs results in either layout:
    4.x ``hypothesis.class_id`` or Foxy/Noetic ``id`` (string or int64)."""
    out = []
    for r in results:
        h = getattr(r, "hypothesis", r)
        class_id = h.class_id if hasattr(h, "class_id") else str(h.id)
        out.append((class_id, float(h.score), r.pose))
    return out


def parse_hypotheses(
    hyps: list[tuple[str, float]], class_names: dict[str, str]
) -> tuple[dict[str, Measurement], str | None, float | None]:
    """Attributes (best score per attribute) and the best combined label of hypotheses."""
    attributes: dict[str, Measurement] = {}
    best: dict[str, float] = {}
    label, label_p = None, None
    for class_id, score in hyps:
        class_id = class_names.get(class_id, class_id)
        if not is_measurement_class_id(class_id):
            if label is None or (not math.isnan(score) and score > (label_p or -1.0)):
                label, label_p = class_id, (None if math.isnan(score) else score)
            continue
        try:
            name, m = measurement_of_class_id(class_id, score)
        except ValueError as err:
            raise SkipError("bad_hypothesis", str(err)) from None
        if score > best.get(name, -1.0):
            attributes[name], best[name] = m, score
    return attributes, label, label_p
