"""The `agrislam` command line: open a source, run the world model, write the outputs."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from agrislam import __version__
from agrislam.config import AgrislamConfig, load_mapping
from agrislam.pipeline import RunResult, run_survey
from agrislam.records import Record
from agrislam.sources import SourceError, open_source
from agrislam.world import WorldModel

app = typer.Typer(
    name="agrislam",
    help="Semantic SLAM for crop fields: a probabilistic map of every plant.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
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


ConfigOption = Annotated[
    Path | None,
    typer.Option("--config", "-c", exists=True, dir_okay=False, help="YAML/TOML/JSON config."),
]
OutOption = Annotated[Path, typer.Option("--out", "-o", help="Output folder.")]
SOURCE_SECTIONS = ("bag", "sim")  # config file sections for the source, not the world model


@app.command()
def simulate(
    preset: Annotated[
        str, typer.Option(help="Schema preset of the simulated field.")
    ] = "colour_size",
    plants: Annotated[int, typer.Option(min=1, help="Number of plants.")] = 400,
    seed: Annotated[int, typer.Option(help="Random seed; a run is deterministic per seed.")] = 1,
    out: OutOption = Path("runs/simulate"),
    record: Annotated[
        Path | None, typer.Option(help="Also write the simulated survey (.jsonl, or .mcap bag).")
    ] = None,
    config: ConfigOption = None,
) -> None:
    """Simulate a field survey and map it (default: the paper's 400-plant simulation)."""
    from agrislam.sources.simulated import simulation_uri

    _survey(simulation_uri(plants=plants, seed=seed, preset=preset), config, out, record=record)


@app.command()
def run(
    log: Annotated[
        str,
        typer.Argument(
            metavar="SOURCE",
            help="Survey log (.jsonl, .jsonl.gz), rosbag2 folder (sqlite3/MCAP), .mcap file, "
            "ROS 1 .bag, or a simulation (sim:?plants=400&seed=1&preset=colour_size).",
        ),
    ],
    config: ConfigOption = None,
    out: OutOption = Path("runs/run"),
    strict: Annotated[
        bool, typer.Option("--strict/--lenient", help="Stop at the first bad line, or skip it.")
    ] = False,
) -> None:
    """Map a recorded (or simulated) survey."""
    _survey(log, config, out, strict=strict)


def _survey(
    path_or_uri: str,
    config: Path | None,
    out: Path,
    *,
    strict: bool = False,
    record: Path | None = None,
) -> None:
    """Open the source, run the survey, print the source's report and the run's summary.
    The config file's ``bag:`` and ``sim:`` sections go to the source that reads them."""
    data = load_mapping(config) if config else {}
    sections = {name: data.pop(name, None) for name in SOURCE_SECTIONS}
    cfg = AgrislamConfig.model_validate(data)
    try:
        source = open_source(path_or_uri, cfg, strict=strict, **sections)
    except (FileNotFoundError, ValueError) as err:
        console.print(f"[red]{escape(str(err))}[/]", soft_wrap=True)
        raise typer.Exit(2) from None
    try:
        records: Iterable[Record] = source.records()
        if record is not None:
            records = list(records)
            _record(records, record)
            console.print(f"recorded the survey to [bold]{escape(str(record))}[/]")
        result = _run(records, cfg, out, f"mapping {source.name}")
    except SourceError as err:
        hint = " (use --lenient to skip bad lines)"
        console.print(f"[red]{escape(str(err))}[/]{hint}", soft_wrap=True)
        raise typer.Exit(1) from None
    console.print(source.report.summary(), markup=False, soft_wrap=True)
    _summary(result, out)


@app.command("config")
def config_cmd(
    defaults: Annotated[
        bool, typer.Option("--defaults", help="Print every default value.")
    ] = False,
    file: Annotated[Path | None, typer.Argument(help="A config file to check and show.")] = None,
) -> None:
    """Show a configuration with every value filled in (`--defaults`: the defaults), as JSON."""
    cfg = AgrislamConfig.load(file) if file and not defaults else AgrislamConfig()
    console.print_json(json.dumps(cfg.model_dump(mode="json", by_alias=True)))


# ----------------------------------------------------------------------- helpers


def _run(records: Iterable[Record], cfg: AgrislamConfig, out: Path, what: str) -> RunResult:
    total = len(records) if isinstance(records, list) else None
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
    ) as progress:
        task = progress.add_task(what, total=total)
        return run_survey(records, WorldModel(cfg), out, lambda: progress.advance(task))


def _record(records: list[Record], path: Path) -> None:
    if path.suffix == ".jsonl":
        from agrislam.sinks.jsonl import write_log

        write_log(records, path)
    else:
        from agrislam.sinks.rosbag import write_survey_bag

        write_survey_bag(records, path)


def _summary(result: RunResult, out: Path) -> None:
    objects = result.snapshot.objects
    frames = result.n_frames
    table = Table(title="agrislam run", show_header=False)
    table.add_row("objects mapped", str(len(objects)))
    table.add_row("frames", str(frames))
    table.add_row("wall time", f"{result.wall_seconds:.1f} s")
    total = result.snapshot.step_seconds() * 1e3
    if len(total):
        import numpy as np

        table.add_row(
            "step time (ms)",
            f"median {np.median(total):.1f}, p95 {np.percentile(total, 95):.1f}, "
            f"max {total.max():.1f}",
        )
    console.print(table)
    for issue, count in sorted(result.issues.items()):
        console.print(f"[yellow]{count} x {issue}[/]")
    if result.metrics is not None:
        from agrislam.evaluation import print_metrics

        print_metrics(result.metrics, console)
    console.print(f"outputs in [bold]{out}[/]: " + ", ".join(p.name for p in result.outputs))
