"""The `agrislam` command line: open a source, run the world model, write the outputs.

A user error (a bad config value, an input it cannot read, a bad line in strict mode, an
output folder in use) ends a command with one message saying what, where and what to do,
and a non-zero exit code: 2 before anything ran, 1 for a run that stopped or found no
usable data, 130 for Ctrl-C. A traceback only with `agrislam --debug ...`."""

from __future__ import annotations

import json
import signal
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
import yaml
from pydantic import ValidationError
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from agrislam import __version__
from agrislam.config import AgrislamConfig, load_mapping
from agrislam.io.sinks.run_folder import RunFolder
from agrislam.io.sources import Source, SourceError, open_source
from agrislam.records import Record
from agrislam.run.checkpoint import Checkpoints, InputFingerprint, config_identity
from agrislam.run.health import print_health
from agrislam.run.pipeline import RunError, RunResult, describe, run_survey
from agrislam.run.season import SeasonRun
from agrislam.world import WorldModel

app = typer.Typer(
    name="agrislam",
    help="Semantic SLAM for crop fields: a probabilistic map of every plant.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console()
DEBUG = {"on": False}  # set by the global --debug option
STOP = {"requested": False}  # set by Ctrl-C or SIGTERM during a run


def _version(value: bool) -> None:
    if value:
        console.print(f"agrislam {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version.")
    ] = False,
    debug: Annotated[
        bool, typer.Option("--debug", help="Show the full traceback of an error.")
    ] = False,
) -> None:
    """Semantic SLAM for crop fields."""
    DEBUG["on"] = debug


ConfigOption = Annotated[
    Path | None,
    typer.Option("--config", "-c", exists=True, dir_okay=False, help="YAML/TOML/JSON config."),
]
OutOption = Annotated[Path, typer.Option("--out", "-o", help="Output folder.")]
ForceOption = Annotated[
    bool,
    typer.Option("--force", help="Replace the outputs of an earlier run in the --out folder."),
]
FormatOption = Annotated[
    list[str] | None,
    typer.Option(
        "--format",
        help="Georeferenced map files, repeatable: geojson, gpkg, isoxml (weeds as an "
        "ISOBUS prescription), shapefile (the same, zipped); default geojson and gpkg.",
    ),
]
SOURCE_SECTIONS = ("bag", "sim")  # config file sections for the source, not the world model


@app.command(context_settings={"allow_extra_args": True})
def simulate(
    ctx: typer.Context,
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
    force: ForceOption = False,
    formats: FormatOption = None,
    days: Annotated[
        list[float] | None,
        typer.Option(
            help="A season: one survey log per day (--days 0 7 14), each mapped on the "
            "previous day's map, its robot starting at an unknown place.",
        ),
    ] = None,
) -> None:
    """Simulate a field survey and map it (default: the paper's 400-plant simulation)."""
    from agrislam.io.sources.simulated import simulation_uri

    if days:
        _season(days + _numbers(ctx.args), preset, plants, seed, out, config, force)
        return
    if ctx.args:
        _fail(f"unexpected arguments {' '.join(ctx.args)}", 2)
    uri = simulation_uri(plants=plants, seed=seed, preset=preset)
    _survey(uri, config, out, record=record, force=force, formats=formats)


def _numbers(args: list[str]) -> list[float]:
    """The further values of --days (`--days 0 7 14`: typer takes the first only)."""
    try:
        return [float(a) for a in args]
    except ValueError:
        _fail(f"--days takes numbers, got {' '.join(args)}", 2)


def _season(
    days: list[float],
    preset: str,
    plants: int,
    seed: int,
    out: Path,
    config: Path | None,
    force: bool,
) -> None:
    """Each survey day as a log of its own (OUT/day_007.jsonl) mapped into OUT/day_007/,
    every day after the first continuing the previous day's map.sqlite."""
    from agrislam.io.sinks.jsonl import write_log
    from agrislam.sim.config import SimConfig
    from agrislam.sim.season import SeasonSimulator, season_config

    if sorted(days) != days or len(set(days)) != len(days):
        _fail(f"--days must increase, got {days}", 2)
    names = [f"day_{day:03g}" for day in days]
    earlier = [f"{name}.jsonl" for name in names if (out / f"{name}.jsonl").exists()]
    if earlier and not force:  # each day's run checks its own folder; the logs are here
        _fail(
            f"--out {out} holds the logs of an earlier season ({', '.join(earlier)}); use "
            "--force to replace them, or choose another --out",
            2,
        )
    with _user_errors():
        data = load_mapping(config) if config else {}
        base = SimConfig.model_validate({**(data.get("sim") or {}), "seed": seed})
        base.field.n_plants = plants
        base.schema_ = base.schema_ if "schema" in (data.get("sim") or {}) else preset
        sim = SeasonSimulator(season_config(base, days))
        out.mkdir(parents=True, exist_ok=True)
    previous = None
    for d, name in enumerate(names):
        log = out / f"{name}.jsonl"
        write_log(sim.day_records(d), log)
        console.print(f"[bold]{name}[/]: survey log {escape(str(log))}")
        _survey(str(log), config, out / name, force=force, prior_map=previous)
        previous = out / name / "map.sqlite"


