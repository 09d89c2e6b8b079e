"""A run's output folder, checked before the run starts and held while it runs.

- `--out` must be a folder that can be written (not an existing file);
- one run at a time: the folder is locked (`.agrislam.lock`, holding the owner's pid); a
  second run into it refuses, naming the owner. The lock is an OS lock (flock), so the
  lock of a process that died (kill -9) is free again and the next run takes it over;
- a folder that holds the outputs of an earlier run (complete or not) is refused unless
  the run is told to replace them (`force`): then every one of the old run's files goes
  first, so no stale file of it stays beside the new ones; a run that resumes the
  earlier one (`resume`) keeps them: its map.sqlite holds the checkpoint;
- a run never removes or overwrites one of its own inputs (`inputs`: the log, the config,
  the map it continues): one that is a file the run writes in the folder, or a folder the
  outputs would go into, refuses the run before anything is touched, `force` or not;
- temporary files a killed run left behind (`sinks.atomic`) are removed."""

from __future__ import annotations

import json
import os
import socket
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

from agrislam.io.sinks.atomic import is_temporary, remove

try:
    import fcntl
except ImportError:  # not POSIX: an exclusive lock file, removed when the run ends
    fcntl = None  # type: ignore[assignment]

LOCK_NAME = ".agrislam.lock"
# every file a run writes (pipeline.write_outputs): what marks a folder as used, and what
# `force` removes
OUTPUT_NAMES = (
    "objects.csv",
    "trajectory.csv",
    "map.sqlite",
    "map.sqlite-journal",  # a checkpoint's transaction cut by a kill (rolled back on open)
    "skipped.csv",
    "map.geojson",
    "map.gpkg",
    "taskdata.zip",
    "prescription_shp.zip",
    "map.mcap",
    "map_foxglove.mcap",
    "report.png",
    "changes.csv",  # a survey that continued a saved map
    "season.png",
    "metrics.json",
    "live.mcap",  # what `agrislam live` received
)


class RunFolderError(ValueError):
    """The output folder cannot take this run; the message says why and what to do."""


