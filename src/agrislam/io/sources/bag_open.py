"""Opening a ROS bag, with a message a person can act on when it cannot be read, and the
readable part of a truncated MCAP file salvaged.

A bag cut off while it was recorded has lost its MCAP summary and footer, and rosbags
refuses it; its data section is still whole records up to the cut. `salvaged_mcap` copies
those into a temporary file closed by a footer that says "no summary", which rosbags reads
by scanning."""

from __future__ import annotations

import struct
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader

MAGIC = b"\x89MCAP0\r\n"
OP_FOOTER, OP_CHUNK, OP_DATA_END = 0x02, 0x06, 0x0F
# a footer without a summary: opcode, length 20, summary start 0, summary offset start 0,
# summary crc 0; then the closing magic
EMPTY_FOOTER = struct.pack("<BQQQI", OP_FOOTER, 20, 0, 0, 0) + MAGIC
TRUNCATED = ("File end magic is invalid", "Invalid MCAP footer", "Invalid MCAP summary offset")


class UnreadableBagError(ValueError):
    """A bag that cannot be opened; the message says why and what to do."""


@contextmanager
def opened_bag(path: Path, store: Any, note: Callable[[str], None]) -> Iterator[AnyReader]:
    """The bag open for reading (closed afterwards): a truncated MCAP file as its
    salvaged part, said through `note`; UnreadableBagError for what cannot be read."""
    try:
        reader = _open(path, store)
    except Exception as err:
        if not is_truncated_mcap(path, err):
            raise UnreadableBagError(explain(path, err)) from None
        with salvaged_mcap(path) as (copy, kept, total):
            try:
                reader = _open(copy, store)
            except Exception as again:
                raise UnreadableBagError(
                    f"{explain(path, err)}; nothing could be salvaged ({again})"
                ) from None
            note(
                f"the file is truncated (it ends inside a record): the whole messages of its "
                f"first {kept:,} of {total:,} bytes ({100.0 * kept / total:.0f} %) were read"
            )
            with _closing(reader):
                yield reader
        return
    with _closing(reader):
        yield reader


def check_bag(path: Path, store: Any) -> None:
    """UnreadableBagError now, before a run, for a bag that cannot be opened (a truncated
    MCAP file passes: its readable part is salvaged when it is read)."""
    try:
        _open(path, store).close()
    except Exception as err:
        if not is_truncated_mcap(path, err):
            raise UnreadableBagError(explain(path, err)) from None


def _open(path: Path, store: Any) -> AnyReader:
    reader = AnyReader([path], default_typestore=store)
    reader.open()
    return reader


@contextmanager
def _closing(reader: AnyReader) -> Iterator[AnyReader]:
    try:
        yield reader
    finally:
        reader.close()


def is_truncated_mcap(path: Path, error: BaseException) -> bool:
    """Whether `error` of opening `path` is that of an MCAP file cut off before its end."""
    return path.suffix.lower() == ".mcap" and any(t in str(error) for t in TRUNCATED)


@contextmanager
def salvaged_mcap(path: Path) -> Iterator[tuple[Path, int, int]]:
    """(copy, bytes read, bytes in the file): the whole records of a truncated MCAP file,
    and those of the chunk it was cut in (uncompressed, zstd or lz4), as a readable MCAP
    file in a temporary folder that is removed afterwards."""
    total = path.stat().st_size
    with path.open("rb") as f:
        kept, (cut_chunk, used) = _whole_records(f, total)
        with tempfile.TemporaryDirectory(prefix="agrislam-salvage-") as folder:
            copy = Path(folder) / path.name
            with copy.open("wb") as out:
                f.seek(0)
                _copy(f, out, kept)
                out.write(cut_chunk)
                out.write(EMPTY_FOOTER)
            yield copy, kept + used, total


