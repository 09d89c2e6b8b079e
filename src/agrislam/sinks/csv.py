"""`objects.csv` and `trajectory.csv` (DESIGN.md "Outputs of a run"): the map as plain tables.

Columns are built as whole numpy arrays and joined once, so 100,000 objects take about a
second. `object_columns` is the one object table; the GeoJSON and report sinks read it too.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from agrislam.config import ContinuousAttribute, FieldSchema
from agrislam.snapshot import MapSnapshot, ObjectMap, Trajectory

FLOAT_FORMAT = "{:.9g}".format  # 9 significant digits: 0.1 mm at 10 km, 1e-9 in probabilities
STATUS_NAME = "active"  # a snapshot carries the active objects only (snapshot.STATUS_ACTIVE)
TRAJECTORY_SOURCES = ("optimised", "dead_reckoning")


def value_names(schema: FieldSchema | None, attribute: str, n_values: int) -> list[str]:
    """Names of a discrete attribute's values: the schema's, or "0", "1", ... without one."""
    spec = schema.discrete.get(attribute) if schema is not None else None
    if spec is None:
        return [str(i) for i in range(n_values)]
    if spec.n_values != n_values:
        raise ValueError(
            f"attribute {attribute!r}: the schema has {spec.n_values} values {spec.values!r} "
            f"but the map holds {n_values} probabilities per object"
        )
    return list(spec.values)


def most_probable(belief: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the most probable value per object and its probability, for a (k, n) belief."""
    top = np.argmax(belief, axis=1)
    return top, belief[np.arange(len(belief)), top]


def discrete_sureness(p: np.ndarray, n_values: int) -> np.ndarray:
    """0 for a uniform belief over n values, 1 for a certain one, from the top probability."""
    return np.clip((p - 1.0 / n_values) / (1.0 - 1.0 / n_values), 0.0, 1.0)


def continuous_scale(
    snapshot: MapSnapshot, name: str, mean: np.ndarray
) -> tuple[float, float, float]:
    """(lo, hi, prior variance) of a continuous attribute: the schema's range and initial
    variance, else the estimates' own range and a uniform prior's variance over it."""
    spec = snapshot.schema.continuous.get(name) if snapshot.schema is not None else None
    if isinstance(spec, ContinuousAttribute):
        return spec.min, spec.max, spec.initial_var
    lo, hi = float(np.nanmin(mean, initial=0.0)), float(np.nanmax(mean, initial=1.0))
    return lo, hi, (hi - lo) ** 2 / 12.0 or 1.0


def continuous_sureness(var: np.ndarray, prior_var: float) -> np.ndarray:
    """0 while the std is as wide as the prior's, 1 when it has shrunk to nothing."""
    return np.clip(1.0 - np.sqrt(var / prior_var), 0.0, 1.0)


def discrete_columns(snapshot: MapSnapshot) -> dict[str, tuple[list[str], np.ndarray]]:
    """Checked discrete beliefs: attribute -> (value names, (k, n) probabilities)."""
    objects, out = snapshot.objects, {}
    for name, belief in objects.discrete.items():
        belief = np.asarray(belief, dtype=float)
        if belief.ndim != 2 or len(belief) != len(objects):
            raise ValueError(
                f"attribute {name!r}: belief array has shape {belief.shape}, expected "
                f"({len(objects)}, n_values)"
            )
        out[name] = (value_names(snapshot.schema, name, belief.shape[1]), belief)
    return out


def object_columns(snapshot: MapSnapshot, distributions: bool = True) -> dict[str, np.ndarray]:
    """The object table of `objects.csv`, column name -> array (strings for value names);
    without `distributions`, only the most probable value and its probability per attribute."""
    objects = snapshot.objects
    _check_lengths(objects)
    k = len(objects)
    cov = np.asarray(objects.cov, dtype=float).reshape(k, 2, 2)
    columns: dict[str, np.ndarray] = {
        "id": np.asarray(objects.ids),
        "x": np.asarray(objects.xy, dtype=float)[:, 0],
        "y": np.asarray(objects.xy, dtype=float)[:, 1],
        "cov_xx": cov[:, 0, 0],
        "cov_xy": 0.5 * (cov[:, 0, 1] + cov[:, 1, 0]),
        "cov_yy": cov[:, 1, 1],
        "n_meas": np.asarray(objects.n_meas),
        "interest": np.asarray(objects.interest, dtype=float),
        "status": np.full(k, STATUS_NAME),
    }
    extra: list[tuple[str, np.ndarray]] = []
    for name, (values, belief) in discrete_columns(snapshot).items():
        top, p = most_probable(belief)
        extra += [(name, np.asarray(values)[top]), (f"{name}_p", p)]
        if distributions:
            extra += [(f"{name}_{v}", belief[:, j]) for j, v in enumerate(values)]
    for name, (mean, var) in objects.continuous.items():
        mean, var = np.asarray(mean, dtype=float), np.asarray(var, dtype=float)
        if mean.shape != (k,) or var.shape != (k,):
            raise ValueError(
                f"attribute {name!r}: mean/var arrays have shapes {mean.shape}/{var.shape}, "
                f"expected ({k},)"
            )
        extra += [(name, mean), (f"{name}_var", var)]
    for col, array in extra:
        if col in columns:
            raise ValueError(f"column {col!r} of attribute values clashes with another column")
        columns[col] = array
    return columns


