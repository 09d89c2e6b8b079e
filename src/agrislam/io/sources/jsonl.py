"""The survey log, JSON Lines version 1 (shared/spec/log-format.md, this project's additions
in docs/log-format.md), read as a source: a streaming reader that checks every line, stops
at a bad one (strict) or skips and counts it (lenient); a bad meta line always stops it."""

from __future__ import annotations

import io
import json
import math
import re
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path
from typing import IO, Any

import numpy as np

from agrislam.config import (
    AgrislamConfig,
    ContinuousAttribute,
    DiscreteAttribute,
    FieldSchema,
    InputLimits,
    SensorDefaults,
)
from agrislam.config.limits import first_error
from agrislam.io.sources.clock import Rejected, RobotClocks
from agrislam.io.sources.compressed import GzipText, check_gzip
from agrislam.io.sources.early_detections import EarlyDetections
from agrislam.io.sources.log_report import LogError, ReadReport
from agrislam.io.sources.odometry_gaps import OdometryGaps
from agrislam.io.sources.validate import REASONS, BadRecordError, check_record, within
from agrislam.records import (
    Anchor,
    ContinuousMeasurement,
    Detection,
    Detections,
    DiscreteMeasurement,
    FieldPrior,
    GnssFix,
    Measurement,
    Meta,
    Odometry,
    Record,
    RobotStart,
    TruthObject,
    TruthPose,
)

__all__ = ["REASONS", "LogError", "LogReader", "ReadReport", "read_log"]

VERSION = 1
# the start-pose std a robot gets when meta gives a start_pose without start_sigma (m, m, rad)
DEFAULT_START_SIGMA = (0.01, 0.01, 0.005)
# an odometry line that cannot be decoded still tells whose motion it held
_ODOM = re.compile(r'"type"\s*:\s*"odom"')
_ROBOT = re.compile(r'"robot"\s*:\s*"([^"\\]{1,200})"')
BOM = "\ufeff"  # a UTF-8 byte order mark before the first line is accepted (docs/log-format.md)


# ------------------------------------------------------------------------------ reading


def _number(obj: dict, key: str, *, required: bool = True, default: float | None = None) -> Any:
    if key not in obj or obj[key] is None:
        if required:
            raise BadRecordError("missing_field", f"'{key}' is missing")
        return default
    return _real(obj[key], f"'{key}'")


