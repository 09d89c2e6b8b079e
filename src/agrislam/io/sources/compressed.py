"""A gzip-compressed survey log (`.jsonl.gz`) as its text, read up to where the compressed
stream breaks off: a file cut short (a copy or a download that stopped, a recorder that was
killed) or damaged still gives every line before the break, and `GzipText.broken` says
where and why it broke, for the log reader to report as bad input. A file named `.gz` that
holds no gzip data is refused before a run (`check_gzip`): the name picks the reader, and a
plain-text log misnamed is one rename away, while guessing would read another compression
as text."""

from __future__ import annotations

import gzip
import io
import zlib
from dataclasses import dataclass
from pathlib import Path

GZIP_MAGIC = b"\x1f\x8b"
TEXT_START = (b"{", b"#", b"\xef\xbb\xbf", b"\n", b"\r", b" ", b"\t")  # how a log's text begins


@dataclass(frozen=True, slots=True)
class Break:
    """Where a compressed stream broke off: `reason` (a key of validate.REASONS: truncated
    for a file cut short, bad_compression for damaged data) and what was read before."""

    reason: str
    message: str


class GzipText(io.RawIOBase):
    """The decompressed bytes of a .gz file, to its end or to where its stream breaks off
    (then `broken`; the bytes before it were all given)."""

    def __init__(self, path: Path) -> None:
        self._file = gzip.open(path, "rb")  # noqa: SIM115 (closed with this stream)
        self._size = path.stat().st_size
        self._given = 0
        self.broken: Break | None = None

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: memoryview) -> int:  # type: ignore[override]
        if self.broken is not None:
            return 0
        try:
            chunk = self._file.read1(len(buffer))
        except EOFError:
            self._break("truncated", "the file was cut short")
            return 0
        except (zlib.error, gzip.BadGzipFile) as err:
            self._break("bad_compression", f"the file is damaged ({err})")
            return 0
        buffer[: len(chunk)] = chunk
        self._given += len(chunk)
        return len(chunk)

    def close(self) -> None:
        if not self.closed:
            self._file.close()
        super().close()

    def _break(self, reason: str, why: str) -> None:
        self.broken = Break(
            reason,
            f"{why}: its gzip stream ({self._size:,} bytes) breaks off after "
            f"{self._given:,} bytes of text; the lines before are kept",
        )


def check_gzip(path: Path) -> None:
    """ValueError, saying what to do, for a file named .gz that is not gzip data (an empty
    file is left to read as an empty log)."""
    with path.open("rb") as f:
        head = f.read(4)
    if not head or head.startswith(GZIP_MAGIC):
        return
    if head.startswith(TEXT_START):
        raise ValueError(
            f"{path} is named .gz but is not gzip-compressed: it reads as a plain-text log; "
            f"rename it to {path.with_suffix('').name} (or compress it with gzip)"
        )
    raise ValueError(
        f"{path} is named .gz but is not gzip-compressed (it begins with bytes {head.hex(' ')}): "
        "a damaged file, or another compression; give the .jsonl or a gzip of it"
    )
