"""The `agrislam` command line: pick a source, run the world model, write the outputs."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from agrislam import __version__
from agrislam.config import AgrislamConfig, load_mapping
from agrislam.pipeline import RunResult, run_survey
from agrislam.records import Record
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
    from agrislam.sim.config import SimConfig
    from agrislam.sim.simulator import Simulator

    data = load_mapping(config) if config else {}
    sim_data = data.pop("sim", {})
    sim_cfg = SimConfig.model_validate(sim_data)
    sim_cfg = sim_cfg.model_copy(update={"seed": seed, "schema_": preset})
    sim_cfg.field.n_plants = plants
    cfg = AgrislamConfig.model_validate(data)
    simulator = Simulator(sim_cfg)
    records = list(simulator.records())
    if record is not None:
        _record(records, record)
        console.print(f"recorded the survey to [bold]{record}[/]")
    result = _run(records, cfg, out, f"simulating {plants} plants, seed {seed}")
    _summary(result, out)


@app.command()
def run(
    log: Annotated[
        Path,
        typer.Argument(
            exists=True,
            help="Survey log (.jsonl), rosbag2 folder (sqlite3/MCAP), .mcap file or ROS 1 .bag.",
        ),
    ],
    config: ConfigOption = None,
    out: OutOption = Path("runs/run"),
    strict: Annotated[
        bool, typer.Option("--strict/--lenient", help="Stop at the first bad line, or skip it.")
    ] = False,
) -> None:
    """Map a recorded survey."""
    data = load_mapping(config) if config else {}
    bag_data = data.pop("bag", None)
    cfg = AgrislamConfig.model_validate(data)
    if _is_bag(log):
        from agrislam.sources.rosbag import BagSourceConfig, open_bag_source

        records, report = open_bag_source(log, cfg, BagSourceConfig.model_validate(bag_data or {}))
        result = _run(records, cfg, out, f"mapping {log.name}")
    else:
        from agrislam.sources.jsonl import LogError, read_log

        records = read_log(log, strict=strict)
        try:
            result = _run(records, cfg, out, f"mapping {log.name}")
        except LogError as err:
            console.print(f"[red]{err}[/] (use --lenient to skip bad lines)")
            raise typer.Exit(1) from None
        report = records.report
    console.print(report.summary())
    _summary(result, out)


def _is_bag(path: Path) -> bool:
    return path.is_dir() or path.suffix in (".mcap", ".bag", ".db3")


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
