"""What reading a survey log found: lines, records, and every bad line with its number, its
reason (`sources.validate.REASONS`) and a message naming the field. A run writes the bad
lines as `skipped.csv` and their counts into its summary."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from agrislam.io.sources.base import SourceError
from agrislam.io.sources.validate import REASONS

MAX_MESSAGE = 200  # characters of a bad line's message that are kept (a line may be huge)


class LogError(SourceError):
    """A bad line: where it is and why. `fatal`: a bad meta line, which stops a read in
    lenient mode too (the meta line is the survey's contract)."""

    def __init__(
        self, line: int, reason: str, message: str, source: str = "", *, fatal: bool = False
    ) -> None:
        if len(message) > MAX_MESSAGE:
            message = message[: MAX_MESSAGE - 3] + "..."
        self.line, self.reason, self.message, self.source = line, reason, message, source
        self.fatal = fatal
        where = f"{source}:{line}" if source else f"line {line}"
        super().__init__(f"{where}: {reason}: {message}")


@dataclass
class ReadReport:
    """What a read found: lines seen, records yielded, bad lines by reason (lenient mode)
    and each bad line (the first `max_listed`)."""

    source: str = ""
    lines: int = 0
    records: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    bad_lines: list[LogError] = field(default_factory=list)
    max_examples: int = 20
    max_listed: int = 100_000

    @property
    def n_skipped(self) -> int:
        return sum(self.skipped.values())

    @property
    def examples(self) -> list[LogError]:
        """The first few bad lines, in line order."""
        return sorted(self.bad_lines, key=lambda e: e.line)[: self.max_examples]

    def add(self, err: LogError) -> None:
        self.skipped[err.reason] += 1
        if len(self.bad_lines) < self.max_listed:
            self.bad_lines.append(err)

    def skipped_table(self) -> dict[str, list[Any]]:
        """Every listed bad line as columns (line, reason, message), in line order."""
        rows = sorted(self.bad_lines, key=lambda e: e.line)
        return {
            "line": [e.line for e in rows],
            "reason": [e.reason for e in rows],
            "message": [e.message for e in rows],
        }

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
        lines = [f"{head}, {self.n_skipped} bad lines skipped: {parts}"]
        lines += [f"  {e}" for e in self.examples[:5]]
        if self.n_skipped > 5:
            lines.append(f"  ... {self.n_skipped - 5} more, each listed in a run's skipped.csv")
        return "\n".join(lines)