@app.command()
def history(
    map_file: Annotated[Path, typer.Argument(metavar="MAP", exists=True, dir_okay=False)],
    plant: Annotated[int | None, typer.Option(help="One plant's rows over the surveys.")] = None,
    plot: Annotated[
        Path | None, typer.Option(help="Write the change map and growth curves (PNG).")
    ] = None,
) -> None:
    """A saved map's season: its surveys and what changed, or one plant's history."""
    from agrislam.io.sinks.history import read_history
    from agrislam.io.sinks.season_figures import growth_attribute, write_season_figure
    from agrislam.io.sinks.sqlite import load_map
    from agrislam.run.saved_map import check_map_file, reading

    with _user_errors():
        check_map_file(map_file, label="MAP", continuing=False)
        with reading(map_file, "MAP"):
            hist = read_history(map_file)
            wanted = plant is not None or plot is not None
            schema = load_map(map_file).schema if wanted else None
    if not hist.surveys:
        _fail(f"{map_file}: no history (a map written by an older agrislam)", 1)
    if plant is not None:
        rows = hist.plant(plant)
        if not rows:
            _fail(f"plant {plant} is not in {map_file}", 1)
        table = Table("survey", "status", "x", "y", "n_meas", "interest", "P(gone)", "beliefs")
        for r in rows:
            gone = "" if r["p_gone"] is None else f"{r['p_gone']:.3f}"
            beliefs = _belief_text(r["beliefs"], schema)
            table.add_row(
                str(r["survey"]),
                r["status"],
                f"{r['x']:.3f}",
                f"{r['y']:.3f}",
                str(r["n_meas"]),
                f"{r['interest']:.3f}",
                gone,
                beliefs,
            )
        console.print(table)
    else:
        table = Table("survey", "day", "localised", "kept", "gone", "new", "not looked at")
        t0 = hist.surveys[0][1]
        for survey, t_abs, localised, summary in hist.surveys:
            changes = json.loads(summary).get("changes") or {}
            counts = [str(changes.get(k, "")) for k in ("kept", "gone", "new", "not_looked_at")]
            day = f"{(t_abs - t0) / 86_400:.1f}"
            table.add_row(str(survey), day, "yes" if localised else "-", *counts)
        console.print(table)
    if plot is not None:
        with _user_errors(), _writing("--plot", plot):
            plot.parent.mkdir(parents=True, exist_ok=True)
            write_season_figure(hist, plot, growth_attribute(schema))
        console.print(f"wrote {escape(str(plot))}")


def _belief_text(beliefs: dict[str, list[float]], schema: Any) -> str:
    """Most probable value and its probability per discrete attribute, mean +- std per
    continuous one."""
    parts = []
    for name, v in beliefs.items():
        if schema is not None and name in schema.discrete:
            k = max(range(len(v)), key=v.__getitem__)
            parts.append(f"{name} {schema.discrete[name].values[k]} {v[k]:.2f}")
        else:
            parts.append(f"{name} {v[0]:.3f}+-{max(v[1], 0.0) ** 0.5:.3f}")
    return ", ".join(parts)


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
    force: ForceOption = False,
    formats: FormatOption = None,
    resume: Annotated[
        bool,
        typer.Option(
            "--resume",
            help="Carry on a killed or stopped run in --out from its last checkpoint "
            "(same input and config); without one, start from the first record.",
        ),
    ] = False,
    prior_map: Annotated[
        Path | None,
        typer.Option(
            "--map",
            exists=True,
            dir_okay=False,
            help="Continue this saved map.sqlite: re-localise in it, keep its plants' ids, "
            "list what changed.",
        ),
    ] = None,
) -> None:
    """Map a recorded (or simulated) survey."""
    _survey(
        log,
        config,
        out,
        strict=strict,
        force=force,
        formats=formats,
        resume=resume,
        prior_map=prior_map,
    )


