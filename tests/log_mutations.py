"""Mutations of a valid survey log: what the fuzz tests (tests/test_fuzz_sources.py), the
hostile-input tests and the fuzzing script (benchmarks/fuzz_logs.py) throw at the readers and
the pipeline.

- `mutate`: one field or one line made malformed. A mutation is three numbers (line,
  field, kind), so hypothesis can shrink it and a failure can be replayed.
- `OPERATORS`: one plausible bad message, well formed and within the input limits (a
  re-sent odometry record, a jump, an overconfident covariance, a renamed robot, no meta,
  a wrong row angle, GNSS fixes far off, a detection far away), by name and a seed.
- `split_robots`: a survey's frames shared out among many short-lived robots."""

from __future__ import annotations

import bisect
import copy
import itertools
import json
import math
import random
from collections.abc import Callable
from typing import Any

from agrislam.io.sinks.jsonl import record_to_json
from agrislam.sim.config import SimConfig
from agrislam.sim.simulator import Simulator

# what a number, a covariance or any field can be turned into
NUMBER_KINDS: list[Callable[[Any], Any]] = [
    lambda v: math.nan,
    lambda v: math.inf,
    lambda v: -math.inf,
    lambda v: 1e308,
    lambda v: -1e150,
    lambda v: 10**400,
    lambda v: str(v),  # a number given as a string
    lambda v: -abs(v) if isinstance(v, (int, float)) and v else -1.0,
    lambda v: 0,
    lambda v: True,
    lambda v: 1e9,
]


def _asymmetric(c: list[list[Any]]) -> list[list[Any]]:
    return [[x + (1.0 if i < j else 0.0) for j, x in enumerate(row)] for i, row in enumerate(c)]


def _tiny_negative(c: list[list[Any]]) -> list[list[Any]]:
    """The last variance -1e-12 (a driver's rounding gone wrong)."""
    last = len(c) - 1
    return [[-1e-12 if i == j == last else x for j, x in enumerate(row)] for i, row in enumerate(c)]


COVARIANCE_KINDS: list[Callable[[Any], Any]] = [
    lambda c: [[0.0] * len(c) for _ in c],  # all zeros
    lambda c: [[-x for x in row] for row in c],  # negative definite
    _asymmetric,
    _tiny_negative,
    lambda c: [row[:-1] for row in c],  # wrong shape
]
ANY_KINDS: list[Callable[[Any], Any]] = [
    lambda v: None,
    lambda v: "x",
    lambda v: [],
    lambda v: {},
    lambda v: [v, v] if not isinstance(v, list) else v + v,  # longer
    lambda v: v[:-1] if isinstance(v, list) and v else [[[[]]]],  # shorter
]
LINE_KINDS = [
    "cut",  # the line loses its end
    "garbage",
    "nested",  # deep brackets
    "duplicate",
    "swap",  # with the next line
    "bom",
    "digits",  # a 5,000-digit number
    "not_utf8",
]
N_KINDS = len(NUMBER_KINDS) + len(COVARIANCE_KINDS) + len(ANY_KINDS) + 1 + len(LINE_KINDS)


def kind_name(kind: int) -> str:
    """What mutation `kind` of `mutate` does, by class: a number, a covariance, a field's
    type, a field deleted, or a whole line's change."""
    kind %= N_KINDS
    bounds = list(
        itertools.accumulate([len(NUMBER_KINDS), len(COVARIANCE_KINDS), len(ANY_KINDS), 1])
    )
    classes = ("a number", "a covariance", "a field's type", "a field deleted")
    if kind < bounds[-1]:
        return f"edit: {classes[bisect.bisect_right(bounds, kind)]}"
    return f"edit: line {LINE_KINDS[kind - bounds[-1]]}"


