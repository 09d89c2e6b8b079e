"""The `agrislam` command line: pick a source, run the world model, write the outputs."""

from __future__ import annotations

import json
from typing import Annotated

import typer
from rich.console import Console

from agrislam import __version__
from agrislam.config import AgrislamConfig

app = typer.Typer(
    name="agrislam",
    help="Semantic SLAM for crop fields: a probabilistic map of every plant.",
    no_args_is_help=True,
    add_completion=False,
)
console = Console()


def _version(value: bool) -> None:
    if value:
        console.print(f"agrislam {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version.")
    ] = False,
) -> None:
    """Semantic SLAM for crop fields."""


@app.command("config")
def config_cmd(
    defaults: Annotated[
        bool, typer.Option("--defaults", help="Print every default value.")
    ] = False,
) -> None:
    """Show the configuration (`--defaults`: every parameter with its default, as JSON)."""
    cfg = AgrislamConfig()
    console.print_json(json.dumps(cfg.model_dump(mode="json", by_alias=True)))