def _whole_records(f: Any, total: int) -> tuple[int, tuple[bytes, int]]:
    """The offset after the last whole record of the data section, and the whole records
    inside the chunk record the file ends in with the bytes of the file they took (none if
    it ends elsewhere)."""
    if f.read(8) != MAGIC:
        raise UnreadableBagError(f"{getattr(f, 'name', 'file')}: not an MCAP file")
    end = 8
    while end + 9 <= total:
        f.seek(end)
        op, length = struct.unpack("<BQ", f.read(9))
        if op in (OP_FOOTER, 0):
            break
        if end + 9 + length > total:
            return end, _records_of_cut_chunk(f, total) if op == OP_CHUNK else (b"", 0)
        end += 9 + length
        if op == OP_DATA_END:
            break
    return end, (b"", 0)


def _records_of_cut_chunk(f: Any, total: int) -> tuple[bytes, int]:
    """The whole records at the start of a chunk whose end was cut off, and the bytes of
    the file they took (for a compressed chunk: all that is left of it)."""
    start = f.tell() - 9
    head = f.read(28)  # message start and end time, uncompressed size and crc
    (n,) = struct.unpack("<I", f.read(4))
    compression = f.read(n).decode("ascii", "replace")
    f.read(8)  # the length of the records as stored
    stored = f.read(max(total - f.tell(), 0))
    if len(head) < 28:
        return b"", 0
    try:
        if compression == "zstd":
            import zstandard

            data = zstandard.ZstdDecompressor().decompressobj().decompress(stored)
        elif compression == "lz4":
            import lz4.frame

            data = lz4.frame.LZ4FrameDecompressor().decompress(stored)
        elif compression == "":
            data = stored
        else:
            return b"", 0
    except Exception:  # a stream cut inside its first block: nothing to use
        return b"", 0
    end = 0
    while end + 9 <= len(data):
        _, length = struct.unpack_from("<BQ", data, end)
        if end + 9 + length > len(data):
            break
        end += 9 + length
    if not end:
        return b"", 0
    used = (f.tell() - len(stored) + end if compression == "" else total) - start
    return bytes(data[:end]), used


def _copy(src: Any, dst: Any, n: int) -> None:
    while n > 0:
        block = src.read(min(n, 1 << 20))
        if not block:
            break
        dst.write(block)
        n -= len(block)


def explain(path: Path, err: BaseException) -> str:
    """What is wrong with a bag that did not open, and what to do about it."""
    text = str(err) or type(err).__name__
    if path.is_dir():
        if not (path / "metadata.yaml").exists():
            files = sorted(p.name for p in path.iterdir() if p.suffix in (".mcap", ".db3"))
            hint = (
                f"; run agrislam on {path / files[0]} itself (a .mcap file reads without it), "
                f"or recreate it with `ros2 bag reindex {path}`"
                if files
                else "; it holds no .mcap or .db3 file either: is it a bag?"
            )
            return f"{path}: a rosbag2 folder needs its metadata.yaml and this one has none{hint}"
        return (
            f"{path}: not a readable rosbag2 folder ({text}); check it with `ros2 bag info`"
            + _recover(text)
        )
    if path.stat().st_size == 0:
        return f"{path} is empty: record or copy the bag again"
    suffix = path.suffix.lower()
    if suffix == ".bag":
        return (
            f"{path} is not a ROS 1 bag, or a damaged one ({type(err).__name__}: {text}); check "
            "it with `rosbag info`, a truncated one can be repaired with `rosbag reindex`"
        )
    if suffix == ".db3":
        return (
            f"{path} is not a rosbag2 SQLite bag, or a damaged one ({text}); check it with "
            f"`ros2 bag info`{_recover(text)}"
        )
    if suffix == ".mcap":
        return f"{path} is not an MCAP bag, or a damaged one ({text}); check it with `mcap doctor`"
    return f"{path}: not a readable ROS bag ({text})"


def _recover(text: str) -> str:
    """The way to rescue a damaged (truncated) SQLite database, when that is the error."""
    if "malformed" not in text:
        return ""
    return (
        "; the sqlite3 tool can rescue what is left: `sqlite3 BAG.db3 .recover | sqlite3 new.db3`"
    )
