"""Mutations of a valid survey log, one field or one line at a time: what the fuzz tests
(tests/test_fuzz_sources.py) and the fuzzing script (benchmarks/fuzz_logs.py) throw at the
readers and the pipeline. A mutation is three numbers (line, field, kind), so hypothesis
can shrink it and a failure can be replayed."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

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
