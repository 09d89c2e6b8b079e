"""The object and trajectory tables of a map snapshot, column name -> whole numpy array: what
`objects.csv` and `trajectory.csv` hold and the GeoJSON sink reads. A helper of the sinks,
not a sink: it writes nothing."""

from __future__ import annotations

import numpy as np

from agrislam.io.sinks.readouts import discrete_columns, most_probable
from agrislam.snapshot import MapSnapshot, ObjectMap, Trajectory

STATUS_NAME = "active"  # a snapshot carries the active objects only (snapshot.STATUS_ACTIVE)

TRAJECTORY_SOURCES = ("optimised", "dead_reckoning")


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
