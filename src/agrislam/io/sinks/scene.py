"""The map as a scene to draw in 3D: how each plant looks (colour by an attribute, opacity
and size by how sure the map is of it), its position ellipse, the row lines and the time
stamp. What the ROS marker sink and the Foxglove sink both draw; a helper of the sinks,
not a sink: it writes nothing."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib import colormaps

from agrislam.io.sinks.readouts import (
    continuous_scale,
    continuous_sureness,
    discrete_columns,
    discrete_sureness,
    most_probable,
    opacity,
    value_colours,
)
from agrislam.snapshot import MapSnapshot

ELLIPSE_SIGMAS = 2.0


@dataclass(frozen=True, slots=True)
class PlantStyle:
    """How each object is drawn: RGBA (k, 4) with opacity from `sureness` (k,) in [0, 1],
    and a label per object ("size: big 0.82")."""

    attribute: str | None
    rgba: np.ndarray
    sureness: np.ndarray
    labels: list[str]

    def sizes(self, diameter: float) -> np.ndarray:
        """Marker diameters (k,): half of `diameter` for a belief that knows nothing, all
        of it for a certain one."""
        return diameter * (0.5 + 0.5 * self.sureness)


def default_attribute(snapshot: MapSnapshot) -> str | None:
    """The first discrete attribute of the map, else the first continuous one."""
    objects = snapshot.objects
    return next(iter(objects.discrete), next(iter(objects.continuous), None))


def plant_style(snapshot: MapSnapshot, attribute: str | None = None) -> PlantStyle:
    """Colour by the attribute's most probable value (discrete) or mean (continuous, viridis
    over the schema's range); without attributes, by the interest heuristic h (sec. 2.7)."""
    objects = snapshot.objects
    name = attribute if attribute is not None else default_attribute(snapshot)
    k = len(objects)
    if name is None:
        h = np.asarray(objects.interest, dtype=float)
        rgba = colormaps["viridis"](np.clip(h, 0.0, 1.0))
        return PlantStyle(None, rgba, np.ones(k), [f"h {v:.2f}" for v in h])
    if name in objects.discrete:
        values, belief = discrete_columns(snapshot)[name]
        top, p = most_probable(belief)
        sureness = discrete_sureness(p, len(values))
        rgba = value_colours(name, values, snapshot)[top] if k else np.empty((0, 4))
        labels = [f"{name}: {values[j]} {q:.2f}" for j, q in zip(top, p, strict=True)]
    elif name in objects.continuous:
        mean, var = (np.asarray(a, dtype=float) for a in objects.continuous[name])
        lo, hi, prior_var = continuous_scale(snapshot, name, mean)
        rgba = colormaps["viridis"](np.clip((mean - lo) / ((hi - lo) or 1.0), 0.0, 1.0))
        sureness = continuous_sureness(var, prior_var)
        labels = [f"{name}: {m:.3g} ± {np.sqrt(v):.2g}" for m, v in zip(mean, var, strict=True)]
    else:
        known = [*objects.discrete, *objects.continuous]
        raise ValueError(f"attribute {name!r} is not in the map (it has {known})")
    rgba = np.array(rgba, dtype=float).reshape(k, 4)
    rgba[:, 3] = opacity(sureness)
    return PlantStyle(name, rgba, sureness, labels)


def covariance_ellipses(
    cov: np.ndarray, sigmas: float = ELLIPSE_SIGMAS
) -> tuple[np.ndarray, np.ndarray]:
    """Full axis lengths (k, 2), major first, and the major axis heading (k,) of the
    `sigmas` ellipses of 2x2 covariances (k, 2, 2)."""
    w, V = np.linalg.eigh(np.asarray(cov, dtype=float).reshape(-1, 2, 2))
    axes = 2.0 * sigmas * np.sqrt(np.clip(w[:, ::-1], 0.0, None))
    heading = np.arctan2(V[:, 1, 1], V[:, 0, 1])
    return axes, heading


def row_segments(snapshot: MapSnapshot) -> np.ndarray:
    """(r, 2, 2) end points of the fitted rows over the along-row extent of the objects."""
    rows = snapshot.rows
    if rows is None or len(rows.offsets) == 0:
        return np.empty((0, 2, 2))
    d = np.array([np.cos(rows.angle), np.sin(rows.angle)])
    n = np.array([-d[1], d[0]])  # snapshot.RowLines: row k is {p : n . p = offsets[k]}
    xy = np.asarray(snapshot.objects.xy, dtype=float).reshape(-1, 2)
    along = xy @ d if len(xy) else np.zeros(1)
    lo, hi = along.min() - 0.5, along.max() + 0.5
    base = np.asarray(rows.offsets, dtype=float)[:, None] * n
    return np.stack([base + lo * d, base + hi * d], axis=1)


def snapshot_time(snapshot: MapSnapshot) -> float:
    """The latest trajectory time of the snapshot (0 without trajectories)."""
    ends = [float(tr.t[-1]) for tr in snapshot.trajectories.values() if len(tr.t)]
    return max(ends, default=0.0)
