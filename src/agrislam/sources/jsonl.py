"""The survey log, JSON Lines version 1 (shared/spec/log-format.md), read as a source: a
streaming reader that checks every line (`sinks.jsonl` writes the log). It never loads the
file whole; a bad line either stops it (strict) with the line number and the reason, or is
skipped and counted (lenient)."""

from __future__ import annotations

import gzip
import json
import math
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from agrislam.config import ContinuousAttribute, DiscreteAttribute, FieldSchema
from agrislam.records import (
    Anchor,
    ContinuousMeasurement,
    Detection,
    Detections,
    DiscreteMeasurement,
    FieldPrior,
    Measurement,
    Meta,
    Odometry,
    Record,
    RobotStart,
    TruthObject,
    TruthPose,
)
from agrislam.sources.base import SourceError

VERSION = 1
# the start-pose std a robot gets when meta gives a start_pose without start_sigma (m, m, rad)
DEFAULT_START_SIGMA = (0.01, 0.01, 0.005)

# why a line was rejected; the spec's "Bad input" list plus the ways a line can be malformed
REASONS = {
    "not_json": "not a JSON object",
    "truncated": "the file ends in the middle of this line",
    "bad_encoding": "not UTF-8",
    "unknown_type": "unknown record type",
    "missing_field": "a required field is missing",
    "bad_value": "a field has the wrong type or shape",
    "non_finite": "a number is missing, NaN or infinite",
    "bad_covariance": "a covariance is not symmetric positive semi-definite",
    "p_out_of_range": "a probability p outside [0, 1]",
    "not_in_schema": "an attribute or value not in the schema",
    "time_backwards": "time goes backwards for this robot",
    "meta_not_first": "a meta record after other records",
    "unsupported_version": "a log format version this reader does not know",
    "bad_schema": "the meta schema is invalid",
}


class LogError(SourceError):
    """A bad line: where it is and why."""

    def __init__(self, line: int, reason: str, message: str, source: str = "") -> None:
        self.line, self.reason, self.message, self.source = line, reason, message, source
        where = f"{source}:{line}" if source else f"line {line}"
        super().__init__(f"{where}: {reason}: {message}")


class _BadLineError(Exception):
    def __init__(self, reason: str, message: str) -> None:
        self.reason, self.message = reason, message


@dataclass
class ReadReport:
    """What a read found: lines seen, records yielded, bad lines by reason (lenient mode)."""

    source: str = ""
    lines: int = 0
    records: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    examples: list[LogError] = field(default_factory=list)  # the first few bad lines
    max_examples: int = 20

    @property
    def n_skipped(self) -> int:
        return sum(self.skipped.values())

    def add(self, err: LogError) -> None:
        self.skipped[err.reason] += 1
        if len(self.examples) < self.max_examples:
            self.examples.append(err)

    def as_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "lines": self.lines,
            "records": self.records,
            "skipped": dict(self.skipped),
            "examples": [str(e) for e in self.examples],
        }

    def summary(self) -> str:
        head = f"{self.source or 'log'}: {self.records} records from {self.lines} lines"
        if not self.skipped:
            return head + ", no bad lines"
        parts = ", ".join(f"{n} {r} ({REASONS.get(r, r)})" for r, n in self.skipped.most_common())
        return f"{head}, {self.n_skipped} bad lines skipped: {parts}"


# ------------------------------------------------------------------------------ reading