def _survey(
    path_or_uri: str,
    config: Path | None,
    out: Path,
    *,
    strict: bool = False,
    record: Path | None = None,
    force: bool = False,
    formats: list[str] | None = None,
    resume: bool = False,
    prior_map: Path | None = None,
) -> None:
    """Open the source, run the survey, print the source's report and the run's summary.
    The config file's ``bag:`` and ``sim:`` sections go to the source that reads them.
    Everything that can be checked before mapping is checked first: the config, the
    source, the output folder."""
    with _user_errors():
        data = load_mapping(config) if config else {}
        sections = {name: data.pop(name, None) for name in SOURCE_SECTIONS}
        if formats:
            data.setdefault("outputs", {})["formats"] = formats
        cfg = _validated(AgrislamConfig, data, config)
        if resume and force:
            raise ValueError("--resume carries on the run in --out, --force replaces it: give one")
        if resume and prior_map is not None:  # a checkpoint does not hold the season's state
            raise ValueError(
                "--resume of a run that continues a saved map (--map) is not supported"
            )
        source = open_source(path_or_uri, cfg, strict=strict, **sections)
        identity = config_identity(cfg, strict=strict, **sections)
        season = _season_of(prior_map, cfg)
        inputs = {
            "the input": Path(path_or_uri) if Path(path_or_uri).exists() else None,
            "--config": config,
            "--map": prior_map,
            "--record": record,
        }
        with RunFolder(out, force=force, resume=resume, inputs=inputs) as folder:
            checkpoints = Checkpoints(
                folder.path / "map.sqlite",
                InputFingerprint(path_or_uri),
                identity,
                cfg.checkpoint,
            )
            if folder.replaced:
                console.print(f"--force: replaced the earlier run's {', '.join(folder.replaced)}")
            records: Iterable[Record] | Source = source
            if record is not None:
                records = list(source.records())
                _record(records, record)
                console.print(f"recorded the survey to [bold]{escape(str(record))}[/]")
            try:
                with _stop_between_records():
                    result = _run(
                        records,
                        cfg,
                        folder,
                        f"mapping {source.name}",
                        checkpoints,
                        resume,
                        season,
                    )
            except RunError as err:
                _stopped(err, out, strict)
    console.print(source.report.summary(), markup=False, soft_wrap=True)
    _summary(result, out)
    if not result.usable:
        _fail(f"{source.name}: no usable data (no odometry or detections were read)", 1)


@contextmanager
def _stop_between_records() -> Iterator[None]:
    """Ctrl-C or SIGTERM (a scheduler stopping the run) ends the run after the record in
    hand, so the map written of what was read is whole; a second one stops at once.
    (kill -9 cannot be caught: the outputs are atomic, and the lock is the OS's.)"""

    def request(signum: int, frame: Any) -> None:
        if STOP["requested"]:
            raise KeyboardInterrupt
        STOP["requested"] = True

    STOP["requested"] = False
    try:
        previous = {sig: signal.signal(sig, request) for sig in (signal.SIGINT, signal.SIGTERM)}
    except ValueError:  # not the main thread: signals stay as they are
        yield
        return
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _advance(progress: Progress, task: Any) -> None:
    """After each record: the progress bar, and a requested stop."""
    progress.advance(task)
    if STOP["requested"]:
        raise KeyboardInterrupt


@contextmanager
def _user_errors() -> Iterator[None]:
    """Errors of the user's input as one message and an exit code; a traceback only with
    --debug."""
    try:
        yield
    except (typer.Exit, typer.Abort):
        raise
    except Exception as err:
        if DEBUG["on"]:
            raise
        if isinstance(err, ValidationError):  # a source's config section (sim:, bag:)
            _fail(f"{err.title}: {_problems(err)}", 2)
        if isinstance(err, (OSError, ValueError, yaml.YAMLError)):  # config, source, --out
            _fail(str(err) or describe(err), 2)
        _fail(
            f"internal error: {describe(err)} (run again with --debug for the traceback, and "
            "please report it)",
            3,
        )


@contextmanager
def _writing(option: str, path: Path) -> Iterator[None]:
    """A file the user named that cannot be written (no such folder and none can be made,
    no permission, a folder of that name) as one line naming the option."""
    try:
        yield
    except OSError as err:
        why = err.strerror or str(err)
        raise ValueError(
            f"{option} {path} cannot be written ({why}): choose a file in a folder you may write to"
        ) from None


def _validated(model: Any, data: dict[str, Any], path: Path | None) -> Any:
    """The config model of `data`; bad values are one line naming each key."""
    try:
        return model.model_validate(data)
    except ValidationError as err:
        where = f"config {path}" if path else "config"
        raise ValueError(f"{where}: {_problems(err)}") from None


