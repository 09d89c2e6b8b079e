"""Belief read-outs every map sink shows the same way: a discrete attribute's value names
and checked probabilities, its most probable value, how sure a belief is (0: knows nothing,
1: certain), a continuous attribute's scale, and the colours and opacity they are drawn with."""

from __future__ import annotations

import numpy as np
from matplotlib import colormaps
from matplotlib.colors import is_color_like, to_rgba_array

from agrislam.config import ContinuousAttribute, FieldSchema
from agrislam.snapshot import MapSnapshot

MIN_OPACITY = 0.15  # a belief that knows nothing is still visible
# colours that say what the value is, for value names a farmer will recognise
KNOWN_VALUE_COLOURS = {
    "healthy": "tab:green",
    "diseased": "tab:red",
    "crop": "tab:green",
    "weed": "tab:purple",
}


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


def opacity(sureness: np.ndarray) -> np.ndarray:
    """Faint (MIN_OPACITY) for a belief that knows nothing, solid for a certain one."""
    return MIN_OPACITY + (1.0 - MIN_OPACITY) * sureness


def value_colours(name: str, values: list[str], snapshot: MapSnapshot) -> np.ndarray:
    """(n, 4) RGBA per value: the colour itself for a colour attribute, green/red for
    healthy/diseased etc., light to dark green for ordered (growing) sizes, else tab10."""
    spec = snapshot.schema.discrete.get(name) if snapshot.schema is not None else None
    if "colo" in name.lower() and all(is_color_like(v) for v in values):
        return to_rgba_array(values)
    if all(v in KNOWN_VALUE_COLOURS for v in values):
        return to_rgba_array([KNOWN_VALUE_COLOURS[v] for v in values])
    if (spec is not None and spec.time_model is not None) or name.lower() == "size":
        return colormaps["YlGn"](np.linspace(0.3, 0.95, len(values)))
    return colormaps["tab10"](np.arange(len(values)) % 10)