def _real(v: Any, what: str) -> float:
    """A JSON number as a float: never a string or a bool, nor an integer beyond floats."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise BadRecordError("bad_value", f"{what} must be a number, got {_short(v)}")
    try:
        x = float(v)
    except OverflowError:
        raise BadRecordError(
            "out_of_bounds", f"{what} is an integer of {len(str(v))} digits"
        ) from None
    if not math.isfinite(x):
        raise BadRecordError("non_finite", f"{what} is {v!r}")
    return x


def _short(v: Any, width: int = 80) -> str:
    text = repr(v)
    return text if len(text) <= width else text[: width - 3] + "..."


def _array(obj: dict, key: str, shape: tuple[int, ...], *, required: bool = True) -> Any:
    """Numbers of `shape` given as nested JSON lists; a string or bool among them is bad."""
    if key not in obj or obj[key] is None:
        if required:
            raise BadRecordError("missing_field", f"'{key}' is missing")
        return None
    v = obj[key]
    if not _has_shape(v, shape):
        raise BadRecordError("bad_value", f"'{key}' must have shape {shape}, got {_short(v)}")
    flat = v if len(shape) == 1 else [x for row in v for x in row]
    return np.array([_real(x, f"'{key}' entry") for x in flat], dtype=float).reshape(shape)


def _has_shape(v: Any, shape: tuple[int, ...]) -> bool:
    """Whether v is JSON lists nested to `shape` (each entry checked as a number later)."""
    if not shape:
        return not isinstance(v, (list, dict))
    return isinstance(v, list) and len(v) == shape[0] and all(_has_shape(x, shape[1:]) for x in v)


def _covariance(obj: dict, key: str, n: int) -> np.ndarray | None:
    """The n x n matrix as given; `sources.validate` checks that it is a covariance."""
    return _array(obj, key, (n, n), required=False)


def _probability(obj: dict, key: str, where: str) -> float:
    p = _number(obj, key)
    if not 0.0 <= p <= 1.0:
        raise BadRecordError("p_out_of_range", f"{where}: p = {p} is outside [0, 1]")
    return p


def _string(obj: dict, key: str, *, required: bool = True) -> Any:
    if key not in obj or obj[key] is None:
        if required:
            raise BadRecordError("missing_field", f"'{key}' is missing")
        return None
    v = obj[key]
    if not isinstance(v, str) or not v:
        raise BadRecordError("bad_value", f"'{key}' must be a non-empty string, got {_short(v)}")
    return v


def _mapping(obj: dict, key: str) -> dict:
    v = obj.get(key)
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise BadRecordError("bad_value", f"'{key}' must be an object, got {_short(v)}")
    return v


class _Parser:
    """Turns one decoded JSON object into a record, checking it against the spec and the
    schema and `sources.validate`; keeps the state checks need across lines (the schema)."""

    def __init__(self, schema: FieldSchema | None, limits: InputLimits) -> None:
        self.schema = schema
        self.limits = limits
        self.seen_records = False

    def parse(self, obj: Any) -> Record:
        if not isinstance(obj, dict):
            raise BadRecordError("not_json", f"expected a JSON object, got {type(obj).__name__}")
        kind = obj.get("type")
        if not isinstance(kind, str):
            raise BadRecordError("unknown_type", f"'type' must be a string, got {_short(kind)}")
        handler = {
            "meta": self._meta,
            "odom": self._odom,
            "detections": self._detections,
            "gnss": self._gnss,
            "truth_pose": self._truth_pose,
            "truth_object": self._truth_object,
        }.get(kind)  # type: ignore[arg-type]
        if handler is None:
            raise BadRecordError("unknown_type", f"unknown record type {kind!r}")
        rec = check_record(handler(obj), self.limits)
        self.seen_records = True
        return rec

    def _timed(self, obj: dict) -> tuple[float, str]:
        return _number(obj, "t"), _string(obj, "robot")

    def _meta(self, obj: dict) -> Meta:
        if self.seen_records:
            raise BadRecordError("meta_not_first", "meta must be the first record of the log")
        version = obj.get("version", VERSION)
        if isinstance(version, bool) or version != VERSION:
            raise BadRecordError(
                "unsupported_version", f"version {_short(version)}; this reader knows {VERSION}"
            )
        schema = None
        if obj.get("schema") is not None:
            try:
                schema = FieldSchema.model_validate(obj["schema"])
            except (ValueError, TypeError) as err:
                raise BadRecordError("bad_schema", first_error(err)) from None
        robots = {}
        for name, spec in _mapping(obj, "robots").items():
            with within(f"robots.{name}"):
                if not isinstance(spec, dict):
                    raise BadRecordError("bad_value", "must be an object")
                pose = _array(spec, "start_pose", (3,), required=False)
                if pose is None:
                    continue  # placed at the origin or by the mapper (spec, meta)
                sigma = _array(spec, "start_sigma", (3,), required=False)
            sigma = np.array(DEFAULT_START_SIGMA) if sigma is None else sigma
            robots[name] = RobotStart(pose=pose, sigma=sigma)
        anchor = prior = None
        if obj.get("anchor") is not None:
            with within("anchor"):
                a = _mapping(obj, "anchor")
                anchor = Anchor(
                    _number(a, "lat"),
                    _number(a, "lon"),
                    _number(a, "h", required=False, default=0.0),
                    _number(a, "yaw_deg", required=False, default=0.0),
                )
        if obj.get("field") is not None:
            with within("field"):
                f = _mapping(obj, "field")
                keys = ("row_spacing", "min_plant_distance", "row_angle_deg")
                prior = FieldPrior(*(_number(f, k, required=False) for k in keys))
        if schema is not None:
            self.schema = schema
        start = _survey_start(obj)
        return Meta(
            version=VERSION,
            schema=schema,
            robots=robots,
            anchor=anchor,
            field=prior,
            survey_start=start,
        )

    def _odom(self, obj: dict) -> Odometry:
        t, robot = self._timed(obj)
        pose = _array(obj, "pose", (3,), required=False)
        delta = _array(obj, "delta", (3,), required=False)
        if (pose is None) == (delta is None):
            raise BadRecordError(
                "missing_field" if pose is None else "bad_value",
                "an odom record needs exactly one of 'pose' and 'delta'",
            )
        return Odometry(t=t, robot=robot, pose=pose, delta=delta, cov=_covariance(obj, "cov", 3))

    def _detections(self, obj: dict) -> Detections:
        t, robot = self._timed(obj)
        objects = obj.get("objects")
        if objects is None:
            raise BadRecordError("missing_field", "'objects' is missing")
        if not isinstance(objects, list):
            raise BadRecordError("bad_value", f"'objects' must be a list, got {_short(objects)}")
        most = self.limits.max_detections_per_frame
        if len(objects) > most:  # refused before any work is spent on its detections
            raise BadRecordError(
                "too_many_detections",
                f"{len(objects)} detections in one frame; at most {most} "
                "(advanced.sensor.limits.max_detections_per_frame)",
            )
        dets = []
        for k, o in enumerate(objects):
            with within(f"objects[{k}]"):
                dets.append(self._detection(o))
        return Detections(
            t=t, robot=robot, objects=tuple(dets), sensor=_string(obj, "sensor", required=False)
        )

    def _detection(self, o: Any) -> Detection:
        if not isinstance(o, dict):
            raise BadRecordError("bad_value", f"expected an object, got {_short(o)}")
        has_xy, has_rb = "xy" in o, "range" in o or "bearing" in o
        if has_xy == has_rb:
            raise BadRecordError(
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
        label = _string(o, "label", required=False)
        label_p = _probability(o, "p", f"label {label!r}") if label is not None else None
        truth_id = _string(o, "truth_id", required=False)
        attrs = {n: self._measurement(n, m) for n, m in _mapping(o, "attributes").items()}
        return Detection(
            **geometry, attributes=attrs, label=label, label_p=label_p, truth_id=truth_id
        )

    def _measurement(self, name: str, m: Any) -> Measurement:
        if not isinstance(m, dict):
            raise BadRecordError(
                "bad_value", f"attribute {name!r}: expected an object, got {_short(m)}"
            )
        spec = self._spec(name)
        value = m.get("value")
        discrete = isinstance(spec, DiscreteAttribute) if spec else isinstance(value, str)
        if value is None:
            raise BadRecordError("missing_field", f"attribute {name!r}: 'value' is missing")
        if discrete:
            if not isinstance(value, str):
                raise BadRecordError(
                    "bad_value", f"attribute {name!r}: value {_short(value)} is not a string"
                )
            self._check_value(name, spec, value)
            return DiscreteMeasurement(value, _probability(m, "p", f"attribute {name!r}"))
        return ContinuousMeasurement(_number(m, "value"), _number(m, "var"))

    def _spec(self, name: str) -> DiscreteAttribute | ContinuousAttribute | None:
        if self.schema is None:
            return None
        spec = self.schema.attributes.get(name)
        if spec is None:
            known = ", ".join(self.schema.attributes)
            raise BadRecordError(
                "not_in_schema", f"attribute {name!r} is not in the schema ({known})"
            )
        return spec

    @staticmethod
    def _check_value(name: str, spec: Any, value: str) -> None:
        if isinstance(spec, DiscreteAttribute) and value not in spec.values:
            raise BadRecordError(
                "not_in_schema", f"attribute {name!r}: {_short(value)} not in {spec.values}"
            )

    def _gnss(self, obj: dict) -> GnssFix:
        """A GNSS fix (docs/log-format.md "gnss", reader version 1.2)."""
        t, robot = self._timed(obj)
        lat, lon, alt = (_number(obj, k) for k in ("lat", "lon", "alt"))
        cov = _covariance(obj, "cov", 3)
        antenna = _array(obj, "antenna", (3,), required=False)
        return GnssFix(t, robot, lat, lon, alt, _string(obj, "fix"), cov, antenna)

    def _truth_pose(self, obj: dict) -> TruthPose:
        t, robot = self._timed(obj)
        return TruthPose(t=t, robot=robot, pose=_array(obj, "pose", (3,)))

    def _truth_object(self, obj: dict) -> TruthObject:
        oid = obj.get("id")
        if oid is None:
            raise BadRecordError("missing_field", "'id' is missing")
        if not isinstance(oid, (str, int)) or isinstance(oid, bool):
            raise BadRecordError("bad_value", f"'id' must be a string, got {_short(oid)}")
        attrs: dict[str, str | float] = {}
        for name, value in _mapping(obj, "attributes").items():
            spec = self._spec(name)
            if isinstance(spec, DiscreteAttribute) or (spec is None and isinstance(value, str)):
                if not isinstance(value, str):
                    raise BadRecordError(
                        "bad_value", f"attribute {name!r}: {_short(value)} is not a string"
                    )
                self._check_value(name, spec, value)
                attrs[name] = value
            else:
                attrs[name] = _number({name: value}, name)
        return TruthObject(id=str(oid), xy=_array(obj, "xy", (2,)), attributes=attrs)


def _lines(f: IO[bytes], limit: int) -> Iterator[tuple[int, bytes | str | None]]:
    """(number, line) of each line; None for a line longer than `limit` bytes, which is
    skipped to its end unread (a line of any length costs no memory)."""
    n = 0
    while True:
        raw = f.readline(limit + 1)
        if not raw:
            return
        n += 1
        if len(raw) > limit and raw[-1:] not in (b"\n", "\n"):
            while (rest := f.readline(1 << 20)) and rest[-1:] not in (b"\n", "\n"):
                pass
            yield n, None
            continue
        yield n, raw


class LogReader:
    """A survey log as a source: its records, line by line (`records()` or iterating it).

    strict: raise `LogError` at the first bad line (records before it have been yielded);
    otherwise skip bad lines and count them in `report` (that of the latest pass). A bad
    meta line raises in either mode; a repeated record (`_Repeats`) is skipped and counted
    in either mode: dropping it loses nothing. `schema` validates attributes when the log's meta has
    none; `limits` bounds every value (default: `InputLimits()`). The motion of a rejected
    odometry record is kept (`sources.odometry_gaps`), `default_odom_cov` the diagonal of
    a record without a covariance (the run's `sensor.odom_cov_diag`)."""

    def __init__(
        self,
        source: str | Path | IO[bytes],
        *,
        strict: bool = True,
        schema: FieldSchema | None = None,
        limits: InputLimits | None = None,
        default_odom_cov: tuple[float, float, float] | None = None,
    ) -> None:
        self.source = source
        self.strict = strict
        self.schema = schema
        self.limits = limits or InputLimits()
        self.default_odom_cov = np.diag(default_odom_cov or SensorDefaults().odom_cov_diag)
        name = str(source) if isinstance(source, (str, Path)) else getattr(source, "name", "")
        self.report = ReadReport(source=str(name))

    @property
    def name(self) -> str:
        return self.report.source

    def records(self) -> Iterator[Record]:
        return iter(self)

    def check(self) -> None:
        """ValueError now, before a run, for a file named .gz that holds no gzip data."""
        if isinstance(self.source, (str, Path)) and Path(self.source).suffix == ".gz":
            check_gzip(Path(self.source))

    def __iter__(self) -> Iterator[Record]:
        self.report = ReadReport(source=self.report.source)
        if not isinstance(self.source, (str, Path)):
            yield from self._records(self.source)
        elif Path(self.source).suffix == ".gz":
            text = GzipText(Path(self.source))
            with io.BufferedReader(text) as f:
                yield from self._records(f, text)
        else:
            with open(self.source, "rb") as f:
                yield from self._records(f)

    def _records(self, f: IO[bytes], compressed: GzipText | None = None) -> Iterator[Record]:
        """The records of the lines of `f`; `compressed`: the stream under `f`, whose break
        (a .gz file cut short or damaged) is reported as bad input after the lines before it."""
        parser = _Parser(self.schema, self.limits)
        clocks: RobotClocks[tuple[int, Record]] = RobotClocks(self.limits)
        early: EarlyDetections[tuple[int, Record]] = EarlyDetections()
        self._gaps = OdometryGaps(self.default_odom_cov)
        repeats = _Repeats()
        report, first, broken_line = self.report, True, None
        for n, raw in _lines(f, self.limits.max_line_bytes):
            report.lines = n
            obj = None
            try:
                obj = self._decode(n, raw, first)
                if obj is None:
                    continue
                first = False
                rec = parser.parse(obj)
                if isinstance(rec, Odometry):
                    self._gaps.check(rec)
            except BadRecordError as bad:
                meta = isinstance(obj, dict) and obj.get("type") == "meta"
                self._bad(LogError(n, bad.reason, bad.message, report.source, fatal=meta))
                self._lost_odometry(obj)
                continue
            except LogError as err:
                if err.reason == "truncated" and compressed and compressed.broken:
                    broken = compressed.broken  # the line the stream broke off in
                    err, broken_line = LogError(n, broken.reason, broken.message, err.source), n
                self._bad(err)
                self._lost_odometry_line(raw)
                continue
            if isinstance(rec, (Meta, TruthObject)):
                yield from self._yield([(n, rec)])
                continue
            if (earlier := repeats.of(n, obj)) is not None:
                message = (
                    f"robot {rec.robot!r}: the {obj['type']} record of line {earlier} again "
                    f"(t = {rec.t}): a re-sent message, dropped"
                )
                report.add(LogError(n, "repeated", message, report.source))
                continue
            if isinstance(rec, Detections) and early.waits(rec.robot):
                early.hold(rec.robot, rec.t, (n, rec))
                continue
            timed = [(n, rec)]
            if isinstance(rec, Odometry) and early.waits(rec.robot):
                ahead, late = early.odometry(rec.robot, rec.t)
                self._reject(late)
                timed = ahead + timed
            for item in timed:
                released, rejected = clocks.offer(rec.robot, item[1].t, item)
                self._reject(rejected)
                yield from self._yield(released)
        for item in early.finish():  # robots without odometry: their frames unplaced
            released, rejected = clocks.offer(item[1].robot, item[1].t, item)
            self._reject(rejected)
            yield from self._yield(released)
        self._reject(clocks.finish())
        broken = compressed.broken if compressed is not None else None
        if broken is not None and broken_line is None:  # it broke off between two lines
            self._bad(LogError(report.lines + 1, broken.reason, broken.message, report.source))

    def _lost_odometry(self, obj: Any) -> None:
        """An odometry line that could not be read: its robot's motion is bridged."""
        if not (isinstance(obj, dict) and obj.get("type") == "odom"):
            return
        robot, t = obj.get("robot"), obj.get("t")
        if isinstance(robot, str):
            ok = isinstance(t, (int, float)) and not isinstance(t, bool)
            self._gaps.rejected(robot, float(t) if ok and abs(t) < 1e300 else None, None)

    def _lost_odometry_line(self, raw: bytes | str | None) -> None:
        """A line that is not JSON but names an odometry record and its robot: bridged."""
        if raw is None:
            return
        text = raw.decode("utf-8", "replace") if isinstance(raw, bytes) else raw
        if _ODOM.search(text) and (robot := _ROBOT.search(text)):
            self._gaps.rejected(robot[1], None, None)

    def _decode(self, n: int, raw: bytes | str | None, first: bool) -> Any:
        """The line's JSON value, None for a blank or comment line; LogError if it is not
        JSON (fatal when it is the first line and meant as meta)."""
        source = self.report.source
        if raw is None:
            most = self.limits.max_line_bytes
            raise LogError(n, "line_too_long", f"longer than {most} bytes", source)
        try:
            text = raw.decode("utf-8") if isinstance(raw, bytes) else raw
        except UnicodeDecodeError as err:
            raise LogError(n, "bad_encoding", str(err), source) from None
        stripped = text.removeprefix(BOM).strip() if n == 1 else text.strip()
        if not stripped or stripped.startswith("#"):
            return None
        try:
            return json.loads(stripped)
        except json.JSONDecodeError as err:
            reason = "truncated" if not text.endswith("\n") else "not_json"
            message = f"{err.msg} at column {err.colno}"
        except RecursionError:
            reason, message = "not_json", "nested too deeply to read"
        except ValueError as err:  # an integer beyond Python's digit limit
            reason, message = "not_json", str(err).split(";")[0]
        meta = first and '"meta"' in stripped[:200]
        raise LogError(n, reason, message, source, fatal=meta)

    def _yield(self, entries: list[tuple[int, Record]]) -> Iterator[Record]:
        for _, rec in entries:
            self.report.records += 1
            yield self._gaps.accepted(rec) if isinstance(rec, Odometry) else rec

    def _reject(self, rejected: list[Rejected[tuple[int, Record]]]) -> None:
        for r in rejected:
            (n, rec) = r.item
            self._bad(LogError(n, r.reason, r.message, self.report.source))
            if isinstance(rec, Odometry):
                self._gaps.rejected(rec.robot, rec.t, rec)

    def _bad(self, err: LogError) -> None:
        if self.strict or err.fatal:
            raise err
        self.report.add(err)


class _Repeats:
    """Each robot's latest record of each type, to tell a re-sent message: the same record
    (same t, same content) again. A repeated odometry `delta` would move the robot twice;
    a repeated frame or fix would count its evidence twice."""

    def __init__(self) -> None:
        self.latest: dict[tuple[str, str], tuple[int, dict]] = {}

    def of(self, line: int, obj: dict) -> int | None:
        """The line that `obj` (a timed record's JSON, read from `line`) repeats, or None."""
        key = (obj["robot"], obj["type"])
        before = self.latest.get(key)
        if before is not None and before[1]["t"] == obj["t"] and before[1] == obj:
            return before[0]
        self.latest[key] = (line, obj)
        return None


def read_log(
    source: str | Path | IO[bytes],
    *,
    strict: bool = True,
    schema: FieldSchema | None = None,
    config: AgrislamConfig | None = None,
) -> LogReader:
    """A streaming reader of a survey log (`.jsonl`, or `.jsonl.gz`); `config`: the run's,
    whose `sensor.limits` bound every value."""
    if config is None:
        return LogReader(source, strict=strict, schema=schema)
    sensor = config.advanced.sensor
    return LogReader(
        source,
        strict=strict,
        schema=schema,
        limits=sensor.limits,
        default_odom_cov=sensor.odom_cov_diag,
    )


def _survey_start(obj: dict) -> float | None:
    """`survey_start` (reader 1.2): the ISO 8601 date-time with a time zone of the survey's
    t = 0, as Unix seconds; absent: t counts from any epoch the log likes."""
    text = obj.get("survey_start")
    if text is None:
        return None
    with within("survey_start"):
        if not isinstance(text, str):
            raise BadRecordError("bad_value", "must be an ISO 8601 date-time string")
        try:
            when = datetime.fromisoformat(text.replace("Z", "+00:00"))
        except ValueError:
            raise BadRecordError("bad_value", f"{_short(text)} is no ISO 8601 date-time") from None
        if when.tzinfo is None:
            raise BadRecordError("bad_value", "the date-time needs a time zone (Z or +hh:mm)")
    return when.timestamp()