def _problems(err: ValidationError) -> str:
    """Every problem of a pydantic error on one line."""
    return "; ".join(_problem(e) for e in err.errors())


def _problem(error: Any) -> str:
    """One pydantic error as 'key.path: what (got value)'."""
    key = ".".join(str(p) for p in error["loc"]) or "(top level)"
    if error["type"] == "extra_forbidden":
        return f"{key}: unknown key (every key: agrislam config --defaults --all)"
    what = str(error["msg"]).removeprefix("Value error, ")
    value = error.get("input")
    got = "" if isinstance(value, (dict, list)) else f" (got {value!r})"
    return f"{key}: {what}{got}"


def _stopped(err: RunError, out: Path, strict: bool) -> NoReturn:
    """A run that stopped: why, what it read, and what of it was written."""
    result, cause = err.result, err.__cause__
    if DEBUG["on"] and not isinstance(cause, SourceError):
        raise err
    if isinstance(cause, SourceError):
        fatal = getattr(cause, "fatal", False)
        hint = "" if fatal or not strict else " (use --lenient to skip bad lines)"
        if fatal:
            hint = " (the meta line is the survey's contract: fix it; --lenient does not skip it)"
        console.print(f"[red]{escape(str(cause))}[/]{hint}", soft_wrap=True)
    elif isinstance(cause, KeyboardInterrupt):
        console.print("[red]interrupted[/]")
    else:  # not the input's fault: an error of agrislam itself
        console.print(
            f"[red]the run stopped: {escape(describe(cause or err))}[/] (run again with "
            "--debug for the traceback, and please report it)",
            soft_wrap=True,
        )
    if result.outputs:
        console.print(
            f"the map of the {result.n_frames} frames before it is in "
            f"[bold]{escape(str(out))}[/]: " + ", ".join(p.name for p in result.outputs),
            soft_wrap=True,
        )
    else:
        console.print("nothing was mapped: no outputs written")
    for name, why in result.output_errors.items():
        console.print(f"[yellow]{name} not written: {escape(why)}[/]", soft_wrap=True)
    raise typer.Exit(130 if isinstance(cause, KeyboardInterrupt) else 1)


def _fail(message: str, code: int) -> NoReturn:
    console.print(f"[red]{escape(message)}[/]", soft_wrap=True)
    raise typer.Exit(code)


ListenOption = Annotated[
    str | None, typer.Option("--listen", help="Zenoh endpoint to listen on as a peer.")
]
ConnectOption = Annotated[
    str | None,
    typer.Option("--connect", help="Zenoh endpoint to join (rmw_zenoh: tcp/localhost:7447)."),
]


def _config_sections(config: Path | None) -> tuple[AgrislamConfig, dict[str, Any]]:
    """The config file's model and its source sections (``bag:``, ``sim:``)."""
    data = load_mapping(config) if config else {}
    sections = {name: data.pop(name, None) for name in SOURCE_SECTIONS}
    return _validated(AgrislamConfig, data, config), sections


@app.command()
def live(
    config: ConfigOption = None,
    out: OutOption = Path("runs/live"),
    listen: ListenOption = None,
    connect: ConnectOption = None,
    force: ForceOption = False,
) -> None:
    """Map the robots live over Zenoh (as a ROS 2 node on rmw_zenoh), publishing the map;
    every message goes to OUT/live.mcap. Ctrl-C or SIGTERM writes the outputs of `run`."""
    from agrislam.io.sources.bag_config import BagSourceConfig
    from agrislam.live.mapper import LiveMapper, run_live

    def on_start(mapper: LiveMapper) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: mapper.stop())
        console.print(f"mapping live (Ctrl-C to stop and write the outputs to {out})")

    with _user_errors():
        cfg, sections = _config_sections(config)
        bag = BagSourceConfig.model_validate(sections["bag"] or {})
        with RunFolder(out, force=force) as folder:
            try:
                result, stats = run_live(cfg, folder, listen, connect, on_start, bag)
            except RunError as err:
                _stopped(err, out, strict=False)
    console.print_json(json.dumps(stats.as_dict()))
    _summary(result, out)