def trajectory_columns(snapshot: MapSnapshot) -> dict[str, np.ndarray]:
    """`robot, t, x, y, theta, source`: optimised trajectories first, then dead reckoning."""
    parts: list[tuple[str, Trajectory]] = [
        (source, traj)
        for source, trajs in zip(
            TRAJECTORY_SOURCES, (snapshot.trajectories, snapshot.dead_reckoning), strict=True
        )
        for traj in trajs.values()
    ]
    for source, traj in parts:
        poses = np.asarray(traj.poses, dtype=float)
        if poses.ndim != 2 or poses.shape != (len(traj.t), 3):
            raise ValueError(
                f"{source} trajectory of robot {traj.robot!r}: poses have shape {poses.shape}, "
                f"expected ({len(traj.t)}, 3)"
            )
    poses = [np.asarray(traj.poses, dtype=float).reshape(-1, 3) for _, traj in parts]
    stacked = np.concatenate(poses) if poses else np.empty((0, 3))
    counts = [len(p) for p in poses]
    return {
        "robot": np.repeat(np.asarray([t.robot for _, t in parts], dtype=str), counts),
        "t": np.concatenate([np.asarray(t.t, dtype=float) for _, t in parts] or [np.empty(0)]),
        "x": stacked[:, 0],
        "y": stacked[:, 1],
        "theta": stacked[:, 2],
        "source": np.repeat(np.asarray([s for s, _ in parts], dtype=str), counts),
    }


def write_objects_csv(snapshot: MapSnapshot, path: str | Path) -> Path:
    """Write `objects.csv`: one row per mapped object (DESIGN.md "Outputs of a run")."""
    return write_table(object_columns(snapshot), path)


def write_trajectory_csv(snapshot: MapSnapshot, path: str | Path) -> Path:
    """Write `trajectory.csv`: the optimised and dead-reckoned poses of every robot."""
    return write_table(trajectory_columns(snapshot), path)


def write_table(columns: dict[str, np.ndarray], path: str | Path) -> Path:
    """Write equal-length columns as CSV (RFC 4180 quoting) with a header line."""
    path = Path(path)
    text = [_format_column(np.asarray(c)) for c in columns.values()]
    lines = [",".join(_quote(list(columns)))]
    lines += map(",".join, zip(*text, strict=True))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8", newline="")
    return path


def _format_column(column: np.ndarray) -> list[str]:
    if column.dtype.kind == "f":
        return list(map(FLOAT_FORMAT, column.tolist()))
    if column.dtype.kind in "iub":
        return list(map(str, column.astype(np.int64).tolist()))
    names, index = np.unique(column.astype(str), return_inverse=True)
    return list(np.asarray(_quote(names.tolist()), dtype=object)[index])


def _quote(fields: Sequence[str]) -> list[str]:
    """CSV quoting: fields with a comma, quote or line break go in double quotes."""
    return [
        '"' + f.replace('"', '""') + '"' if any(c in f for c in ',"\r\n') else f for f in fields
    ]


def _check_lengths(objects: ObjectMap) -> None:
    k = len(objects)
    for name, shape in (
        ("xy", (k, 2)),
        ("cov", (k, 2, 2)),
        ("n_meas", (k,)),
        ("interest", (k,)),
        ("row", (k,)),
    ):
        actual = np.shape(getattr(objects, name))
        if actual != shape:
            raise ValueError(f"objects.{name} has shape {actual}, expected {shape} for {k} ids")
