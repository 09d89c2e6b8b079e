"""`report.png`: one page a farmer can read. The map coloured by attribute (opacity = how
sure the map is), the interest surface (where a second look pays off), the trajectories and
where each step's time went; drawn with matplotlib's object API on the Agg canvas, plants as
rasterised scatter points so that a whole field draws quickly."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from agrislam.io.sinks.readouts import (
    continuous_scale,
    continuous_sureness,
    discrete_columns,
    discrete_sureness,
    most_probable,
    opacity,
    value_colours,
)
from agrislam.snapshot import MapSnapshot, Trajectory

REAL_TIME_BUDGET_MS = 1000.0  # real time: one frame per second (sec. 3.1.3)
PANEL_WIDTH_IN = 5.0  # one field map's axes
LEGEND_WIDTH_IN = 1.7  # its legend or colour bar, to the right
STEP_PANEL_HEIGHT_IN = 3.4
MARGIN_LEFT_IN, MARGIN_TOP_IN, MARGIN_BOTTOM_IN = 0.8, 0.65, 0.55  # labels and titles
DPI = 110
MAX_TOP_ATTRIBUTES = 3
MAX_STEP_BINS = 600
ROW_OVERHANG_M = 0.3  # a row line runs this far past its first and last plant
INTEREST_CMAP = "YlOrRd"
DISPLAY_CELLS = 1500  # interest surface cells a panel shows a side at most (~1,000 pixels)
HEADLINE_SEPARATOR = "   ·   "
SOURCE_STYLE = {  # trajectory kind -> line style
    "truth": {"color": "black", "lw": 2.2, "alpha": 0.45, "ls": "-"},
    "dead reckoning": {"color": "tab:red", "lw": 1.2, "alpha": 0.9, "ls": "--"},
    "optimised": {"color": "tab:blue", "lw": 1.4, "alpha": 0.95, "ls": "-"},
}


def write_report(
    snapshot: MapSnapshot,
    path: str | Path,
    metrics: Mapping[str, Any] | None = None,
    truth: Mapping[str, Trajectory] | None = None,
    title: str = "agrislam field map",
    dpi: int = DPI,
) -> Path:
    """Write `report.png`: attribute maps, interest surface, trajectories and step times;
    `metrics` (e.g. metrics.json) give the headline, `truth` the true trajectories."""
    extent = _field_extent(snapshot)
    attributes = _attribute_names(snapshot)[:MAX_TOP_ATTRIBUTES] or [None]
    field_panels: list[Any] = [*attributes, "interest", "trajectories"]
    title_lines = _title_lines(snapshot, title, metrics)
    fig, field_axes, step_axes = _layout(len(field_panels), extent, True, title_lines)
    for ax, panel in zip(field_axes, field_panels, strict=True):
        if panel == "interest":
            _draw_interest(ax, snapshot, extent)
        elif panel == "trajectories":
            _draw_trajectories(ax, snapshot, truth)
        else:
            _draw_attribute(ax, snapshot, panel, extent)
    assert step_axes is not None
    _draw_step_times(step_axes, snapshot.step_times)
    return _save(fig, path, dpi)


def write_attribute_maps(
    snapshot: MapSnapshot,
    path: str | Path,
    title: str = "agrislam attribute maps",
    dpi: int = DPI,
) -> Path:
    """One map per attribute of the schema (all of them), coloured by its estimate."""
    extent = _field_extent(snapshot)
    attributes = _attribute_names(snapshot) or [None]
    fig, axes, _ = _layout(len(attributes), extent, False, _title_lines(snapshot, title, None))
    for ax, name in zip(axes, attributes, strict=True):
        _draw_attribute(ax, snapshot, name, extent)
    return _save(fig, path, dpi)


# ------------------------------------------------------------------------------ layout


def _layout(
    n_field: int,
    extent: tuple[float, float, float, float],
    step_panel: bool,
    title_lines: list[str],
) -> tuple[Figure, list[Axes], Axes | None]:
    """Field panels on a grid sized to the field's shape (3 across for a square field, 1 for
    a long strip), each with room for its legend on the right; the step-time panel fills the
    last row's free cells, or a row of its own. Placed by hand: constrained layout is slow."""
    width, height = extent[1] - extent[0], extent[3] - extent[2]
    ratio = width / max(height, 1e-9)
    ncols = min(n_field, 3 if ratio < 1.6 else 2 if ratio < 3.5 else 1)
    nrows = math.ceil(n_field / ncols)
    free = nrows * ncols - n_field
    own_row = step_panel and free == 0
    axes_w = PANEL_WIDTH_IN if ncols > 1 else 2.0 * PANEL_WIDTH_IN
    axes_h = float(np.clip(axes_w / ratio, 1.6, 1.3 * PANEL_WIDTH_IN))
    cell_w, cell_h = MARGIN_LEFT_IN + axes_w + LEGEND_WIDTH_IN, MARGIN_TOP_IN + axes_h + 0.6
    title_h = 0.2 + 0.28 * len(title_lines)
    heights = [cell_h] * nrows + ([STEP_PANEL_HEIGHT_IN] if own_row else [])
    fig_w, fig_h = cell_w * ncols, sum(heights) + title_h
    fig = Figure(figsize=(fig_w, fig_h))
    tops = fig_h - title_h - np.concatenate([[0.0], np.cumsum(heights)])

    def place(row: int, col: int, span: int = 1) -> Axes:
        """Axes in grid cell (row, col) spanning `span` columns, less the margins."""
        left = col * cell_w + MARGIN_LEFT_IN
        right = (col + span) * cell_w - LEGEND_WIDTH_IN
        top, bottom = tops[row] - MARGIN_TOP_IN, tops[row + 1] + MARGIN_BOTTOM_IN
        ax = fig.add_axes(
            (left / fig_w, bottom / fig_h, (right - left) / fig_w, (top - bottom) / fig_h)
        )
        ax.set_anchor("C")
        return ax

    axes = [place(i // ncols, i % ncols) for i in range(n_field)]
    steps = None
    if step_panel:
        steps = place(nrows, 0, ncols) if own_row else place(nrows - 1, ncols - free, free)
    fig.suptitle(
        "\n".join(title_lines), y=1.0 - 0.15 / fig_h, va="top", fontsize=13, fontweight="bold"
    )
    return fig, axes, steps


def _title_lines(snapshot: MapSnapshot, title: str, metrics: Mapping[str, Any] | None) -> list[str]:
    robots = sorted({*snapshot.trajectories, *snapshot.dead_reckoning})
    first = f"{title}: {len(snapshot.objects):,} plants mapped"
    if robots:
        first += f", {len(robots)} robot{'s' * (len(robots) != 1)}"
    return [first, *_headline(metrics or {})]


def _headline(metrics: Mapping[str, Any]) -> list[str]:
    """Headline lines under the title: the evaluation's key numbers when `metrics` is what
    agrislam.evaluation.metrics writes (metrics.json), else its first scalar entries."""
    return _evaluation_headline(metrics) or _scalar_headline(metrics)


def _evaluation_headline(metrics: Mapping[str, Any]) -> list[str]:
    """'mapped 398/400 plants (99.5 %)', attribute accuracies, trajectory RMS, ..."""
    first, second = [], []
    objects = _mapping(metrics.get("objects"))
    if objects.get("n_truth"):
        mapped, n = objects.get("mapped", 0), objects["n_truth"]
        first.append(f"mapped {mapped}/{n} plants ({mapped / n:.1%})")
        first.append(
            f"{objects.get('duplicates', 0)} duplicates, {objects.get('false_objects', 0)} false"
        )
    if objects.get("position_rms") is not None:
        first.append(f"position RMS {objects['position_rms']:.3f} m")
    association = _mapping(metrics.get("association"))
    if association.get("purity") is not None:
        first.append(
            f"association purity {association['purity']:.1%}, "
            f"completeness {association.get('completeness', float('nan')):.1%}"
        )
    for name, scores in _mapping(metrics.get("attributes")).items():
        scores = _mapping(scores)
        if scores.get("accuracy") is not None:
            second.append(f"{name} {scores['accuracy']:.1%} right")
        elif scores.get("rms") is not None:
            second.append(f"{name} RMS {scores['rms']:.3g}")
    trajectory = _mapping(metrics.get("trajectory"))
    optimised = _mapping(trajectory.get("optimised")).get("rms_position")
    dead = _mapping(trajectory.get("dead_reckoning")).get("rms_position")
    if optimised is not None:
        second.append(
            f"trajectory RMS {optimised:.3f} m"
            + (f" (dead reckoning {dead:.3f} m)" if dead is not None else "")
        )
    return [*_lines(first, 3), *_lines(second, 3)]


def _scalar_headline(metrics: Mapping[str, Any], per_line: int = 4, most: int = 8) -> list[str]:
    scalars = [(key, value) for key, value in _flatten(metrics) if _is_scalar(value)]
    return _lines([f"{key}: {_fmt(value)}" for key, value in scalars[:most]], per_line)


def _lines(items: list[str], per_line: int) -> list[str]:
    """Items joined a few to a line."""
    return [
        HEADLINE_SEPARATOR.join(items[i : i + per_line]) for i in range(0, len(items), per_line)
    ]


def _mapping(value: Any) -> Mapping[str, Any]:
    return value if isinstance(value, Mapping) else {}


def _flatten(metrics: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for key, value in metrics.items():
        name = f"{prefix}{key}"
        out += _flatten(value, name + ".") if isinstance(value, Mapping) else [(name, value)]
    return out


def _is_scalar(value: Any) -> bool:
    return isinstance(value, (int, float, str, np.integer, np.floating)) and not isinstance(
        value, bool
    )


def _fmt(value: Any) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{value:.3g}"
    return str(value)


def _save(fig: Figure, path: str | Path, dpi: int) -> Path:
    path = Path(path)
    fig.savefig(path, dpi=dpi, facecolor="white")
    return path


# ----------------------------------------------------------------------- field panels


def _field_extent(snapshot: MapSnapshot) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) around the plants, else the surface, else the trajectories."""
    xy = _finite(np.asarray(snapshot.objects.xy, dtype=float).reshape(-1, 2))
    if len(xy) == 0 and snapshot.interest_surface is not None:
        e = snapshot.interest_surface.extent
        xy = np.array([[e[0], e[2]], [e[1], e[3]]])
    return _extent_of(xy if len(xy) else _all_poses(snapshot, None))


def _extent_of(xy: np.ndarray) -> tuple[float, float, float, float]:
    """Bounding box of the finite points plus a margin (5 %, at least 0.5 m)."""
    xy = _finite(xy)
    if len(xy) == 0:
        return (-1.0, 1.0, -1.0, 1.0)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    margin = max(0.05 * float(np.max(hi - lo)), 0.5)
    return (lo[0] - margin, hi[0] + margin, lo[1] - margin, hi[1] + margin)


def _finite(xy: np.ndarray) -> np.ndarray:
    return xy[np.all(np.isfinite(xy), axis=1)]


def _all_poses(snapshot: MapSnapshot, truth: Mapping[str, Trajectory] | None) -> np.ndarray:
    trajs = [*snapshot.trajectories.values(), *snapshot.dead_reckoning.values()]
    trajs += list((truth or {}).values())
    poses = [np.asarray(t.poses, dtype=float).reshape(-1, 3)[:, :2] for t in trajs]
    return np.concatenate(poses) if poses else np.empty((0, 2))


def _field_axes(ax: Axes, extent: tuple[float, float, float, float], title: str) -> None:
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=11)
    ax.grid(True, color="0.88", lw=0.6, zorder=0)
    ax.set_axisbelow(True)


def _marker_size(ax: Axes, extent: tuple[float, float, float, float], n: int) -> float:
    """Scatter size (pt^2) of a plant ~0.12 m across at the panel's scale, kept visible: a
    few objects over a wide map (trees in a park) are drawn larger than their size."""
    fig_w_in = ax.figure.get_figwidth() * ax.get_position().width
    points_per_m = 72.0 * fig_w_in / max(extent[1] - extent[0], 1e-9)
    size = (0.12 * points_per_m) ** 2
    floor = max(0.4 if n > 20_000 else 2.0, min(4000.0 / max(n, 1), 25.0))
    return float(np.clip(size, floor, 60.0))


def _scatter(
    ax: Axes, xy: np.ndarray, colours: Any, size: float, zorder: float = 3, **kw: Any
) -> Any:
    edges = {"edgecolors": "0.25", "linewidths": 0.35} if len(xy) <= 5000 else {"linewidths": 0}
    return ax.scatter(
        xy[:, 0], xy[:, 1], c=colours, s=size, rasterized=True, zorder=zorder, **edges, **kw
    )


def _draw_rows(ax: Axes, snapshot: MapSnapshot) -> None:
    """Each fitted row {p : n . p = offset} (sec. 2.6.2) as a thin line over the stretch its
    plants cover (all plants' stretch for a row without assigned plants)."""
    rows = snapshot.rows
    if rows is None or len(rows.offsets) == 0:
        return
    offsets = np.asarray(rows.offsets, dtype=float)
    direction = np.array([math.cos(rows.angle), math.sin(rows.angle)])
    normal = np.array([-direction[1], direction[0]])
    xy = np.asarray(snapshot.objects.xy, dtype=float).reshape(-1, 2)
    along = xy @ direction
    start = np.full(len(offsets), along.min(initial=np.inf))
    end = np.full(len(offsets), along.max(initial=-np.inf))
    row = np.asarray(snapshot.objects.row).astype(np.int64)
    on_row = (row >= 0) & (row < len(offsets))
    if np.any(on_row):
        own_start, own_end = np.full(len(offsets), np.inf), np.full(len(offsets), -np.inf)
        np.minimum.at(own_start, row[on_row], along[on_row])
        np.maximum.at(own_end, row[on_row], along[on_row])
        has = np.isfinite(own_start)
        start[has], end[has] = own_start[has], own_end[has]
    if not np.all(np.isfinite(start)):  # no plants at all: nothing to measure a row by
        return
    pad = ROW_OVERHANG_M
    a = offsets[:, None] * normal + (start - pad)[:, None] * direction
    b = offsets[:, None] * normal + (end + pad)[:, None] * direction
    lines = LineCollection(
        np.stack([a, b], axis=1), colors="0.6", linewidths=0.7, linestyles=(0, (4, 3)), zorder=1
    )
    ax.add_collection(lines, autolim=False)
    ax.plot([], [], color="0.6", lw=0.7, ls=(0, (4, 3)), label="fitted row")


def _attribute_names(snapshot: MapSnapshot) -> list[str]:
    return [*snapshot.objects.discrete, *snapshot.objects.continuous]


def _draw_attribute(
    ax: Axes, snapshot: MapSnapshot, name: str | None, extent: tuple[float, float, float, float]
) -> None:
    """One attribute over the field; without one, how often each plant was seen."""
    if name is None:
        title = "plants: times seen (no attributes in the schema)"
    elif name in snapshot.objects.discrete:
        title = f"{name}: most probable value (faint = unsure)"
    else:
        title = f"{name}: estimate (faint = unsure)"
    _field_axes(ax, extent, title)
    xy = np.asarray(snapshot.objects.xy, dtype=float).reshape(-1, 2)
    size = _marker_size(ax, extent, len(xy))
    _draw_rows(ax, snapshot)
    if name is None:
        n_meas = np.asarray(snapshot.objects.n_meas, dtype=float)
        norm = Normalize(0, max(float(n_meas.max(initial=1)), 1))
        _colorbar(ax, _scatter(ax, xy, n_meas, size, cmap="viridis", norm=norm), "times seen")
        if ax.get_legend_handles_labels()[0]:  # the fitted rows
            ax.legend(loc="upper left", bbox_to_anchor=(1.3, 1.0), fontsize=8, frameon=False)
    elif name in snapshot.objects.discrete:
        _draw_discrete(ax, snapshot, name, xy, size)
    else:
        _draw_continuous(ax, snapshot, name, xy, size)


def _draw_discrete(ax: Axes, snapshot: MapSnapshot, name: str, xy: np.ndarray, size: float) -> None:
    values, belief = discrete_columns(snapshot)[name]
    top, p = most_probable(belief)
    palette = value_colours(name, values, snapshot)
    n = len(values)
    rgba = palette[top] if len(top) else np.empty((0, 4))
    rgba[:, 3] = opacity(discrete_sureness(p, n))
    _scatter(ax, xy, rgba, size)
    counts = np.bincount(top, minlength=n)
    handles = [
        Patch(facecolor=palette[j], edgecolor="0.25", label=f"{v} ({counts[j]})")
        for j, v in enumerate(values)
        if counts[j] > 0
    ]
    handles += [h for h in ax.get_legend_handles_labels()[0] if isinstance(h, Line2D)]
    ax.legend(
        handles=handles,
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        fontsize=8,
        title=name,
        title_fontsize=9,
        frameon=False,
    )


def _draw_continuous(
    ax: Axes, snapshot: MapSnapshot, name: str, xy: np.ndarray, size: float
) -> None:
    mean, var = (np.asarray(a, dtype=float) for a in snapshot.objects.continuous[name])
    lo, hi, prior_var = continuous_scale(snapshot, name, mean)
    norm = Normalize(lo, hi)
    rgba = colormaps["viridis"](norm(mean))
    rgba[:, 3] = opacity(continuous_sureness(var, prior_var))
    _scatter(ax, xy, rgba, size)
    sm = colormaps["viridis"]
    _colorbar(ax, ScalarMappable(norm=norm, cmap=sm), f"{name} (estimated mean)")


def _colorbar(ax: Axes, mappable: Any, label: str) -> None:
    """A colour bar hugging the right edge of a field panel."""
    cax = ax.inset_axes((1.04, 0.0, 0.045, 1.0))
    ax.figure.colorbar(mappable, cax=cax, label=label)


def coarsened(values: np.ndarray, most: int = DISPLAY_CELLS) -> tuple[np.ndarray, int]:
    """A grid's means over square blocks of `block` cells a side (returned with it), at most
    `most` blocks a side: a panel shows about a thousand pixels a side, and a whole field's
    surface of millions of cells drawn cell by cell costs memory in proportion to the field.
    The blocks of the last row and column reach past the grid, holding its edge values."""
    block = -(-max(values.shape) // most)
    if block <= 1:
        return values, 1
    ny, nx = (-(-n // block) * block for n in values.shape)
    padded = np.pad(values, ((0, ny - values.shape[0]), (0, nx - values.shape[1])), mode="edge")
    means = padded.reshape(ny // block, block, nx // block, block).mean(axis=(1, 3))
    return means.astype(np.float32), block


def _draw_interest(
    ax: Axes, snapshot: MapSnapshot, extent: tuple[float, float, float, float]
) -> None:
    """The interest surface (sec. 2.7) with the plants on top."""
    xy = np.asarray(snapshot.objects.xy, dtype=float).reshape(-1, 2)
    norm = Normalize(0.0, 1.0)
    surface = snapshot.interest_surface
    if surface is not None:
        values, block = coarsened(surface.values)
        x0, y0, res = surface.x0, surface.y0, surface.resolution * block
        ax.imshow(
            values,
            origin="lower",
            extent=(x0, x0 + values.shape[1] * res, y0, y0 + values.shape[0] * res),
            cmap=INTEREST_CMAP,
            norm=norm,
            interpolation="bilinear",
            zorder=1,
        )
        many = len(xy) > 5000
        ax.scatter(
            xy[:, 0],
            xy[:, 1],
            s=0.3 if many else 9.0,
            c="0.1",
            alpha=0.3 if many else 1.0,
            edgecolors="white",
            linewidths=0 if many else 0.6,
            rasterized=True,
            zorder=3,
            label="plants",
        )
    else:  # no surface: the heuristic per plant
        _scatter(
            ax,
            xy,
            np.asarray(snapshot.objects.interest, dtype=float),
            _marker_size(ax, extent, len(xy)),
            cmap=INTEREST_CMAP,
            norm=norm,
        )
    _colorbar(
        ax,
        ScalarMappable(norm=norm, cmap=colormaps[INTEREST_CMAP]),
        "interest h: 0 known, 1 worth a revisit",
    )
    _field_axes(ax, extent, "where to look again (interest heuristic)")


def _draw_trajectories(
    ax: Axes, snapshot: MapSnapshot, truth: Mapping[str, Trajectory] | None
) -> None:
    xy = np.asarray(snapshot.objects.xy, dtype=float).reshape(-1, 2)
    ax.scatter(
        xy[:, 0],
        xy[:, 1],
        s=1.0 if len(xy) > 5000 else 4.0,
        c="0.7",
        linewidths=0,
        rasterized=True,
        zorder=1,
        label="mapped plants",
    )
    groups = (
        ("truth", truth or {}),
        ("dead reckoning", snapshot.dead_reckoning),
        ("optimised", snapshot.trajectories),
    )
    for source, trajs in groups:
        for i, traj in enumerate(trajs.values()):
            poses = np.asarray(traj.poses, dtype=float).reshape(-1, 3)
            ax.plot(
                poses[:, 0],
                poses[:, 1],
                zorder=2,
                label=source if i == 0 else None,
                **SOURCE_STYLE[source],
            )
    starts = snapshot.trajectories or snapshot.dead_reckoning
    if len(starts) > 1:  # name the robots at their starts
        for traj in starts.values():
            if len(traj.poses):
                x, y = np.asarray(traj.poses, dtype=float)[0, :2]
                ax.annotate(
                    traj.robot,
                    (x, y),
                    xytext=(-4, 4),
                    textcoords="offset points",
                    ha="right",
                    fontsize=8,
                    color="tab:blue",
                )
    _field_axes(ax, _extent_of(np.concatenate([_all_poses(snapshot, truth), xy])), "trajectories")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)


# ------------------------------------------------------------------------- step times


def _draw_step_times(ax: Axes, step_times: Mapping[str, np.ndarray]) -> None:
    """Stacked per-stage time per step, in ms, with the 1 s real-time budget."""
    ax.set_title("time per step, by stage", fontsize=11)
    if not step_times:
        ax.text(
            0.5,
            0.5,
            "no step times recorded",
            ha="center",
            va="center",
            transform=ax.transAxes,
            color="0.4",
        )
        ax.set_axis_off()
        return
    lengths = {stage: len(t) for stage, t in step_times.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"step_times: stages have different numbers of steps {lengths}")
    ms = np.array([np.asarray(t, dtype=float) for t in step_times.values()]) * 1e3
    total = ms.sum(axis=0)  # per step, before binning
    n_steps = ms.shape[1]
    steps = np.arange(n_steps)
    if n_steps > MAX_STEP_BINS:  # mean per bin keeps a 10,000-step run readable
        edges = np.linspace(0, n_steps, MAX_STEP_BINS + 1).astype(int)
        ms = np.add.reduceat(ms, edges[:-1], axis=1) / np.diff(edges)
        steps = 0.5 * (edges[:-1] + edges[1:] - 1)
    colours = colormaps["tab10"](np.arange(len(step_times)) % 10)
    ax.stackplot(steps, ms, labels=list(step_times), colors=colours, alpha=0.85, lw=0)
    p50, p95, peak = np.percentile(total, 50), np.percentile(total, 95), total.max(initial=0)
    top = float(ms.sum(axis=0).max(initial=0))
    if top > 0.25 * REAL_TIME_BUDGET_MS:
        ax.axhline(
            REAL_TIME_BUDGET_MS, color="black", ls="--", lw=1.2, label="real-time budget (1 s)"
        )
    ax.set_xlim(steps[0] if len(steps) else 0, steps[-1] if len(steps) > 1 else 1)
    ax.set_ylim(
        0,
        max(top, REAL_TIME_BUDGET_MS * 1.05 if top > 0.25 * REAL_TIME_BUDGET_MS else top) * 1.08
        or 1.0,
    )
    ax.set_xlabel(
        "step"
        + (f" (mean of {n_steps / len(steps):.0f} per point)" if n_steps > MAX_STEP_BINS else "")
    )
    ax.set_ylabel("time (ms)")
    ax.grid(True, axis="y", color="0.88", lw=0.6)
    ax.set_title(
        "time per step, by stage\n"
        f"median {p50:.1f} ms, p95 {p95:.1f} ms, max {peak:.1f} ms "
        f"(real-time budget {REAL_TIME_BUDGET_MS:.0f} ms)",
        fontsize=11,
    )
    handles, labels = ax.get_legend_handles_labels()
    ax.legend(
        handles[::-1],
        labels[::-1],
        loc="upper left",
        bbox_to_anchor=(1.005, 1.0),
        fontsize=8,
        frameon=False,
    )