def _number(obj: dict, key: str, *, required: bool = True, default: float | None = None) -> Any:
    if key not in obj or obj[key] is None:
        if required:
            raise _BadLineError("missing_field", f"'{key}' is missing")
        return default
    v = obj[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _BadLineError("bad_value", f"'{key}' must be a number, got {v!r}")
    if not math.isfinite(v):
        raise _BadLineError("non_finite", f"'{key}' is {v!r}")
    return float(v)


def _array(obj: dict, key: str, shape: tuple[int, ...], *, required: bool = True) -> Any:
    if key not in obj or obj[key] is None:
        if required:
            raise _BadLineError("missing_field", f"'{key}' is missing")
        return None
    v = obj[key]
    try:
        a = np.array(v, dtype=float)
    except (TypeError, ValueError):
        raise _BadLineError(
            "bad_value", f"'{key}' must be numbers of shape {shape}, got {v!r}"
        ) from None
    if a.shape != shape or _has_bool(v):
        raise _BadLineError("bad_value", f"'{key}' must have shape {shape}, got {v!r}")
    if not np.isfinite(a).all():
        raise _BadLineError("non_finite", f"'{key}' has a NaN or infinite entry: {v!r}")
    return a


def _has_bool(v: Any) -> bool:
    return isinstance(v, bool) or (isinstance(v, list) and any(_has_bool(x) for x in v))


def _covariance(obj: dict, key: str, n: int) -> np.ndarray | None:
    c = _array(obj, key, (n, n), required=False)
    if c is None:
        return None
    scale = max(1.0, float(np.abs(c).max()))
    if not np.allclose(c, c.T, rtol=0.0, atol=1e-9 * scale):
        raise _BadLineError("bad_covariance", f"'{key}' is not symmetric: {c.tolist()}")
    if np.linalg.eigvalsh(0.5 * (c + c.T)).min() < -1e-9 * scale:
        raise _BadLineError(
            "bad_covariance", f"'{key}' is not positive semi-definite: {c.tolist()}"
        )
    return c


def _probability(obj: dict, key: str, where: str) -> float:
    p = _number(obj, key)
    if not 0.0 <= p <= 1.0:
        raise _BadLineError("p_out_of_range", f"{where}: p = {p} is outside [0, 1]")
    return p


def _string(obj: dict, key: str, *, required: bool = True) -> Any:
    if key not in obj or obj[key] is None:
        if required:
            raise _BadLineError("missing_field", f"'{key}' is missing")
        return None
    v = obj[key]
    if not isinstance(v, str) or not v:
        raise _BadLineError("bad_value", f"'{key}' must be a non-empty string, got {v!r}")
    return v


def _mapping(obj: dict, key: str) -> dict:
    v = obj.get(key)
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise _BadLineError("bad_value", f"'{key}' must be an object, got {v!r}")
    return v


def _pydantic_message(err: ValueError) -> str:
    errors = getattr(err, "errors", None)
    if not callable(errors):
        return str(err)
    first = errors()[0]
    where = ".".join(str(p) for p in first.get("loc", ()))
    msg = str(first.get("msg", err)).removeprefix("Value error, ")
    return f"{where}: {msg}" if where else msg


class _Parser:
    """Turns one decoded JSON object into a record, checking it against the spec and the
    schema; keeps the state checks need across lines (schema, per-robot time)."""

    def __init__(self, schema: FieldSchema | None) -> None:
        self.schema = schema
        self.last_t: dict[str, float] = {}
        self.seen_records = False

    def parse(self, obj: Any) -> Record:
        if not isinstance(obj, dict):
            raise _BadLineError("not_json", f"expected a JSON object, got {type(obj).__name__}")
        kind = obj.get("type")
        handler = {
            "meta": self._meta,
            "odom": self._odom,
            "detections": self._detections,
            "truth_pose": self._truth_pose,
            "truth_object": self._truth_object,
        }.get(kind)  # type: ignore[arg-type]
        if handler is None:
            raise _BadLineError("unknown_type", f"unknown record type {kind!r}")
        rec = handler(obj)
        self.seen_records = True
        return rec

    def _timed(self, obj: dict) -> tuple[float, str]:
        t, robot = _number(obj, "t"), _string(obj, "robot")
        last = self.last_t.get(robot)
        if last is not None and t < last:
            raise _BadLineError("time_backwards", f"robot {robot!r}: t = {t} after t = {last}")
        return t, robot

    def _commit_time(self, t: float, robot: str) -> None:
        self.last_t[robot] = t

    def _meta(self, obj: dict) -> Meta:
        if self.seen_records:
            raise _BadLineError("meta_not_first", "meta must be the first record of the log")
        version = obj.get("version", VERSION)
        if version != VERSION:
            raise _BadLineError(
                "unsupported_version", f"version {version!r}; this reader knows {VERSION}"
            )
        schema = None
        if obj.get("schema") is not None:
            try:
                schema = FieldSchema.model_validate(obj["schema"])
            except ValueError as err:
                raise _BadLineError("bad_schema", _pydantic_message(err)) from None
        robots = {}
        for name, spec in _mapping(obj, "robots").items():
            if not isinstance(spec, dict):
                raise _BadLineError("bad_value", f"robots.{name} must be an object")
            pose = _array(spec, "start_pose", (3,), required=False)
            if pose is None:
                continue  # placed at the origin or by the mapper (spec, meta)
            sigma = _array(spec, "start_sigma", (3,), required=False)
            sigma = np.array(DEFAULT_START_SIGMA) if sigma is None else sigma
            if (sigma < 0).any():
                raise _BadLineError("bad_value", f"robots.{name}.start_sigma must be >= 0")
            robots[name] = RobotStart(pose=pose, sigma=sigma)
        anchor = None
        if obj.get("anchor") is not None:
            a = _mapping(obj, "anchor")
            lat, lon = _number(a, "lat"), _number(a, "lon")
            if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
                raise _BadLineError("bad_value", f"anchor lat/lon ({lat}, {lon}) out of range")
            anchor = Anchor(
                lat,
                lon,
                _number(a, "h", required=False, default=0.0),
                _number(a, "yaw_deg", required=False, default=0.0),
            )
        prior = None
        if obj.get("field") is not None:
            f = _mapping(obj, "field")
            prior = FieldPrior(
                *(
                    _number(f, k, required=False)
                    for k in ("row_spacing", "min_plant_distance", "row_angle_deg")
                )
            )
        if schema is not None:
            self.schema = schema
        return Meta(version=VERSION, schema=schema, robots=robots, anchor=anchor, field=prior)

    def _odom(self, obj: dict) -> Odometry:
        t, robot = self._timed(obj)
        pose = _array(obj, "pose", (3,), required=False)
        delta = _array(obj, "delta", (3,), required=False)
        if (pose is None) == (delta is None):
            raise _BadLineError(
                "missing_field" if pose is None else "bad_value",
                "an odom record needs exactly one of 'pose' and 'delta'",
            )
        rec = Odometry(t=t, robot=robot, pose=pose, delta=delta, cov=_covariance(obj, "cov", 3))
        self._commit_time(t, robot)
        return rec

    def _detections(self, obj: dict) -> Detections:
        t, robot = self._timed(obj)
        objects = obj.get("objects")
        if objects is None:
            raise _BadLineError("missing_field", "'objects' is missing")
        if not isinstance(objects, list):
            raise _BadLineError("bad_value", f"'objects' must be a list, got {objects!r}")
        dets = []
        for k, o in enumerate(objects):
            try:
                dets.append(self._detection(o))
            except _BadLineError as bad:
                raise _BadLineError(bad.reason, f"objects[{k}]: {bad.message}") from None
        rec = Detections(
            t=t, robot=robot, objects=tuple(dets), sensor=_string(obj, "sensor", required=False)
        )
        self._commit_time(t, robot)
        return rec

    def _detection(self, o: Any) -> Detection:
        if not isinstance(o, dict):
            raise _BadLineError("bad_value", f"expected an object, got {o!r}")
        has_xy, has_rb = "xy" in o, "range" in o or "bearing" in o
        if has_xy == has_rb:
            raise _BadLineError(
                "missing_field" if not has_xy else "bad_value",
                "give either 'xy' or 'range'/'bearing'",
            )
        geometry: dict[str, Any] = {}
        if has_xy:
            geometry = {"xy": _array(o, "xy", (2,)), "cov": _covariance(o, "cov", 2)}
        else:
            geometry = {"range": _number(o, "range"), "bearing": _number(o, "bearing")}
            for key in ("sigma_range", "sigma_bearing"):
                geometry[key] = _number(o, key, required=False)
                if geometry[key] is not None and geometry[key] < 0:
                    raise _BadLineError("bad_value", f"'{key}' must be >= 0")
            if geometry["range"] < 0:
                raise _BadLineError("bad_value", f"range {geometry['range']} < 0")
        label = _string(o, "label", required=False)
        label_p = _probability(o, "p", f"label {label!r}") if label is not None else None
        truth_id = _string(o, "truth_id", required=False)
        attrs = {n: self._measurement(n, m) for n, m in _mapping(o, "attributes").items()}
        return Detection(
            **geometry, attributes=attrs, label=label, label_p=label_p, truth_id=truth_id
        )

    def _measurement(self, name: str, m: Any) -> Measurement:
        if not isinstance(m, dict):
            raise _BadLineError("bad_value", f"attribute {name!r}: expected an object, got {m!r}")
        spec = self._spec(name)
        value = m.get("value")
        discrete = isinstance(spec, DiscreteAttribute) if spec else isinstance(value, str)
        if value is None:
            raise _BadLineError("missing_field", f"attribute {name!r}: 'value' is missing")
        if discrete:
            if not isinstance(value, str):
                raise _BadLineError(
                    "bad_value", f"attribute {name!r}: value {value!r} is not a string"
                )
            self._check_value(name, spec, value)
            return DiscreteMeasurement(value, _probability(m, "p", f"attribute {name!r}"))
        v = _number(m, "value")
        var = _number(m, "var")
        if var < 0:
            raise _BadLineError("bad_value", f"attribute {name!r}: var {var} < 0")
        return ContinuousMeasurement(v, var)

    def _spec(self, name: str) -> DiscreteAttribute | ContinuousAttribute | None:
        if self.schema is None:
            return None
        spec = self.schema.attributes.get(name)
        if spec is None:
            known = ", ".join(self.schema.attributes)
            raise _BadLineError(
                "not_in_schema", f"attribute {name!r} is not in the schema ({known})"
            )
        return spec

    @staticmethod
    def _check_value(name: str, spec: Any, value: str) -> None:
        if isinstance(spec, DiscreteAttribute) and value not in spec.values:
            raise _BadLineError(
                "not_in_schema", f"attribute {name!r}: {value!r} not in {spec.values}"
            )

    def _truth_pose(self, obj: dict) -> TruthPose:
        t, robot = self._timed(obj)
        rec = TruthPose(t=t, robot=robot, pose=_array(obj, "pose", (3,)))
        self._commit_time(t, robot)
        return rec

    def _truth_object(self, obj: dict) -> TruthObject:
        oid = obj.get("id")
        if oid is None:
            raise _BadLineError("missing_field", "'id' is missing")
        if not isinstance(oid, (str, int)) or isinstance(oid, bool):
            raise _BadLineError("bad_value", f"'id' must be a string, got {oid!r}")
        attrs: dict[str, str | float] = {}
        for name, value in _mapping(obj, "attributes").items():
            spec = self._spec(name)
            if isinstance(spec, DiscreteAttribute) or (spec is None and isinstance(value, str)):
                if not isinstance(value, str):
                    raise _BadLineError(
                        "bad_value", f"attribute {name!r}: {value!r} is not a string"
                    )
                self._check_value(name, spec, value)
                attrs[name] = value
            else:
                attrs[name] = _number({name: value}, name)
        return TruthObject(id=str(oid), xy=_array(obj, "xy", (2,)), attributes=attrs)


def _open(path: Path, mode: str) -> IO[bytes]:
    if path.suffix == ".gz":
        return gzip.open(path, mode + "b")  # type: ignore[return-value]
    return open(path, mode + "b")


class LogReader:
    """A survey log as a source: its records, line by line (`records()` or iterating it).

    strict: raise `LogError` at the first bad line (records before it have been yielded);
    otherwise skip bad lines and count them in `report` (that of the latest pass). `schema`
    validates attributes when the log's meta has none."""

    def __init__(
        self,
        source: str | Path | IO[bytes],
        *,
        strict: bool = True,
        schema: FieldSchema | None = None,
    ) -> None:
        self.source = source
        self.strict = strict
        self.schema = schema
        name = str(source) if isinstance(source, (str, Path)) else getattr(source, "name", "")
        self.report = ReadReport(source=str(name))

    @property
    def name(self) -> str:
        return self.report.source

    def records(self) -> Iterator[Record]:
        return iter(self)

    def __iter__(self) -> Iterator[Record]:
        self.report = ReadReport(source=self.report.source)
        if isinstance(self.source, (str, Path)):
            with _open(Path(self.source), "r") as f:
                yield from self._lines(f)
        else:
            yield from self._lines(self.source)

    def _lines(self, f: IO[bytes]) -> Iterator[Record]:
        parser = _Parser(self.schema)
        report = self.report
        for n, raw in enumerate(f, start=1):
            report.lines = n
            try:
                text = raw.decode("utf-8") if isinstance(raw, bytes) else raw
            except UnicodeDecodeError as err:
                self._bad(LogError(n, "bad_encoding", str(err), report.source))
                continue
            stripped = text.strip()
            if not stripped or stripped.startswith("#"):
                continue
            try:
                obj = json.loads(stripped)
            except json.JSONDecodeError as err:
                cut = not text.endswith("\n")
                reason = "truncated" if cut else "not_json"
                self._bad(LogError(n, reason, f"{err.msg} at column {err.colno}", report.source))
                continue
            try:
                rec = parser.parse(obj)
            except _BadLineError as bad:
                self._bad(LogError(n, bad.reason, bad.message, report.source))
                continue
            report.records += 1
            yield rec

    def _bad(self, err: LogError) -> None:
        if self.strict:
            raise err
        self.report.add(err)


def read_log(
    source: str | Path | IO[bytes], *, strict: bool = True, schema: FieldSchema | None = None
) -> LogReader:
    """A streaming reader of a survey log (`.jsonl`, or `.jsonl.gz`)."""
    return LogReader(source, strict=strict, schema=schema)
