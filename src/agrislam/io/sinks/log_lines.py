"""A record as the JSON object of its survey-log line (shared/spec/log-format.md): what the
JSONL sink writes and the bag sink carries on ``/agrislam/meta`` and ``/agrislam/truth``.
A helper of the sinks, not a sink: it writes nothing."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

import numpy as np

from agrislam.records import (
    Detection,
    Detections,
    DiscreteMeasurement,
    GnssFix,
    Measurement,
    Meta,
    Odometry,
    Record,
    TruthObject,
    TruthPose,
)


def record_to_json(rec: Record) -> dict[str, Any]:
    """A record as the JSON object of its log line."""
    if isinstance(rec, Odometry):
        out: dict[str, Any] = {"type": "odom", "t": float(rec.t), "robot": rec.robot}
        if rec.pose is not None:
            out["pose"] = _list(rec.pose)
        else:
            out["delta"] = _list(rec.delta)  # type: ignore[arg-type]
        if rec.cov is not None:
            out["cov"] = _list(rec.cov)
        return out
    if isinstance(rec, Detections):
        out = {"type": "detections", "t": float(rec.t), "robot": rec.robot}
        if rec.sensor is not None:
            out["sensor"] = rec.sensor
        out["objects"] = [_detection_json(d) for d in rec.objects]
        return out
    if isinstance(rec, GnssFix):
        out = {"type": "gnss", "t": float(rec.t), "robot": rec.robot, "lat": float(rec.lat)}
        out |= {"lon": float(rec.lon), "alt": float(rec.alt), "fix": rec.fix}
        if rec.cov is not None:
            out["cov"] = _list(rec.cov)
        if rec.antenna is not None:
            out["antenna"] = _list(rec.antenna)
        return out
    if isinstance(rec, TruthPose):
        return {
            "type": "truth_pose",
            "t": float(rec.t),
            "robot": rec.robot,
            "pose": _list(rec.pose),
        }
    if isinstance(rec, TruthObject):
        attrs = {k: (v if isinstance(v, str) else float(v)) for k, v in rec.attributes.items()}
        return {"type": "truth_object", "id": rec.id, "xy": _list(rec.xy), "attributes": attrs}
    if isinstance(rec, Meta):
        out = {"type": "meta", "version": rec.version}
        if rec.schema is not None:
            out["schema"] = rec.schema.model_dump(mode="json", exclude_none=True)
        if rec.robots:
            out["robots"] = {
                n: {"start_pose": _list(r.pose), "start_sigma": _list(r.sigma)}
                for n, r in rec.robots.items()
            }
        if rec.survey_start is not None:  # docs/log-format.md 1.2
            when = datetime.fromtimestamp(rec.survey_start, tz=UTC)
            out["survey_start"] = when.isoformat().replace("+00:00", "Z")
        if rec.anchor is not None:
            a = rec.anchor
            out["anchor"] = {"lat": a.lat, "lon": a.lon, "h": a.h, "yaw_deg": a.yaw_deg}
        if rec.field is not None:
            f = rec.field
            out["field"] = {
                "row_spacing": f.row_spacing,
                "min_plant_distance": f.min_plant_distance,
                "row_angle_deg": f.row_angle_deg,
            }
        return out
    raise TypeError(f"not a record: {rec!r}")


def _detection_json(d: Detection) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if d.xy is not None:
        out["xy"] = _list(d.xy)
        if d.cov is not None:
            out["cov"] = _list(d.cov)
    else:
        out["range"], out["bearing"] = float(d.range), float(d.bearing)  # type: ignore[arg-type]
        for key in ("sigma_range", "sigma_bearing"):
            if getattr(d, key) is not None:
                out[key] = float(getattr(d, key))
    if d.attributes:
        out["attributes"] = {n: _measurement_json(m) for n, m in d.attributes.items()}
    if d.label is not None:
        out["label"] = d.label
        if d.label_p is not None:
            out["p"] = float(d.label_p)
    if d.truth_id is not None:
        out["truth_id"] = d.truth_id
    return out


def _measurement_json(m: Measurement) -> dict[str, Any]:
    if isinstance(m, DiscreteMeasurement):
        return {"value": m.value, "p": float(m.p)}
    return {"value": float(m.value), "var": float(m.var)}


def _list(a: np.ndarray) -> list:
    return np.asarray(a, dtype=float).tolist()
