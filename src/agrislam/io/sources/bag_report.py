"""What reading a ROS bag found: the topics used for each role, messages and records
counted, and every problem as an issue naming its topic and stamp. Bad input never stops
the bag reader; it skips the message (`SkipError`) and says why here."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True, slots=True)
class BagIssue:
    kind: str  # missing_topic, unknown_type, undecodable, time_backwards, no_depth, ...
    topic: str | None
    stamp: float | None
    message: str

    def __str__(self) -> str:
        where = self.topic or "bag"
        if self.stamp is not None:
            where += f" @ {self.stamp:.6f}"
        return f"{where}: {self.kind}: {self.message}"


@dataclass
class BagReport:
    """What a bag read found: topics used per role, messages, records, issues, filtered
    detections (beyond the range cut-off: by design, not bad input)."""

    path: str
    roles: dict[str, list[str]] = field(default_factory=dict)
    messages: Counter[str] = field(default_factory=Counter)
    records: Counter[str] = field(default_factory=Counter)
    filtered: Counter[str] = field(default_factory=Counter)
    issues: list[BagIssue] = field(default_factory=list)
    max_issues: int = 10_000

    @property
    def counts(self) -> Counter[str]:
        return Counter(i.kind for i in self.issues)

    def add(self, kind: str, topic: str | None, stamp: float | None, message: str) -> None:
        if len(self.issues) < self.max_issues:
            self.issues.append(BagIssue(kind, topic, stamp, message))

    @property
    def name(self) -> str:
        return self.path

    def skipped_table(self) -> dict[str, list[Any]]:
        """Every issue as columns (topic, stamp, reason, message), what a run writes as
        skipped.csv."""
        return {
            "topic": [i.topic or "" for i in self.issues],
            "stamp": [float("nan") if i.stamp is None else i.stamp for i in self.issues],
            "reason": [i.kind for i in self.issues],
            "message": [i.message for i in self.issues],
        }

    def as_dict(self) -> dict[str, Any]:
        return {
            "source": self.path,
            "roles": {role: list(topics) for role, topics in self.roles.items()},
            "messages": dict(self.messages),
            "records": dict(self.records),
            "filtered": dict(self.filtered),
            "issues": [str(i) for i in self.issues],
        }

    def summary(self) -> str:
        recs = ", ".join(f"{n} {k}" for k, n in sorted(self.records.items())) or "no records"
        head = f"{self.path}: {recs}"
        if self.filtered:
            head += "; filtered " + ", ".join(f"{n} {k}" for k, n in self.filtered.items())
        if not self.issues:
            return head + "; no issues"
        lines = [f"{head}; {len(self.issues)} issues:"]
        lines += [f"  {i}" for i in self.issues[:20]]
        if len(self.issues) > 20:
            lines.append(f"  ... {len(self.issues) - 20} more")
        return "\n".join(lines)


class SkipError(Exception):
    """One message (or detection) cannot be used; the reason goes into the report."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind, self.message = kind, message
