"""The survey log as a sink: records written as JSON Lines version 1
(shared/spec/log-format.md), one line each, what `sources.jsonl` reads back."""

from __future__ import annotations

import gzip
import io
import json
from collections.abc import Iterable
from pathlib import Path
from typing import IO

from agrislam.io.sinks.log_lines import record_to_json
from agrislam.records import Record

__all__ = ["LogWriter", "record_to_json", "write_log"]


class LogWriter:
    """Write records as a survey log, one line each (`.gz` paths are compressed)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._raw = _open_for_writing(self.path)
        self._f = io.TextIOWrapper(self._raw, encoding="utf-8", newline="\n")
        self.lines = 0

    def write(self, rec: Record) -> None:
        self._f.write(json.dumps(record_to_json(rec), separators=(",", ":"), allow_nan=False))
        self._f.write("\n")
        self.lines += 1

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_log(records: Iterable[Record], path: str | Path) -> int:
    """Write every record to `path`; returns the number of lines written."""
    with LogWriter(path) as w:
        for rec in records:
            w.write(rec)
        return w.lines


def _open_for_writing(path: Path) -> IO[bytes]:
    """A binary file to write, gzip-compressed when the name ends in `.gz`."""
    if path.suffix == ".gz":
        return gzip.open(path, "wb")  # type: ignore[return-value]
    return open(path, "wb")
