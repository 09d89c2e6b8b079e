"""How agrislam's records sit in ROS messages, one convention for the bag sink that writes
them and the bag source that reads them back: the topics of meta and ground truth, the
x/y/yaw block of a pose covariance, and attribute measurements as vision_msgs class ids
(``attr=value`` with p as the score, ``attr=value;var=v`` for a continuous one)."""

from __future__ import annotations

import re

import numpy as np

from agrislam.records import ContinuousMeasurement, DiscreteMeasurement, Measurement

META_TOPIC = "/agrislam/meta"
TRUTH_TOPIC = "/agrislam/truth"
UNKNOWN_COVARIANCE = -1.0  # covariance[0] of a pose whose covariance is not known (ROS)
POSE_COV_INDEX = np.array([0, 1, 5])  # x, y, yaw in a row-major 6x6 pose covariance
_CONTINUOUS = re.compile(r"^(?P<name>[^=;]+)=(?P<value>[^;]+);var=(?P<var>.+)$")


def measurement_class_id(name: str, m: Measurement) -> tuple[str, float]:
    """(class_id, score) of one attribute measurement: ``attr=value`` with p, or
    ``attr=value;var=v`` with score 1 for a continuous one."""
    if "=" in name or ";" in name:
        raise ValueError(f"attribute name {name!r} cannot be written as a class_id ('=', ';')")
    if isinstance(m, DiscreteMeasurement):
        return f"{name}={m.value}", float(m.p)
    return f"{name}={float(m.value)!r};var={float(m.var)!r}", 1.0


def is_measurement_class_id(class_id: str) -> bool:
    """Whether a class_id names an attribute measurement (else it is a detector label)."""
    return "=" in class_id


def measurement_of_class_id(class_id: str, score: float) -> tuple[str, Measurement]:
    """(attribute, measurement) of an ``attr=value`` or ``attr=value;var=v`` class_id;
    ValueError when its numbers or its score cannot be one."""
    cont = _CONTINUOUS.match(class_id)
    if cont:
        try:
            return cont["name"], ContinuousMeasurement(float(cont["value"]), float(cont["var"]))
        except ValueError:
            raise ValueError(f"class_id {class_id!r}: not numbers") from None
    name, value = class_id.split("=", 1)
    if not 0.0 <= score <= 1.0:
        raise ValueError(f"class_id {class_id!r}: score {score} not in [0, 1]")
    return name, DiscreteMeasurement(value, score)
