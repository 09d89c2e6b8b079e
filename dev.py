#!/usr/bin/env python3
"""The project's two commands, needing nothing but Python 3.11 on the machine:

    python3 dev.py demo    # create .venv if missing, run the main job (a simulated survey)
    python3 dev.py test    # create .venv if missing, lint, run the whole test suite

`python3 dev.py bench` runs every benchmark script. Extra arguments after the task
go to the command it runs (agrislam simulate / pytest).
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if sys.platform == "win32" else "bin")
STAMP = VENV / ".installed"


def ensure_env() -> None:
    """Create the virtual environment and install the project with its test extra,
    again whenever pyproject.toml changed."""
    wanted = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if STAMP.exists() and STAMP.read_text() == wanted:
        return
    if sys.version_info[:2] != (3, 11):
        sys.exit(f"agrislam needs Python 3.11 (this is {sys.version.split()[0]})")
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
        return run(str(BIN / "ruff"), "check", "src", "tests", "benchmarks", "dev.py") or run(
            str(BIN / "python"), "-m", "pytest", "-m", "not slow", *extra
        )
    for script in sorted((ROOT / "benchmarks").glob("bench_*.py")):
        if code := run(str(BIN / "python"), str(script), *extra):
            return code
    return 0


if __name__ == "__main__":
    sys.exit(main())
