#!/usr/bin/env python3
"""The project's two commands, needing nothing but a supported CPython on the machine
(3.11 to 3.14: every version GTSAM 4.3.0 and the other pinned dependencies publish
wheels for; pyproject.toml's requires-python says the same):

    python3 dev.py demo    # create .venv if missing, run the main job (a simulated survey)
    python3 dev.py test    # create .venv if missing, lint, run the whole test suite

Each Python version gets an environment of its own: the first one used makes .venv/,
another one .venv-3.X/ beside it (`python3.13 dev.py test`), so they never mix.
`python3 dev.py bench` runs every benchmark script. Extra arguments after the task
go to the command it runs (agrislam simulate / pytest).
"""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
PYPROJECT = ROOT / "pyproject.toml"
VERSION = sys.version_info[:2]


def supported_versions() -> tuple[tuple[int, int], tuple[int, int]]:
    """(oldest, first unsupported) minor version of pyproject's requires-python."""
    found = re.search(
        r'requires-python\s*=\s*">=(\d+)\.(\d+),\s*<(\d+)\.(\d+)"', PYPROJECT.read_text()
    )
    if found is None:
        sys.exit('pyproject.toml: requires-python must read ">=3.X,<3.Y"')
    a, b, c, d = (int(v) for v in found.groups())
    return (a, b), (c, d)


def check_version() -> None:
    oldest, beyond = supported_versions()
    if not (sys.implementation.name == "cpython" and oldest <= VERSION < beyond):
        newest = f"{beyond[0]}.{beyond[1] - 1}"
        sys.exit(
            f"agrislam needs CPython {oldest[0]}.{oldest[1]} to {newest} "
            f"(this is {sys.implementation.name} {sys.version.split()[0]})"
        )


def venv_version(folder: Path) -> tuple[int, int] | None:
    """The Python version a virtual environment was made with (None: no environment)."""
    cfg = folder / "pyvenv.cfg"
    found = cfg.exists() and re.search(r"^version\w*\s*=\s*(\d+)\.(\d+)", cfg.read_text(), re.M)
    return (int(found.group(1)), int(found.group(2))) if found else None


def venv_folder() -> Path:
    """.venv if it is this version's (or does not exist yet), else .venv-3.X."""
    default = ROOT / ".venv"
    if venv_version(default) in (None, VERSION):
        return default
    return ROOT / f".venv-{VERSION[0]}.{VERSION[1]}"


VENV = venv_folder()
BIN = VENV / ("Scripts" if sys.platform == "win32" else "bin")
STAMP = VENV / ".installed"


def ensure_env() -> None:
    """Create the virtual environment and install the project with its test extra,
    again whenever pyproject.toml changed."""
    check_version()
    wanted = hashlib.sha256(PYPROJECT.read_bytes()).hexdigest()
    if STAMP.exists() and STAMP.read_text() == wanted:
        return
    if not (BIN / "python").exists():
        venv.create(VENV, with_pip=True)
    pip = [str(BIN / "python"), "-m", "pip", "install", "--quiet"]
    subprocess.run([*pip, "--upgrade", "pip"], check=True)
    subprocess.run([*pip, "-e", f"{ROOT}[test]"], check=True)
    STAMP.write_text(wanted)


def run(*cmd: str) -> int:
    return subprocess.run(cmd, cwd=ROOT).returncode


def main() -> int:
    task, *extra = sys.argv[1:] or ["--help"]
    if task not in ("demo", "test", "bench"):
        print(__doc__)
        return 0 if task in ("-h", "--help") else 2
    ensure_env()
    if task == "demo":
        return run(str(BIN / "agrislam"), "simulate", "--out", "runs/demo", *extra)
    if task == "test":
        print(f"CPython {sys.version.split()[0]} in {VENV.name}/", flush=True)
        return run(str(BIN / "ruff"), "check", "src", "tests", "benchmarks", "dev.py") or run(
            str(BIN / "python"), "-m", "pytest", "-m", "not slow", *extra
        )
    for script in sorted((ROOT / "benchmarks").glob("bench_*.py")):
        code = run(str(BIN / "python"), str(script), *extra)
        if code:
            return code
    return 0


if __name__ == "__main__":
    sys.exit(main())
