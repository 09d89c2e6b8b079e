"""The package's shape (DESIGN.md "Package layout"): imports point one way, sources, sinks,
perception and the simulator stay out of each other's modules, and no module grows past
600 lines. Read from the source text, so a violation fails here before anyone imports it."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "agrislam"
MAX_LINES = 600

# the core, lowest first: each part may import only the parts before it
CORE = [
    "limits",
    "season_config",
    "gnss_config",
    "config",
    "growing",
    "stage_timer",
    "released",
    "records",
    "semantics",
    "snapshot",
    "geometry",
    "spatial_index",
    "association",
    "births",
    "rejoin",
    "objects",
    "index_upkeep",
    "loop_closure",
    "maintenance",
    "range_outliers",
    "prior",
    "world",
]
# adapters: what each must never import (besides the CLI and the pipeline, which none may)
SIDEWAYS = {
    "sources": {"sinks", "evaluation"},
    "sinks": {"sources", "perception", "sim", "evaluation"},
    "perception": {"sources", "sinks", "sim", "ros", "evaluation"},
    "sim": {"sources", "sinks", "perception", "ros", "evaluation"},
    "ros": {"sources", "sinks", "perception", "sim", "evaluation"},
    "evaluation": {"sources", "sinks", "perception", "sim", "ros"},
}
TOP = {"pipeline", "cli"}
# modules of sinks/ that are no sink themselves: the tables and read-outs sinks share, and
# how any of them writes a file (atomic)
SINK_HELPERS = {"columns", "readouts", "scene", "log_lines", "atomic", "geo_layers"}


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(source: str) -> set[str]:
    """The agrislam modules a module's source imports (at any depth of the file)."""
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        found.update(n for n in names if n.split(".")[0] == "agrislam")
    return found


def part(module: str) -> str:
    """The top-level part of the package a module belongs to ('geometry', 'world', ...)."""
    pieces = module.split(".")
    return pieces[1] if len(pieces) > 1 else ""


def violations(module: str, imported: set[str]) -> list[str]:
    """Why each import of `module` breaks the direction of DESIGN.md, if it does."""
    mine, found = part(module), []
    for target in sorted(imported):
        theirs = part(target)
        if not theirs or (theirs == mine and mine != "sinks"):
            continue
        if mine in CORE:
            allowed = CORE[: CORE.index(mine)]
            if theirs not in allowed:
                found.append(f"{module} imports {target}: the core imports only lower parts")
        elif theirs in TOP and mine != "cli":
            found.append(f"{module} imports {target}: nothing below the CLI imports {theirs}")
        elif theirs in SIDEWAYS.get(mine, ()):
            found.append(f"{module} imports {target}: {mine} never imports {theirs}")
        elif mine == theirs == "sinks" and module != "agrislam.sinks":
            name = target.split(".")[2] if target.count(".") >= 2 else ""
            if name and name not in SINK_HELPERS:
                found.append(f"{module} imports {target}: a sink imports no other sink")
    return found


def all_modules() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def test_imports_point_one_way():
    broken = [
        v
        for path in all_modules()
        for v in violations(module_name(path), imports(path.read_text(encoding="utf-8")))
    ]
    assert not broken, "\n".join(broken)


def test_no_module_is_longer_than_600_lines():
    long = {
        str(p.relative_to(PACKAGE)): n
        for p in all_modules()
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert not long, long


@pytest.mark.parametrize(
    ("module", "source", "why"),
    [
        ("agrislam.world", "from agrislam.sinks.csv import x", "the core imports only lower"),
        ("agrislam.geometry.rows", "import agrislam.world", "the core imports only lower"),
        ("agrislam.sinks.report", "from agrislam.sinks.csv import x", "no other sink"),
        ("agrislam.sinks.csv", "from agrislam.perception import camera", "never imports"),
        ("agrislam.sources.rosbag", "from agrislam.sinks import rosbag", "never imports"),
        ("agrislam.sim.field", "from agrislam.pipeline import run_survey", "below the CLI"),
    ],
)
def test_the_checker_catches_each_kind_of_violation(module, source, why):
    found = violations(module, imports(source))
    assert found and why in found[0]


def test_the_checker_lets_allowed_imports_pass():
    allowed = {
        "agrislam.world": "from agrislam.geometry.noise import SensorModel",
        "agrislam.sinks.report": "from agrislam.sinks.readouts import opacity",
        "agrislam.sources.rosbag": "from agrislam.perception.camera import PinholeCamera",
        "agrislam.cli": "from agrislam.pipeline import run_survey",
    }
    for module, source in allowed.items():
        assert violations(module, imports(source)) == []