class RunFolder:
    """The output folder of one run: `open()` (or `with`) checks and locks it, `close()`
    unlocks it. `force`: replace the outputs of an earlier run found in it; `resume`: carry
    on the earlier run, its outputs kept (each is replaced when the run ends); `inputs`:
    the files and folders the run reads or was told to write, by the option that names
    them ('--map': path), none of which it may replace."""

    def __init__(
        self,
        path: str | Path,
        *,
        force: bool = False,
        resume: bool = False,
        inputs: Mapping[str, str | Path | None] | None = None,
    ) -> None:
        self.path = Path(path)
        self.force = force
        self.resume = resume
        self.inputs = {k: Path(v) for k, v in (inputs or {}).items() if v is not None}
        self.created = False
        self.replaced: list[str] = []
        self._fd: int | None = None

    def __enter__(self) -> RunFolder:
        return self.open()

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def open(self) -> RunFolder:
        path = self.path
        if path.exists() and not path.is_dir():
            raise RunFolderError(f"--out {path} is a file, not a folder: give a folder")
        self._spare_inputs()
        try:
            self.created = not path.exists()
            path.mkdir(parents=True, exist_ok=True)
            self._lock()
        except PermissionError as err:
            raise RunFolderError(
                f"--out {path} cannot be written ({err.strerror}): choose a folder you may write to"
            ) from None
        except OSError as err:
            raise RunFolderError(f"--out {path}: {err.strerror or err}") from None
        try:
            self._clear()
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Unlock; a folder this run created and left empty is removed."""
        if self._fd is None:
            return
        lock = self.path / LOCK_NAME
        lock.unlink(missing_ok=True)  # while still holding it: no one locks a dead file
        os.close(self._fd)
        self._fd = None
        if self.created and not any(self.path.iterdir()):
            self.path.rmdir()

    @property
    def outputs(self) -> list[str]:
        """The run outputs in the folder now."""
        return [name for name in OUTPUT_NAMES if (self.path / name).exists()]

    # ----------------------------------------------------------------- helpers

    def _lock(self) -> None:
        lock = self.path / LOCK_NAME
        for _ in range(10):  # the owner may remove the file between our open and lock
            if fcntl is None:
                fd = self._exclusive(lock)
            else:
                fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    os.close(fd)
                    raise self._busy(lock) from None
                if not _same_file(fd, lock):
                    os.close(fd)
                    continue
            os.ftruncate(fd, 0)
            os.write(fd, json.dumps(_owner()).encode())
            os.fsync(fd)
            self._fd = fd
            return
        raise self._busy(lock)

    def _exclusive(self, lock: Path) -> int:
        try:
            return os.open(lock, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            raise self._busy(lock, stale_hint=True) from None

    def _busy(self, lock: Path, stale_hint: bool = False) -> RunFolderError:
        owner = _read_owner(lock)
        who = f"process {owner.get('pid', '?')} on {owner.get('host', '?')}" if owner else "a run"
        since = f" since {owner['started']}" if owner.get("started") else ""
        hint = f"; if no run is active, remove {lock}" if stale_hint else ""
        return RunFolderError(
            f"--out {self.path} is in use by {who}{since}: wait for it to finish or choose "
            f"another --out{hint}"
        )

    def _spare_inputs(self) -> None:
        """Refuse a run whose outputs would replace one of its inputs (`--force` would
        delete it first; the run's own write would overwrite it), or go inside an input
        folder (among a bag's files)."""
        for option, given in self.inputs.items():
            if given.is_dir() and _within(self.path, given):
                raise RunFolderError(
                    f"--out {self.path} lies inside {option} {given}: the outputs would go "
                    "among the input's files; choose an --out outside it"
                )
            name = next((n for n in OUTPUT_NAMES if _same_path(given, self.path / n)), None)
            if name is not None:
                raise RunFolderError(
                    f"{option} {given} is the {name} this run writes in --out {self.path}, "
                    "so it would be replaced: choose another --out (nothing was changed)"
                )

    def _clear(self) -> None:
        """Leftovers of killed runs go; an earlier run's outputs go with `force`, else
        the run is refused."""
        for entry in self.path.iterdir():
            if is_temporary(entry.name):
                remove(entry)
        old = self.outputs
        if not old or self.resume:
            return
        if not self.force:
            raise RunFolderError(
                f"--out {self.path} holds the outputs of an earlier run ({_state(self.path)}: "
                f"{', '.join(old)}); use --force to replace them, or choose another --out"
            )
        for name in old:
            (self.path / name).unlink()
        self.replaced = old


def _owner() -> dict[str, Any]:
    return {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "started": time.strftime("%Y-%m-%d %H:%M:%S"),
    }


def _read_owner(lock: Path) -> dict[str, Any]:
    try:
        owner = json.loads(lock.read_text())
    except (OSError, ValueError):
        return {}
    return owner if isinstance(owner, dict) else {}


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except FileNotFoundError:
        return False


def _same_path(a: Path, b: Path) -> bool:
    """Whether two paths name one file: the same path once links and '..' are resolved,
    or (both existing) the same file by another name (a hard link)."""
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and a.samefile(b))
    except OSError:
        return False


def _within(path: Path, folder: Path) -> bool:
    """Whether `path` is `folder` or lies inside it, links resolved."""
    try:
        return path.resolve().is_relative_to(folder.resolve())
    except OSError:
        return False


def _state(folder: Path) -> str:
    """'finished', 'stopped: why' or 'incomplete' from an earlier run's metrics.json."""
    try:
        run = json.loads((folder / "metrics.json").read_text()).get("run", {})
    except (OSError, ValueError, AttributeError):
        return "incomplete"
    status = run.get("status") if isinstance(run, dict) else None
    return str(status) if status else "finished"
