"""The package's shape (docs/architecture.md): imports point one way, no module imports
itself back through others, adapters stay out of each other's modules, and the tests'
folders mirror the package. Read from the source text, so a violation fails here before
anyone imports it; each rule is also shown failing on a planted violation."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from paths import PACKAGE, REPO

# the core, lowest first: each part may import only the parts before it
CORE = [
    "config",
    "growing",
    "records",
    "timing",
    "geometry",
    "semantics",
    "snapshot",
    "backend",
    "mapping",
    "estimation",
    "frontend",
    "association",
    "maintenance",
    "season",
    "stages",
    "world",
]
# adapters may import the core; what each must never import besides (and never run or cli)
SIDEWAYS = {
    "io.sources": {"io.sinks", "evaluation"},
    "io.sinks": {"io.sources", "io.perception", "sim", "evaluation"},
    "io.perception": {"io.sources", "io.sinks", "sim", "io.ros", "evaluation"},
    "io.ros": {"io.sources", "io.sinks", "io.perception", "sim", "evaluation"},
    "sim": {"io.sources", "io.sinks", "io.perception", "io.ros", "evaluation"},
    "evaluation": {"io.sources", "io.sinks", "io.perception", "sim", "io.ros"},
}
# the run drives the world from sources to sinks; live drives the run from a robot's
# messages; the CLI drives both. Each may import the ones before it.
TOP = ["run", "live", "cli"]
# modules of io/sinks that are no sink themselves: the tables and read-outs sinks share, and
# how any of them writes a file (atomic)
SINK_HELPERS = {"columns", "readouts", "scene", "log_lines", "atomic", "geo_layers"}
# test folders that mirror no package folder
TEST_ONLY_FOLDERS = {"architecture", "benchmarks"}


def module_name(path: Path, package: Path = PACKAGE) -> str:
    parts = path.relative_to(package.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(source: str, known: set[str] | None = None) -> set[str]:
    """The agrislam modules a module's source imports (at any depth of the file). With the
    package's `known` modules, `from agrislam.a import b` names `agrislam.a.b` if that is a
    module, else `agrislam.a`."""
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            subs = [f"{node.module}.{a.name}" for a in node.names]
            if known is None:
                names = [node.module, *subs]
            else:
                names = [s for s in subs if s in known]
                if len(names) < len(subs):
                    names.append(node.module)
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        found.update(n for n in names if n.split(".")[0] == "agrislam")
    return found


def part(module: str) -> str:
    """The part of the package a module belongs to ('backend', 'world', 'io.sinks', ...)."""
    pieces = module.split(".")
    if len(pieces) > 2 and pieces[1] == "io":
        return f"io.{pieces[2]}"
    return pieces[1] if len(pieces) > 1 else ""


def violations(module: str, imported: set[str]) -> list[str]:
    """Why each import of `module` breaks the direction of docs/architecture.md, if it does."""
    mine, found = part(module), []
    for target in sorted(imported):
        theirs = part(target)
        if not theirs or (theirs in ("io", mine) and mine != "io.sinks"):
            continue
        if mine in CORE:
            if theirs not in CORE[: CORE.index(mine)]:
                found.append(f"{module} imports {target}: the core imports only lower parts")
        elif mine == "cli":
            continue
        elif theirs in TOP and not (mine in TOP and TOP.index(theirs) < TOP.index(mine)):
            found.append(f"{module} imports {target}: nothing below the CLI imports {theirs}")
        elif theirs in SIDEWAYS.get(mine, ()):
            found.append(f"{module} imports {target}: {mine} never imports {theirs}")
        elif mine == theirs == "io.sinks" and module != "agrislam.io.sinks":
            name = target.split(".")[3] if target.count(".") >= 3 else ""
            if name and name not in SINK_HELPERS:
                found.append(f"{module} imports {target}: a sink imports no other sink")
    return found


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the package's modules it imports; a package a module lies in is no edge
    (Python loads it first in any case)."""
    paths = {module_name(p, package): p for p in sorted(package.rglob("*.py"))}
    known = set(paths)
    graph = {}
    for name, path in paths.items():
        targets = imports(path.read_text(encoding="utf-8"), known) & known
        graph[name] = {t for t in targets if t != name and not name.startswith(t + ".")}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The groups of modules that import each other round (Tarjan's strongly connected
    components of more than one module), iteratively: no recursion limit."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    found.append(sorted(group))
    return found


