"""Checkpoints of a run and `agrislam run --resume`: every `checkpoint.every_frames` frames
the run's whole state (`RunState`: the world model and what the run gathered beside it) is
saved into its `map.sqlite`, in one transaction with the map so far, so a run killed at any
moment leaves the last checkpoint whole. `--resume` reads the input again from its start,
skips the records the checkpoint had mapped and maps on from the saved state.

The state is a pickle: a part that holds what pickle cannot take implements
`__getstate__`/`__setstate__` (the GTSAM back ends; tests/run/test_checkpoint.py fails on a
part that cannot be pickled). iSAM2 is saved as its factors and linearisation point and
restored as a new iSAM2 of them, so the run itself carries on from the state it saved, read
back: a resumed run then ends with exactly the map of a run never stopped (with the same
`every_frames`, which is why the checkpoint's config must match it).

A checkpoint is a pickle: resume only from output folders of your own runs."""

from __future__ import annotations

import hashlib
import io
import json
import math
import pickle
import sqlite3
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agrislam.config import AgrislamConfig, CheckpointConfig
from agrislam.io.sinks.sqlite import read_checkpoint, write_checkpoint
from agrislam.run.health import Health
from agrislam.world import WorldModel

# raised whenever the state changes shape, so that an older checkpoint is refused, not misread
# (2: folded poses held between both keyframes of their window, backend/incremental/isam_state.py;
# 3: retired nodes in backend/incremental/retired.py, frozen keyframes; 4: per-node integers in
# backend/key_table.py; 5: the truth as arrays, evaluation/ground_truth.py; 6: tables grown by
# growing.Doubling; 7: backend/incremental/marginal_cache.py, the factor store's rows in use alone;
# 8: the world's maintenance.Merger; 9: the Merger's sets of objects detected together;
# 10: the world's rejoin.Rejoiner; 13: the objects RangeOutliers watches and has judged;
# 15: the run's health, run/health.py; 16: the sensor calibration, estimation/sensor_calibration.py;
# 17: the returning robots, association/returning.py; 18: the robots waiting to be placed,
# season/newcomers.py)
FORMAT = b"agrislam-checkpoint 18"
# the modules a checkpoint's objects may come from
TRUSTED_MODULES = {"agrislam", "numpy", "collections", "copyreg", "builtins", "pydantic"}
TRUSTED_MODULES |= {"pydantic_core", "scipy"}
READ_CHUNK = 1 << 20
# checkpoints are at least this many frames per MB of saved state apart: saving grows with
# the map, so they grow apart and keep costing the same share of the run
FRAMES_PER_MB = 250.0


class ResumeError(ValueError):
    """A checkpoint that this run cannot resume from; the message says why and what to do."""


@dataclass(slots=True)
class RunState:
    """A run after the first `position` records of its stream (synchronised, labels split):
    the world model, the truth gathered aside (pipeline.Truth), records mapped by kind,
    frames mapped and the map's health so far (run/health.py)."""

    world: WorldModel
    truth: Any
    counts: Counter[str] = field(default_factory=Counter)
    n_frames: int = 0
    position: int = 0
    health: Health = field(default_factory=Health)


def dump_state(state: RunState) -> bytes:
    return pickle.dumps(state, protocol=5)


class _TrustedUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if module.split(".")[0] not in TRUSTED_MODULES:
            raise pickle.UnpicklingError(f"a checkpoint holds no {module}.{name}")
        return super().find_class(module, name)


def load_state(blob: bytes) -> RunState:
    state = _TrustedUnpickler(io.BytesIO(blob)).load()
    if not isinstance(state, RunState):
        raise pickle.UnpicklingError(f"a checkpoint holds a RunState, not {type(state).__name__}")
    return state


def adopt(world: WorldModel, saved: WorldModel) -> None:
    """`world` becomes `saved` (the caller's object carries the restored state)."""
    if saved is world:
        return
    vars(world).clear()
    vars(world).update(vars(saved))


# ------------------------------------------------------------------ what is resumed


class InputFingerprint:
    """Which input a run reads: for a file (or each file of a folder) its size and the
    SHA-256 of its first `size` bytes, hashed on incrementally as the file grows and is
    read; a `sim:` URI is its own fingerprint."""

    def __init__(self, path_or_uri: str | Path) -> None:
        self.name = str(path_or_uri)
        path = Path(path_or_uri)
        self.root = path if path.exists() else None
        files = sorted(f for f in path.rglob("*") if f.is_file()) if path.is_dir() else [path]
        self._hashes = {f: [hashlib.sha256(), 0] for f in files} if self.root else {}

    def current(self) -> dict[str, Any]:
        """{input, files: {name: [size, sha256 of those bytes]}} as of now."""
        files = {}
        for path, (digest, done) in self._hashes.items():
            with path.open("rb") as f:
                f.seek(done)
                while chunk := f.read(READ_CHUNK):
                    digest.update(chunk)
                    done += len(chunk)
            self._hashes[path][1] = done
            files[self._label(path)] = [done, digest.hexdigest()]
        return {"input": self.name, "files": files}

    def _label(self, path: Path) -> str:
        assert self.root is not None
        return "." if path == self.root else str(path.relative_to(self.root))

    def differs(self, saved: dict[str, Any]) -> str | None:
        """Why the input is not the one of `saved` (its first bytes changed, a file is
        shorter or missing), or None if it is."""
        if not self.root:
            return None if saved["input"] == self.name else f"it read {saved['input']}"
        mine = {self._label(p): p for p in self._hashes}
        for label, (size, hexdigest) in saved["files"].items():
            path, what = mine.get(label), "the file" if label == "." else label
            if path is None:
                return f"{what} is missing"
            if path.stat().st_size < size:
                return f"{what} is shorter than the {size} bytes it had read"
            if _prefix_digest(path, size) != hexdigest:
                return f"the first {size} bytes of {what} are not those it read"
        return None


