"""The field simulator as a source, opened by a ``sim:`` URI whose query (plants, seed,
preset, robots) goes on top of a `SimConfig` (a config file's ``sim:`` section):

    sim:                                        the paper's 400-plant survey (seed 1)
    sim:?plants=2000&seed=4&preset=crops_weeds"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import parse_qsl, urlencode, urlsplit

from agrislam.records import Record
from agrislam.sim.config import SimConfig
from agrislam.sim.simulator import Simulator

SCHEME = "sim"
# query parameter -> (SimConfig attribute path, type)
PARAMETERS: dict[str, tuple[tuple[str, ...], type]] = {
    "plants": (("field", "n_plants"), int),
    "seed": (("seed",), int),
    "preset": (("schema_",), str),
    "robots": (("path", "n_robots"), int),
}


def simulation_uri(**parameters: int | str) -> str:
    """``sim:?plants=..&seed=..`` of the given query parameters (in the order given)."""
    unknown = set(parameters) - set(PARAMETERS)
    if unknown:
        raise ValueError(f"unknown simulation parameters {sorted(unknown)}; known: {_known()}")
    return f"{SCHEME}:?{urlencode(parameters)}" if parameters else f"{SCHEME}:"


def simulation_config(uri: str, base: SimConfig | Mapping[str, Any] | None = None) -> SimConfig:
    """The simulator configuration a ``sim:`` URI names: `base` with the URI's query
    parameters set on it (ValueError for another scheme, an unknown parameter or a bad
    value)."""
    parts = urlsplit(uri)
    if parts.scheme != SCHEME or parts.path.strip("/") or parts.netloc or parts.fragment:
        raise ValueError(f"{uri!r} is not a simulation URI like 'sim:?plants=400&seed=1'")
    cfg = base if isinstance(base, SimConfig) else SimConfig.model_validate(dict(base or {}))
    cfg = cfg.model_copy(deep=True)
    seen = set()
    for key, text in parse_qsl(parts.query, keep_blank_values=True):
        if key not in PARAMETERS:
            raise ValueError(f"{uri!r}: unknown parameter {key!r}; known: {_known()}")
        if key in seen:
            raise ValueError(f"{uri!r}: parameter {key!r} given twice")
        seen.add(key)
        (*owners, attribute), kind = PARAMETERS[key]
        try:
            value = kind(text)
        except ValueError:
            raise ValueError(f"{uri!r}: {key}={text!r} is not {kind.__name__}") from None
        target = cfg
        for owner in owners:
            target = getattr(target, owner)
        setattr(target, attribute, value)  # validated: a bad value names the field
    return cfg


def _known() -> str:
    return ", ".join(PARAMETERS)


@dataclass
class SimulationReport:
    """What a simulated survey yielded: records by kind."""

    name: str
    records: Counter[str] = field(default_factory=Counter)

    def as_dict(self) -> dict[str, Any]:
        return {"source": self.name, "records": dict(self.records)}

    def summary(self) -> str:
        recs = ", ".join(f"{n} {k}" for k, n in sorted(self.records.items())) or "no records"
        return f"{self.name}: {recs}"


class SimulatedSource:
    """The simulated survey of `config` as a source (the default: the paper's survey)."""

    def __init__(self, config: SimConfig | None = None) -> None:
        self.config = config or SimConfig()
        self._report = SimulationReport(self.name)

    @property
    def name(self) -> str:
        cfg = self.config
        parameters: dict[str, int | str] = {"seed": cfg.seed}
        if cfg.field.n_plants is not None:  # else the rows are filled to a length
            parameters = {"plants": cfg.field.n_plants, **parameters}
        if isinstance(cfg.schema_, str):
            parameters["preset"] = cfg.schema_
        return simulation_uri(**parameters)

    @property
    def report(self) -> SimulationReport:
        return self._report

    def records(self) -> Iterator[Record]:
        self._report = report = SimulationReport(self.name)
        return _counted(Simulator(self.config).records(), report)


def _counted(records: Iterator[Record], report: SimulationReport) -> Iterator[Record]:
    for record in records:
        report.records[type(record).__name__] += 1
        yield record