def unmirrored_test_folders(tests: Path, package: Path = PACKAGE) -> list[str]:
    """Test folders that stand for no folder of the package."""
    found = []
    for folder in sorted(p for p in tests.rglob("*") if p.is_dir() and "__" not in p.name):
        relative = folder.relative_to(tests)
        if relative.parts[0] in TEST_ONLY_FOLDERS or relative.name.startswith("."):
            continue
        if not (package / relative).is_dir():
            found.append(str(relative))
    return found


def test_imports_point_one_way():
    broken = [
        v
        for path in sorted(PACKAGE.rglob("*.py"))
        for v in violations(module_name(path), imports(path.read_text(encoding="utf-8")))
    ]
    assert not broken, "\n".join(broken)


def test_no_import_cycle():
    assert cycles(import_graph()) == []


def test_tests_mirror_the_package():
    assert unmirrored_test_folders(REPO / "tests") == []


@pytest.mark.parametrize(
    ("module", "source", "why"),
    [
        ("agrislam.world", "from agrislam.io.sinks.csv import x", "the core imports only lower"),
        ("agrislam.estimation.rows", "import agrislam.world", "the core imports only lower"),
        ("agrislam.backend.batch", "from agrislam.mapping import x", "the core imports only lower"),
        ("agrislam.io.sinks.report", "from agrislam.io.sinks.csv import x", "no other sink"),
        ("agrislam.io.sinks.csv", "from agrislam.io.perception import camera", "never imports"),
        ("agrislam.io.sources.rosbag", "from agrislam.io.sinks import rosbag", "never imports"),
        ("agrislam.sim.field", "from agrislam.run.pipeline import run_survey", "below the CLI"),
        ("agrislam.evaluation.metrics", "from agrislam.cli import app", "below the CLI"),
    ],
)
def test_the_checker_catches_each_kind_of_violation(module, source, why):
    found = violations(module, imports(source))
    assert found and why in found[0]


def test_the_checker_lets_allowed_imports_pass():
    allowed = {
        "agrislam.world": "from agrislam.geometry.noise import SensorModel",
        "agrislam.io.sinks.report": "from agrislam.io.sinks.readouts import opacity",
        "agrislam.io.sources.rosbag": "from agrislam.io.perception.camera import PinholeCamera",
        "agrislam.run.pipeline": "from agrislam.io.sinks.csv import write_objects_csv",
        "agrislam.cli": "from agrislam.run.pipeline import run_survey",
    }
    for module, source in allowed.items():
        assert violations(module, imports(source)) == []


def test_the_cycle_check_catches_a_planted_cycle(tmp_path):
    package = tmp_path / "agrislam"
    (package / "backend").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "backend" / "__init__.py").write_text("from agrislam.backend import batch\n")
    (package / "backend" / "batch.py").write_text("from agrislam.backend.base import Base\n")
    (package / "backend" / "base.py").write_text("from agrislam.backend import protocol\n")
    (package / "backend" / "protocol.py").write_text("import agrislam.backend.batch\n")
    found = cycles(import_graph(package))
    assert found == [
        ["agrislam.backend.base", "agrislam.backend.batch", "agrislam.backend.protocol"]
    ]
    (package / "backend" / "protocol.py").write_text("import numpy\n")
    assert cycles(import_graph(package)) == []


def test_the_mirror_check_catches_a_stray_test_folder(tmp_path):
    package, tests = tmp_path / "src" / "agrislam", tmp_path / "tests"
    (package / "backend").mkdir(parents=True)
    (tests / "backend").mkdir(parents=True)
    (tests / "benchmarks").mkdir()
    assert unmirrored_test_folders(tests, package) == []
    (tests / "geometry_backend").mkdir()
    assert unmirrored_test_folders(tests, package) == ["geometry_backend"]
