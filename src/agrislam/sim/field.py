"""The simulated field: rows of plants with ground-truth attributes drawn from a schema,
weeds off the rows, gaps and doubled plants, and their growth between survey days."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from agrislam.config import (
    SECONDS_PER_DAY,
    ContinuousAttribute,
    DiscreteAttribute,
    FieldSchema,
    GrowthModel,
)
from agrislam.records import TruthObject
from agrislam.semantics.growth import grown_mean
from agrislam.sim.config import FieldLayout, SimConfig

WEED = "weed"


@dataclass(frozen=True, slots=True)
class Field:
    """Ground truth of a field, one row per plant (struct of arrays).

    `discrete[name]` holds value indices into the schema's values, `continuous[name]` the
    values; `length` is every plant's physical length (m), whether or not the schema has it.
    """

    schema: FieldSchema
    ids: np.ndarray  # (n,) str
    xy: np.ndarray  # (n, 2) map frame
    length: np.ndarray  # (n,) m
    growth_rate: np.ndarray  # (n,) alpha of App. B, 1/day
    discrete: dict[str, np.ndarray]
    continuous: dict[str, np.ndarray]
    is_weed: np.ndarray  # (n,) bool
    row: np.ndarray  # (n,) row index, -1 for a plant off the rows
    row_angle: float  # rad, row direction from the map x axis
    row_spacing: float
    n_rows: int
    row_length: float  # m, along the rows from the first plant position
    origin: np.ndarray  # (2,) first plant position of row 0
    l_max: float  # m, the length a plant grows towards (App. B)

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def row_direction(self) -> np.ndarray:
        return np.array([np.cos(self.row_angle), np.sin(self.row_angle)])

    @property
    def row_normal(self) -> np.ndarray:
        return np.array([-np.sin(self.row_angle), np.cos(self.row_angle)])

    def to_map(self, s: np.ndarray | float, across: np.ndarray | float) -> np.ndarray:
        """Field coordinates (s along the rows, across them; row k at k row_spacing) -> xy."""
        s, across = np.asarray(s, float), np.asarray(across, float)
        return self.origin + s[..., None] * self.row_direction + across[..., None] * self.row_normal

    def to_field(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = np.asarray(xy, float) - self.origin
        return d @ self.row_direction, d @ self.row_normal

    def truth_attributes(self, i: int) -> dict[str, str | float]:
        out: dict[str, str | float] = {}
        for name, spec in self.schema.attributes.items():
            if isinstance(spec, DiscreteAttribute):
                out[name] = spec.values[int(self.discrete[name][i])]
            else:
                out[name] = float(self.continuous[name][i])
        return out

    def truth_objects(self) -> Iterator[TruthObject]:
        """The plants' truth records, one at a time (a field of 100,000 is not held twice)."""
        for i in range(len(self)):
            yield TruthObject(
                id=str(self.ids[i]), xy=self.xy[i].copy(), attributes=self.truth_attributes(i)
            )

    def grown(self, days: float) -> Field:
        """The field `days` later: every length follows dx/dt = alpha (l_max - x) (App. B),
        and the size-like attributes follow their length."""
        if days < 0:
            raise ValueError(f"cannot grow backwards ({days} days)")
        # x(t + dt) = l_max - (l_max - x(t)) e^{-alpha dt} (App. B), each plant with its own
        # alpha: the unit-rate model run for alpha * dt
        unit = GrowthModel(rate_per_day=1.0, l_max=self.l_max)
        length = grown_mean(self.length, unit, self.growth_rate * days * SECONDS_PER_DAY)
        return replace(
            self,
            length=length,
            **_length_attributes(self.schema, length, self.l_max, self.discrete, self.continuous),
        )


def size_like(name: str, spec: DiscreteAttribute) -> bool:
    """A discrete attribute that is a binned length: named 'size' or with a growth model."""
    return name == "size" or spec.time_model is not None


def bin_length(length: np.ndarray, n_cells: int, l_max: float) -> np.ndarray:
    """Index of the cell of [0, l_max] split into n equal cells that holds each length (App. B)."""
    return np.clip((np.asarray(length) / l_max * n_cells).astype(int), 0, n_cells - 1)


def _length_attributes(
    schema: FieldSchema,
    length: np.ndarray,
    l_max: float,
    discrete: dict[str, np.ndarray],
    continuous: dict[str, np.ndarray],
) -> dict[str, dict[str, np.ndarray]]:
    """Discrete and continuous truth with the length-driven attributes recomputed."""
    discrete, continuous = dict(discrete), dict(continuous)
    for name, spec in schema.discrete.items():
        if size_like(name, spec):
            cells_l_max = spec.time_model.l_max if spec.time_model else l_max
            discrete[name] = bin_length(length, spec.n_values, cells_l_max)
    if "length" in schema.continuous:
        spec = schema.continuous["length"]
        continuous["length"] = np.clip(length, spec.min, spec.max)
    return {"discrete": discrete, "continuous": continuous}


def value_probabilities(spec: DiscreteAttribute, weights: dict[str, float] | None) -> np.ndarray:
    """Truth value frequencies: named values get their weight, the rest share what is left."""
    named = {v: w for v, w in (weights or {}).items() if v in spec.values}
    p = np.array([named.get(v, 0.0) for v in spec.values], float)
    unnamed = np.array([v not in named for v in spec.values])
    rest = 1.0 - p.sum()
    if unnamed.any() and rest > 0:
        p[unnamed] = rest / unnamed.sum()
    if p.sum() <= 0:
        p[:] = 1.0
    return p / p.sum()


