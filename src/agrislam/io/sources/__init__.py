"""Inputs of a survey, one shape for all: `open_source(path_or_uri, config)` picks the reader
by the path's suffix or the URI's scheme and returns a `Source`. Readers are imported when
first opened, so reading a log never loads rosbags.

- ``survey.jsonl``, ``survey.jsonl.gz``: `sources.jsonl`, the survey log (spec/log-format.md);
- a rosbag2 folder, ``.mcap``, ``.db3``, a ROS 1 ``.bag``: `sources.rosbag`;
- ``sim:?plants=400&seed=1&preset=colour_size``: `sources.simulated`, the field simulator."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from agrislam.io.sources.base import Source, SourceError, SourceReport

if TYPE_CHECKING:
    from agrislam.config import AgrislamConfig
    from agrislam.io.sources.bag_config import BagSourceConfig
    from agrislam.sim.config import SimConfig

__all__ = ["SUPPORTED", "Source", "SourceError", "SourceReport", "open_source"]

LOG_SUFFIXES = (".jsonl", ".jsonl.gz")
BAG_SUFFIXES = (".mcap", ".db3", ".bag")
SUPPORTED = (
    "a survey log (.jsonl, .jsonl.gz), a ROS bag (a rosbag2 folder, .mcap, .db3, a ROS 1 "
    ".bag) or the simulator (sim:, e.g. sim:?plants=400&seed=1&preset=colour_size)"
)
_SCHEME = re.compile(r"^(?P<scheme>[A-Za-z][A-Za-z0-9+.-]+):")  # 2+ letters: not C:\


def open_source(
    path_or_uri: str | Path,
    config: AgrislamConfig | None = None,
    *,
    strict: bool = False,
    bag: BagSourceConfig | Mapping[str, Any] | None = None,
    sim: SimConfig | Mapping[str, Any] | None = None,
) -> Source:
    """The source of a survey log, a ROS bag or a ``sim:`` URI. `config`: the run's
    configuration (schema, label map, sensor defaults and bounds). `strict`: a survey log stops
    at its first bad line (`SourceError`); a bag reports bad input and reads on either way.
    `bag`, `sim`: a config file's ``bag:`` and ``sim:`` sections, each for its own kind only.
    ValueError for an input of no supported kind or a bag that cannot be opened (saying why
    and what to do), FileNotFoundError for a missing path."""
    if not isinstance(path_or_uri, Path) and (match := _SCHEME.match(path_or_uri)):
        if match["scheme"].lower() != "sim":
            raise ValueError(
                f"{path_or_uri!r}: unknown source scheme {match['scheme']!r}; supported: "
                f"{SUPPORTED}"
            )
        from agrislam.io.sources.simulated import SimulatedSource, simulation_config

        return SimulatedSource(simulation_config(path_or_uri, sim))
    path = Path(path_or_uri)
    name = path.name.lower()
    is_log, is_bag = name.endswith(LOG_SUFFIXES), path.is_dir() or name.endswith(BAG_SUFFIXES)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    if is_log:
        from agrislam.io.sources.jsonl import read_log

        log = read_log(path, strict=strict, config=config)
        log.check()  # a misnamed file is a clear error now, not after a run started
        return log
    if is_bag:
        from agrislam.io.sources.bag_config import BagSourceConfig
        from agrislam.io.sources.rosbag import BagSource

        if not isinstance(bag, BagSourceConfig):
            bag = BagSourceConfig.model_validate(bag or {})
        source = BagSource(path, config, bag)
        source.check()  # an unreadable bag is a clear error now, not after a run started
        return source
    raise ValueError(f"{path}: not a kind of input agrislam reads; supported: {SUPPORTED}")