def paths(value: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every path to a field of a JSON value (dict keys and list indices), depth first."""
    out = []
    if isinstance(value, dict):
        for key, item in value.items():
            out.append((*prefix, key))
            out += paths(item, (*prefix, key))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            out.append((*prefix, i))
            out += paths(item, (*prefix, i))
    return out


def mutate(lines: list[str], line: int, field: int, kind: int) -> list[bytes]:
    """`lines` (JSON text, no newlines) with one mutation, as the bytes of each line.

    `line`, `field` and `kind` are taken modulo what exists: any three integers give a
    mutation. Kinds: numbers to NaN, inf, huge, strings, negative...; covariances to zero,
    negative definite, asymmetric, a tiny negative eigenvalue, a wrong shape; any field to
    null, another type, a longer or shorter list, or deleted; whole lines cut, garbage,
    nested, duplicated, swapped, a BOM, a 5,000-digit number, bytes that are not UTF-8."""
    out = [text.encode() for text in lines]
    i = line % len(lines)
    kind %= N_KINDS
    n_field = len(NUMBER_KINDS) + len(COVARIANCE_KINDS) + len(ANY_KINDS) + 1
    if kind >= n_field:
        return _mutate_line(out, i, LINE_KINDS[kind - n_field])
    record = json.loads(lines[i])
    where = paths(record)
    if not where:
        return out
    path = where[field % len(where)]
    parent = record
    for key in path[:-1]:
        parent = parent[key]
    key, value = path[-1], parent[path[-1]]
    if kind < len(NUMBER_KINDS):
        if isinstance(value, (list, dict)):
            return out  # a number mutation of a container: no change (hypothesis moves on)
        parent[key] = NUMBER_KINDS[kind](value)
    elif kind < len(NUMBER_KINDS) + len(COVARIANCE_KINDS):
        if not (isinstance(value, list) and value and all(isinstance(r, list) for r in value)):
            return out
        parent[key] = COVARIANCE_KINDS[kind - len(NUMBER_KINDS)](value)
    elif kind < n_field - 1:
        parent[key] = ANY_KINDS[kind - len(NUMBER_KINDS) - len(COVARIANCE_KINDS)](value)
    else:
        del parent[key]
    out[i] = json.dumps(record).encode()
    return out


def _mutate_line(out: list[bytes], i: int, kind: str) -> list[bytes]:
    text = out[i]
    if kind == "cut":
        out[i] = text[: max(1, len(text) // 2)]
    elif kind == "garbage":
        out[i] = b"\x00garbage{]"
    elif kind == "nested":
        out[i] = b"[" * 100_000 + b"]" * 100_000
    elif kind == "duplicate":
        out.insert(i, text)
    elif kind == "swap" and i + 1 < len(out):
        out[i], out[i + 1] = out[i + 1], out[i]
    elif kind == "bom" and i == 0:
        out[i] = b"\xef\xbb\xbf" + text
    elif kind == "digits":
        out[i] = text.replace(b'"t": ', b'"t": 1' + b"0" * 5000 + b', "t0": ', 1)
    elif kind == "not_utf8":
        out[i] = text[:10] + b"\xff\xfe" + text[10:]
    return out


def as_log(lines: list[bytes]) -> bytes:
    return b"".join(line + b"\n" for line in lines)


def survey_lines(config: dict[str, Any]) -> list[str]:
    """A simulated survey log (`SimConfig` of `config`), one JSON text a line, truth in it."""
    records = Simulator(SimConfig.model_validate(config)).records()
    return [json.dumps(record_to_json(r)) for r in records]


# --------------------------------------------------------- plausible bad messages
Records = list[dict[str, Any]]
FAR_M = 9e6  # m, a detection this far off: within sensor.limits.max_coordinate (1e7)
OFF_NAME = "r9"  # a robot name no meta of these surveys holds
M_PER_DEGREE = 111_320.0  # of latitude; of longitude times cos(latitude)


def _of_type(records: Records, kind: str, moving: bool = False) -> list[int]:
    """Indices of the records of `kind` (`moving`: odometry after each robot's first)."""
    at = [i for i, r in enumerate(records) if r.get("type") == kind]
    if moving:
        first = {records[i]["robot"]: i for i in reversed(at)}
        at = [i for i in at if first[records[i]["robot"]] != i]
    return at


def _duplicated_odometry(records: Records, rng: random.Random) -> Records:
    """One odometry record sent twice (same robot, same t)."""
    i = rng.choice(_of_type(records, "odom", moving=True))
    return [*records[: i + 1], copy.deepcopy(records[i]), *records[i + 1 :]]


def _odometry_jump(axis: int, size: float) -> Callable[[Records, random.Random], Records]:
    """One odometry delta off by `size` along `axis` (x, y, heading)."""

    def jump(records: Records, rng: random.Random) -> Records:
        record = records[rng.choice(_of_type(records, "odom", moving=True))]
        record["delta"][axis] += rng.choice((-1.0, 1.0)) * size
        return records

    return jump


def _diagonal(n: int, variance: float) -> list[list[float]]:
    return [[variance if i == j else 0.0 for j in range(n)] for i in range(n)]


def _detection_covariance(variance: float) -> Callable[[Records, random.Random], Records]:
    """Every detection's covariance diag(variance): an overconfident detector."""

    def overconfident(records: Records, rng: random.Random) -> Records:
        for i in _of_type(records, "detections"):
            for det in records[i]["objects"]:
                det["cov"] = _diagonal(2, variance)
        return records

    return overconfident


def _odometry_covariance(variance: float) -> Callable[[Records, random.Random], Records]:
    """Every odometry covariance diag(variance): overconfident wheel odometry."""

    def overconfident(records: Records, rng: random.Random) -> Records:
        for i in _of_type(records, "odom"):
            records[i]["cov"] = _diagonal(3, variance)
        return records

    return overconfident


def _detections_before_odometry(records: Records, rng: random.Random) -> Records:
    """Copies of the first frames (up to a fifth of them) before the first odometry
    record: the odometry that follows is older than those frames."""
    frames = _of_type(records, "detections")
    copies = [copy.deepcopy(records[i]) for i in frames[: rng.randint(1, max(1, len(frames) // 5))]]
    first = _of_type(records, "odom")[0]
    return [*records[:first], *copies, *records[first:]]


def _renamed_robot(records: Records, rng: random.Random) -> Records:
    """Every record of one robot under a name the meta does not hold."""
    robot = rng.choice(sorted({r["robot"] for r in records if "robot" in r}))
    for record in records:
        if record.get("robot") == robot:
            record["robot"] = OFF_NAME
    return records


def _no_meta(records: Records, rng: random.Random) -> Records:
    return [r for r in records if r.get("type") != "meta"]


def _wrong_row_angle(records: Records, rng: random.Random) -> Records:
    """The meta's row angle 90 degrees off the rows (a simulated field's rows run at the
    meta's row_angle_deg, 0 when it says none)."""
    field = records[0].setdefault("field", {})
    field["row_angle_deg"] = (field.get("row_angle_deg") or 0.0) + 90.0
    return records


def _gnss_offsets(
    alternating: float, common: float = 0.0
) -> Callable[[Records, random.Random], Records]:
    """Every GNSS fix moved `common` metres and then, fix by fix, +-`alternating` metres,
    in one direction drawn for the log."""

    def offsets(records: Records, rng: random.Random) -> Records:
        bearing = rng.uniform(0.0, math.tau)
        for n, i in enumerate(_of_type(records, "gnss")):
            fix = records[i]
            metres = common + (alternating if n % 2 == 0 else -alternating)
            north, east = metres * math.cos(bearing), metres * math.sin(bearing)
            fix["lat"] += north / M_PER_DEGREE
            fix["lon"] += east / (M_PER_DEGREE * math.cos(math.radians(fix["lat"])))
        return records

    return offsets


def _far_detection(records: Records, rng: random.Random) -> Records:
    """One detection FAR_M off along the robot's x axis, within the input limits."""
    frames = [i for i in _of_type(records, "detections") if records[i]["objects"]]
    det = rng.choice(records[rng.choice(frames)]["objects"])
    det["xy"] = [FAR_M, det["xy"][1]]
    return records


OPERATORS: dict[str, Callable[[Records, random.Random], Records]] = {
    "odometry sent twice": _duplicated_odometry,
    "odometry jump 2 m": _odometry_jump(0, 2.0),
    "odometry jump 5 km": _odometry_jump(0, 5_000.0),
    "odometry spin 1,000 rad": _odometry_jump(2, 1_000.0),
    "detection cov 1e-6": _detection_covariance(1e-6),
    "detection cov 1e-12": _detection_covariance(1e-12),
    "detection cov 1e-16": _detection_covariance(1e-16),
    "odometry cov 1e-6": _odometry_covariance(1e-6),
    "odometry cov 1e-12": _odometry_covariance(1e-12),
    "odometry cov 1e-16": _odometry_covariance(1e-16),
    "detections before the first odometry": _detections_before_odometry,
    "robot renamed": _renamed_robot,
    "no meta": _no_meta,
    "row angle 90 deg off": _wrong_row_angle,
    "GNSS alternating +-50 m": _gnss_offsets(50.0),
    "GNSS alternating +-550 m": _gnss_offsets(550.0),
    "GNSS 1,000 km off, alternating +-50 m": _gnss_offsets(50.0, common=1e6),
    "detection 9,000 km off": _far_detection,
}
NEEDS_GNSS = {name for name in OPERATORS if name.startswith("GNSS")}


def operate(lines: list[str], name: str, seed: int) -> list[bytes]:
    """`lines` (JSON text) with plausible bad message `name` of OPERATORS, its random
    choices drawn from `seed`, as the bytes of each line."""
    records = OPERATORS[name]([json.loads(text) for text in lines], random.Random(seed))
    return [json.dumps(record).encode() for record in records]


def split_robots(lines: list[str], frames_each: int) -> list[str]:
    """A one-robot survey's frames shared out in time order among robots of `frames_each`
    frames each, every one in the meta, starting at the true pose of its first record (a
    tight start prior) with a zero first odometry delta: as many frames as the survey,
    driven by many short-lived robots."""
    records = [json.loads(text) for text in lines]
    meta, start = records[0], next(iter(records[0]["robots"].values()))
    times = [r["t"] for r in records if r["type"] == "detections"]
    truth = {r["t"]: r["pose"] for r in records if r["type"] == "truth_pose"}
    meta["robots"] = {}
    for record in records[1:]:
        if "robot" not in record:
            continue
        frame = max(bisect.bisect_right(times, record["t"]) - 1, 0)
        robot = record["robot"] = f"r{frame // frames_each}"
        if record["type"] == "odom" and robot not in meta["robots"]:
            meta["robots"][robot] = {**start, "start_pose": truth[record["t"]]}
            record["delta"] = [0.0, 0.0, 0.0]
    return [json.dumps(record) for record in records]