def growth_l_max(schema: FieldSchema, layout: FieldLayout) -> float:
    for spec in schema.attributes.values():
        if spec.time_model is not None:
            return spec.time_model.l_max
    return layout.l_max


def growth_rate(schema: FieldSchema, default: float) -> float:
    for spec in schema.attributes.values():
        if spec.time_model is not None:
            return spec.time_model.rate_per_day
    return default


def _sowing_positions(layout: FieldLayout, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """(s, row) of every sowing position, rows filled left to right."""
    lo, hi = layout.plant_spacing
    if layout.n_plants is not None:
        per_row = np.full(layout.n_rows, layout.n_plants // layout.n_rows)
        per_row[: layout.n_plants % layout.n_rows] += 1
        s_rows = [
            np.concatenate([[0.0], np.cumsum(rng.uniform(lo, hi, k - 1))]) if k else np.zeros(0)
            for k in per_row
        ]
    else:
        n_max = int(np.ceil(layout.row_length / lo)) + 1
        s_rows = []
        for _ in range(layout.n_rows):
            s = np.concatenate([[0.0], np.cumsum(rng.uniform(lo, hi, n_max))])
            s_rows.append(s[s <= layout.row_length])
    rows = np.concatenate([np.full(len(s), k) for k, s in enumerate(s_rows)])
    return np.concatenate(s_rows), rows


def _place_weeds(
    n: int, s_max: float, layout: FieldLayout, taken: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """(s, across) of up to n weeds anywhere in the field, at least the minimum plant distance from
    every plant (else the map's d_inter prior would merge them) and, off-row, from the rows."""
    d_min = layout.plant_spacing[0]
    sp = layout.row_spacing
    placed: list[np.ndarray] = []
    tree = cKDTree(taken) if len(taken) else None
    for _ in range(50 * n):
        if len(placed) == n:
            break
        p = np.array([rng.uniform(0.0, s_max), rng.uniform(-0.5 * sp, (layout.n_rows - 0.5) * sp)])
        if abs(p[1] / sp - np.round(p[1] / sp)) * sp < 0.25 * sp:
            continue  # on a row: not where an off-row weed grows
        if tree is not None and tree.query(p)[0] < d_min:
            continue
        if placed and np.min(np.linalg.norm(np.array(placed) - p, axis=1)) < d_min:
            continue
        placed.append(p)
    return np.array(placed).reshape(-1, 2)


def make_field(cfg: SimConfig, rng: np.random.Generator) -> Field:
    """Draw a field: sowing positions on rows, gaps, doubles, weeds, and every plant's truth."""
    layout = cfg.field
    schema = cfg.field_schema()
    s, rows = _sowing_positions(layout, rng)
    keep = rng.random(len(s)) >= layout.gap_probability
    row_length = float(s.max()) if len(s) else 0.0
    s, rows = s[keep], rows[keep]
    across = rows * layout.row_spacing + rng.normal(0.0, layout.row_jitter, len(s))
    weed = np.zeros(len(s), bool)

    twin = np.flatnonzero(rng.random(len(s)) < layout.double_probability)
    if len(twin):
        dist = rng.uniform(*layout.double_offset, len(twin))
        ang = rng.uniform(0.0, 2 * np.pi, len(twin))
        s = np.concatenate([s, s[twin] + dist * np.cos(ang)])
        across = np.concatenate([across, across[twin] + dist * np.sin(ang)])
        rows = np.concatenate([rows, rows[twin]])
        weed = np.concatenate([weed, np.zeros(len(twin), bool)])

    n_weeds = round(layout.weed_fraction * len(keep))
    if n_weeds and layout.weeds_off_row:
        sl = _place_weeds(n_weeds, row_length, layout, np.column_stack([s, across]), rng)
        s, across = np.concatenate([s, sl[:, 0]]), np.concatenate([across, sl[:, 1]])
        rows = np.concatenate([rows, np.full(len(sl), -1)])
        weed = np.concatenate([weed, np.ones(len(sl), bool)])
    elif n_weeds:
        weed[rng.choice(len(weed), min(n_weeds, len(weed)), replace=False)] = True

    n = len(s)
    l_max = growth_l_max(schema, layout)
    length = rng.uniform(*layout.length_range, n)
    discrete: dict[str, np.ndarray] = {}
    continuous: dict[str, np.ndarray] = {}
    for name, spec in schema.attributes.items():
        if isinstance(spec, DiscreteAttribute):
            p = value_probabilities(spec, layout.value_weights.get(name))
            values = rng.choice(spec.n_values, n, p=p)
            if WEED in spec.values:
                values = np.where(weed, spec.values.index(WEED), values)
            discrete[name] = values
        elif isinstance(spec, ContinuousAttribute):
            continuous[name] = rng.uniform(spec.min, spec.max, n)
    base = Field(
        schema=schema,
        ids=np.array([f"p{i:0{max(4, len(str(n)))}d}" for i in range(n)]),
        xy=np.zeros((n, 2)),
        length=length,
        growth_rate=growth_rate(schema, cfg.growth.rate_per_day)
        * rng.uniform(1 - cfg.growth.rate_spread, 1 + cfg.growth.rate_spread, n),
        discrete=discrete,
        continuous=continuous,
        is_weed=weed,
        row=np.where(weed & layout.weeds_off_row, -1, rows),
        row_angle=float(np.deg2rad(layout.row_angle_deg)),
        row_spacing=layout.row_spacing,
        n_rows=layout.n_rows,
        row_length=row_length,
        origin=np.asarray(layout.origin, float),
        l_max=l_max,
    )
    return replace(
        base,
        xy=base.to_map(s, across),
        **_length_attributes(schema, length, l_max, discrete, continuous),
    )