def _prefix_digest(path: Path, size: int) -> str:
    digest, left = hashlib.sha256(), size
    with path.open("rb") as f:
        while left and (chunk := f.read(min(READ_CHUNK, left))):
            digest.update(chunk)
            left -= len(chunk)
    return digest.hexdigest()


def config_identity(config: AgrislamConfig, **source: Any) -> str:
    """SHA-256 of everything that decides the map: the config (with its checkpoint
    interval), the source's own settings (a config file's bag:/sim: sections, strict)."""
    text = json.dumps(
        {"config": config.model_dump(mode="json", by_alias=True), "source": source},
        sort_keys=True,
        default=str,
    )
    return hashlib.sha256(text.encode()).hexdigest()


# --------------------------------------------------------------------- checkpoints


class Checkpoints:
    """The checkpoints of one run in `path` (its map.sqlite): `take` when `due`, `resume`
    from the one there. `config`: `config_identity` of the run; `every`: its checkpoint
    section. The frames between checkpoints grow with the size of the state they save
    (FRAMES_PER_MB), so that saving costs the same share of the run on any map; they
    follow from the state alone, so a resumed run takes its next ones where the run it
    resumes would have."""

    def __init__(
        self, path: Path, input_: InputFingerprint, config: str, every: CheckpointConfig
    ) -> None:
        self.path, self.input, self.config, self.every = Path(path), input_, config, every
        self._written = False  # a checkpoint of this run is in `path` (taken or resumed)
        self.taken = 0
        self.seconds = 0.0
        self.issues: Counter[str] = Counter()  # checkpoints that could not be written, why
        self._next: float = every.every_frames  # frames at which the next one is due

    @property
    def last(self) -> dict[str, bytes] | None:
        """The latest checkpoint's entries (None: none was written), read back from `path`
        when asked, so that no second copy of the whole state is held."""
        if not self._written:
            return None
        try:
            return read_checkpoint(self.path)
        except (OSError, sqlite3.Error):
            return None

    def due(self, n_frames: int) -> bool:
        return self.every.every_frames > 0 and n_frames >= self._next

    def _after(self, n_frames: int, blob: bytes) -> None:
        spacing = math.ceil(len(blob) / 1e6 * FRAMES_PER_MB)
        self._next = n_frames + max(self.every.every_frames, spacing)

    def take(self, state: RunState) -> RunState:
        """Save `state` with the map so far; returns the state read back from what was
        saved, which the run carries on with (see the module docstring). A checkpoint that
        cannot be written (a full disk) is an issue of the run, which goes on the same."""
        start = time.perf_counter()
        try:
            snapshot = state.world.snapshot()  # before the state is saved: it may settle it
        except Exception as err:  # the tables keep the last map that could be read
            self.issues[f"checkpoint without its map: {type(err).__name__}: {err}"] += 1
            snapshot = None
        try:
            blob = dump_state(state)
        except (TypeError, AttributeError, pickle.PicklingError) as err:  # a part pickle refuses
            self.issues[f"checkpoints off: the state cannot be saved ({err})"] += 1
            self._next = math.inf
            return state
        entries = {
            "format": FORMAT,
            "state": blob,
            "input": json.dumps(self.input.current()).encode(),
            "config": self.config.encode(),
            "position": str(state.position).encode(),
        }
        try:
            write_checkpoint(self.path, entries, snapshot)
            self._written = True
            self.taken += 1
        except (OSError, sqlite3.Error) as err:
            self.issues[f"checkpoint not written: {type(err).__name__}: {err}"] += 1
        self._after(state.n_frames, blob)
        restored = load_state(blob)
        self.seconds += time.perf_counter() - start
        return restored

    def resume(self) -> RunState | None:
        """The state of the checkpoint in `path`, after checking that it is of this input
        and config; None if there is none to resume from (no map.sqlite, a run killed
        before its first checkpoint or while writing its outputs): the run starts from its
        first record."""
        if not self.path.exists():
            return None
        try:
            entries = read_checkpoint(self.path)
        except Exception as err:
            raise ResumeError(f"--resume: {self.path} cannot be read ({err})") from None
        if entries is None and not (self.path.parent / "metrics.json").exists():
            return None  # killed while it wrote its outputs: its map.sqlite is the last word
        if entries is None:
            raise ResumeError(
                f"--resume: {self.path} is the map of a finished run, with no checkpoint: "
                "nothing to resume; use --force to map the input again"
            )
        if "state" not in entries:
            return None
        if entries.get("format") != FORMAT:
            raise ResumeError(f"--resume: {self.path} holds a checkpoint of another version")
        why = self.input.differs(json.loads(entries["input"]))
        if why is not None:
            raise ResumeError(
                f"--resume: the checkpoint in {self.path} is of another input than "
                f"{self.input.name} ({why}); resume with the input it was taken of, or use "
                "--force to start over"
            )
        if entries["config"].decode() != self.config:
            raise ResumeError(
                f"--resume: the checkpoint in {self.path} was taken with another config (the "
                "config file, its bag:/sim: sections or --strict/--lenient differ); resume "
                "with the same, or use --force to start over"
            )
        self._written = True
        state = load_state(entries["state"])
        self._after(state.n_frames, entries["state"])
        return state
