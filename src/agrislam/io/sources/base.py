"""The one shape of every input: a `Source` yields the survey's records (records.py) and
keeps a report of what it read, whatever it reads them from."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Protocol, runtime_checkable

from agrislam.records import Record


@runtime_checkable
class SourceReport(Protocol):
    """What a source found while it was read: counts, skipped input and why."""

    def summary(self) -> str:
        """A few lines for a person."""
        ...

    def as_dict(self) -> dict[str, Any]:
        """The same as plain JSON-ready values."""
        ...


@runtime_checkable
class Source(Protocol):
    """Records of one survey, in time order, and the report of the latest pass.

    `records()` starts a new pass each time it is called; `report` is complete once that
    pass is."""

    @property
    def name(self) -> str: ...

    @property
    def report(self) -> SourceReport: ...

    def records(self) -> Iterator[Record]: ...


class SourceError(ValueError):
    """Input a source in strict mode refuses to read past; its text says where and why."""
