"""Writing a file so that a reader, or a run killed half-way, sees the old file or the new
one whole, never a part: write to a temporary file beside the target (same folder, so the
same file system), flush it to disk, rename it over the target, flush the folder."""

from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

TEMPORARY_MARK = "agrislam-tmp-"  # in the name of every temporary file (and its helpers)


def temporary_beside(path: Path) -> Path:
    """A fresh hidden name in `path`'s folder that ends like `path` (writers that go by
    the suffix, like matplotlib, still see .png)."""
    return path.with_name(f".{TEMPORARY_MARK}{os.getpid()}-{uuid.uuid4().hex[:8]}-{path.name}")


def is_temporary(name: str) -> bool:
    """Whether a file name is one of `temporary_beside`'s (or a helper folder a writer made
    next to one, `..agrislam-tmp-...`)."""
    return name.startswith(".") and TEMPORARY_MARK in name


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """The path to write `path`'s new content to; when the block ends without an error the
    new file replaces `path` atomically (after fsync), else it is removed."""
    path = Path(path)
    tmp = temporary_beside(path)
    try:
        yield tmp
        fsync_file(tmp)
        os.replace(tmp, path)
        fsync_folder(path.parent)
    except BaseException:
        remove(tmp)
        raise


def fsync_file(path: Path) -> None:
    with open(path, "rb") as f:
        os.fsync(f.fileno())


def fsync_folder(folder: Path) -> None:
    """Make a rename in `folder` durable (POSIX; other systems have no folder handles)."""
    if os.name != "posix":
        return
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def remove(path: Path) -> None:
    """Remove a file or folder if it is there."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)