@app.command()
def replay(
    source: Annotated[str, typer.Argument(metavar="LOG_OR_BAG", help="A survey to publish.")],
    rate: Annotated[
        float, typer.Option(help="Times real time; 0: as fast as the live node takes it.")
    ] = 1.0,
    config: ConfigOption = None,
    listen: ListenOption = None,
    connect: ConnectOption = None,
) -> None:
    """Publish a recorded survey on the robots' topics, for `agrislam live` to map."""
    from agrislam.live.node import LiveNode
    from agrislam.live.replay import recorded_messages
    from agrislam.live.replay import replay as publish

    with _user_errors():
        cfg, sections = _config_sections(config)
        node = LiveNode.open(
            _message_store(),
            listen,
            connect,
            name=f"{cfg.advanced.live.node_name}_replay",
            domain=cfg.live.domain_id,
            scheme=cfg.live.namespaces,
        )
        try:
            messages = recorded_messages(source, cfg, sections)
            done = publish(node, messages, rate, cfg.advanced.live.replay_wait_s)
        finally:
            node.close()
    console.print(f"published {done.published} messages in {done.seconds:.1f} s")
    for msgtype, count in done.skipped.items():
        console.print(f"[yellow]{count} x {msgtype} not published: no definition of it[/]")


def _message_store() -> Any:
    from agrislam.io.ros.messages import typestore

    return typestore("humble")


@app.command("config")
def config_cmd(
    defaults: Annotated[
        bool, typer.Option("--defaults", help="Show the defaults (no file needed).")
    ] = False,
    every: Annotated[
        bool, typer.Option("--all", help="Show the `advanced` section too: every field.")
    ] = False,
    file: Annotated[Path | None, typer.Argument(help="A config file to check and show.")] = None,
) -> None:
    """Show a configuration with its values filled in, as JSON: the fields a user sets
    (`--all`: every field, the `advanced` ones too); `--defaults`: the defaults."""
    with _user_errors():
        data = load_mapping(file) if file and not defaults else {}
        cfg = _validated(AgrislamConfig, data, file)
    hidden = None if every else {"advanced"}
    console.print_json(json.dumps(cfg.model_dump(mode="json", by_alias=True, exclude=hidden)))


# ----------------------------------------------------------------------- helpers


def _run(
    records: Iterable[Record] | Source,
    cfg: AgrislamConfig,
    out: RunFolder,
    what: str,
    checkpoints: Checkpoints,
    resume: bool,
    season: SeasonRun | None = None,
) -> RunResult:
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
        result = run_survey(
            records,
            WorldModel(cfg),
            out,
            lambda: _advance(progress, task),
            checkpoints=checkpoints,
            resume=resume,
            season=season,
            release_world=True,  # nothing here reads the world after the run
        )
    if resume:
        at = (result.checkpoints or {}).get("resumed_at_record")
        console.print(
            f"resumed from the checkpoint at record {at}"
            if at is not None
            else "no checkpoint in --out to resume from: mapped from the first record"
        )
    return result


def _season_of(prior_map: Path | None, cfg: AgrislamConfig) -> SeasonRun | None:
    """The saved map a survey continues, read and checked before its output folder is
    touched (a bad one is a `MapFileError`)."""
    if prior_map is None:
        return None
    from agrislam.run.season_outputs import load_season

    return load_season(prior_map, cfg)


def _record(records: list[Record], path: Path) -> None:
    if path.suffix == ".jsonl":
        from agrislam.io.sinks.jsonl import write_log

        write_log(records, path)
    else:
        from agrislam.io.sinks.rosbag import write_survey_bag

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
    noise = result.noise
    if noise and noise["enabled"]:
        factors = ", ".join(f"{k} x{v:.2f}" for k, v in noise["sigma_factors"].items())
        table.add_row("noise scales", f"{factors} ({noise['pairs_used']} pairs of sightings)")
    for robot, terms in (result.sensor or {}).items():
        used = [
            f"{name} {t['estimate']:+.3f} ± {t['sigma']:.3f}"
            for name, t in terms.items()
            if isinstance(t, dict) and t["used"]
        ]
        if used:
            table.add_row(f"sensor biases {robot}", ", ".join(used))
    console.print(table)
    print_health(result.health, console)
    for issue, count in sorted(result.issues.items()):
        console.print(f"[yellow]{count} x {issue}[/]")
    if result.metrics is not None:
        from agrislam.evaluation.metrics import print_metrics

        print_metrics(result.metrics, console)
    for name, why in result.output_errors.items():
        console.print(f"[yellow]{name} not written: {escape(why)}[/]", soft_wrap=True)
    skipped = getattr(result.source_report, "n_skipped", 0)
    if skipped:
        console.print(f"[yellow]{skipped} bad lines skipped: each is listed in skipped.csv[/]")
    console.print(f"outputs in [bold]{out}[/]: " + ", ".join(p.name for p in result.outputs))
