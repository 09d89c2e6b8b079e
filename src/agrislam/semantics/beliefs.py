"""The belief table: the semantic state of every object of the map as a struct of arrays
(DESIGN.md "State layout"), with the measurement update (sec. 2.5), the lazy time update
(sec. 2.5.2, App. B), the fusion of merged objects and the interest heuristic (sec. 2.7).

A belief is stored at its own time (`belief_time`): reading it later brings it forward
through the attribute's time model without storing that, and an update stores it, so a
step costs nothing for untouched objects and reading never changes a later update."""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from agrislam.config import ContinuousAttribute, DiscreteAttribute, FieldSchema, SemanticsConfig
from agrislam.growing import Doubling
from agrislam.records import ContinuousMeasurement, DiscreteMeasurement, Measurement
from agrislam.semantics import continuous, discrete, growth, heuristic

_STORES = ("_p", "_mean", "_var")  # the attributes holding a column per attribute name


class BeliefInputError(ValueError):
    """A measurement or request the table cannot take; the table is left unchanged."""


@dataclass(frozen=True, slots=True)
class UpdateReport:
    """What one `BeliefTable.update` did, per attribute name."""

    applied: dict[str, int]  # measurements that changed a belief
    ignored: dict[str, int]  # discrete measurements with p < 1/n (sec. 2.3)


@dataclass(slots=True)
class _Collected:
    """The measurements of one attribute in one update call, validated."""

    rows: list[int]  # position in the call's ids
    values: list[float]  # value index (discrete) or measured value (continuous)
    spread: list[float]  # p (discrete) or measurement variance (continuous)


def _occurrence(local: np.ndarray) -> np.ndarray:
    """For each entry, how many equal entries come before it (0 for the first)."""
    order = np.argsort(local, kind="stable")
    ordered = local[order]
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]])
    group_start = np.repeat(starts, np.diff(np.r_[starts, len(local)]))
    occurrence = np.empty(len(local), dtype=np.int64)
    occurrence[order] = np.arange(len(local)) - group_start
    return occurrence


def _rounds(local: np.ndarray, repeats: bool) -> list[np.ndarray]:
    """Split entries into rounds in which every object appears at most once, in order, so
    an object measured twice in one call gets both updates one after the other. `repeats`:
    whether the call has a repeated id at all (if not, one round)."""
    if not repeats or len(np.unique(local)) == len(local):
        return [np.arange(len(local))]
    occurrence = _occurrence(local)
    return [np.flatnonzero(occurrence == r) for r in range(int(occurrence.max()) + 1)]


def _read_only(array: np.ndarray) -> np.ndarray:
    view = array.view()
    view.flags.writeable = False
    return view


class BeliefTable:
    """Semantic beliefs of all objects of a map, one row per object."""

    def __init__(
        self, schema: FieldSchema | None, config: SemanticsConfig, capacity: int = 1024
    ) -> None:
        self.schema = schema
        self.config = config
        self._n = 0
        self._capacity = max(int(capacity), 1)
        attributes = schema.attributes if schema is not None else {}
        self._discrete_spec: dict[str, DiscreteAttribute] = {
            k: v for k, v in attributes.items() if isinstance(v, DiscreteAttribute)
        }
        self._continuous_spec: dict[str, ContinuousAttribute] = {
            k: v for k, v in attributes.items() if isinstance(v, ContinuousAttribute)
        }
        self._value_index = {
            name: {value: i for i, value in enumerate(spec.values)}
            for name, spec in self._discrete_spec.items()
        }
        self._prior = {
            name: np.full(spec.n_values, 1.0 / spec.n_values)
            if spec.prior is None
            else np.asarray(spec.prior, dtype=float) / sum(spec.prior)
            for name, spec in self._discrete_spec.items()
        }
        self._transitions = {
            name: growth.TransitionCache(spec.n_values, spec.time_model)
            for name, spec in self._discrete_spec.items()
            if spec.time_model is not None
        }
        # the smallest variance a continuous belief holds, relative to its range as the
        # probability floor is for discrete ones: a zero-variance measurement cannot freeze it
        self._var_floor = {
            name: config.probability_floor * (spec.max - spec.min) ** 2
            for name, spec in self._continuous_spec.items()
        }
        c = self._capacity
        self._p = {name: np.empty((c, spec.n_values)) for name, spec in self._discrete_spec.items()}
        self._mean = {name: np.empty(c) for name in self._continuous_spec}
        self._var = {name: np.empty(c) for name in self._continuous_spec}
        self._n_meas = np.zeros(c, dtype=np.int64)
        self._last_update = np.empty(c)
        self._belief_time = np.empty(c)
        self._doubling = Doubling(dict.fromkeys(self._columns(), 0))
        self.n_ignored: dict[str, int] = dict.fromkeys(self._discrete_spec, 0)

    # ------------------------------------------------------------------ size and rows

    def __len__(self) -> int:
        return self._n

    @property
    def capacity(self) -> int:
        """Rows allocated; doubles when full."""
        return self._capacity

    @property
    def n_meas(self) -> np.ndarray:
        """Measurements per object (n,), read-only."""
        return _read_only(self._n_meas[: self._n])

    @property
    def last_update(self) -> np.ndarray:
        """Time (s) of each object's last measurement, or of its creation (n,), read-only."""
        return _read_only(self._last_update[: self._n])

    @property
    def belief_time(self) -> np.ndarray:
        """Time (s) each stored belief refers to (n,), read-only."""
        return _read_only(self._belief_time[: self._n])

    def _reserve(self, n_rows: int) -> None:
        """Room for n_rows objects; capacity doubles, so growing is amortised O(1) per row."""
        doubled = self._doubling.reserve(n_rows, self._capacity, self._columns)
        for (attribute, name), column in (doubled or {}).items():
            if name is None:
                setattr(self, attribute, column)
            else:
                getattr(self, attribute)[name] = column
        self._capacity = len(self._n_meas)

    def _columns(self) -> dict[tuple[str, str | None], np.ndarray]:
        """Every column, keyed by the attribute holding it and its name in that store."""
        stores = {attribute: getattr(self, attribute) for attribute in _STORES}
        return {
            **{(a, name): c for a, store in stores.items() for name, c in store.items()},
            **{(a, None): getattr(self, a) for a in ("_n_meas", "_last_update", "_belief_time")},
        }

    def add(self, count: int, t: float) -> np.ndarray:
        """`count` new objects at time t with the initial beliefs; returns their row ids."""
        if count < 0:
            raise BeliefInputError(f"cannot add {count} objects")
        if not math.isfinite(t):
            raise BeliefInputError(f"time t = {t!r} is not finite")
        start, stop = self._n, self._n + int(count)
        self._reserve(stop)
        for name, prior in self._prior.items():
            self._p[name][start:stop] = prior
        for name, spec in self._continuous_spec.items():
            self._mean[name][start:stop] = spec.initial_mean
            self._var[name][start:stop] = spec.initial_var
        self._n_meas[start:stop] = 0
        self._last_update[start:stop] = t
        self._belief_time[start:stop] = t
        self._n = stop
        return np.arange(start, stop, dtype=np.int64)

    def _ids(self, ids: np.ndarray | Sequence[int] | None) -> np.ndarray | slice:
        """Validated row ids; None (every object) becomes a slice, cheaper than fancy indexing."""
        if ids is None:
            return slice(0, self._n)
        ids = np.asarray(ids)
        if ids.ndim != 1 or (len(ids) and not np.issubdtype(ids.dtype, np.integer)):
            raise BeliefInputError(f"object ids must be a 1-d integer array, got {ids!r}")
        if len(ids) and (ids.min() < 0 or ids.max() >= self._n):
            bad = ids[(ids < 0) | (ids >= self._n)]
            raise BeliefInputError(f"object ids {bad.tolist()} not in the table (0..{self._n - 1})")
        return ids.astype(np.int64, copy=False)

    # ----------------------------------------------------------------- reading at t

    def _discrete_at(self, name: str, ids: np.ndarray | slice, t: float | None) -> np.ndarray:
        """Beliefs of validated `ids` brought to t, as a new array."""
        belief = self._p[name][ids]
        cache = self._transitions.get(name)
        if t is None or cache is None:
            return belief.copy() if isinstance(ids, slice) else belief
        # sec. 2.5.2 / App. B: xi(t) = A(t - t_belief) xi(t_belief)
        return growth.propagate(belief, cache(t - self._belief_time[ids]))

    def _continuous_at(
        self, name: str, ids: np.ndarray | slice, t: float | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variance of validated `ids` brought to t, as new arrays."""
        mean, var = self._mean[name][ids], self._var[name][ids]
        model = self._continuous_spec[name].time_model
        if t is None or model is None:
            return (mean.copy(), var.copy()) if isinstance(ids, slice) else (mean, var)
        dt = t - self._belief_time[ids]
        return growth.grown_mean(mean, model, dt), growth.grown_variance(var, model, dt)

    def _all_discrete_at(self, ids: np.ndarray | slice, t: float | None) -> dict[str, np.ndarray]:
        return {name: self._discrete_at(name, ids, t) for name in self._discrete_spec}

    def _all_continuous_at(
        self, ids: np.ndarray | slice, t: float | None
    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        return {name: self._continuous_at(name, ids, t) for name in self._continuous_spec}

    def probabilities(
        self, name: str, ids: np.ndarray | Sequence[int], t: float | None = None
    ) -> np.ndarray:
        """P(x_name) of objects `ids` at time t (the stored time if None): (k, n_values)."""
        if name not in self._discrete_spec:
            raise BeliefInputError(f"{name!r} is not a discrete attribute of the schema")
        return self._discrete_at(name, self._ids(ids), t)

    def gaussian(
        self, name: str, ids: np.ndarray | Sequence[int], t: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variance of continuous attribute `name` of objects `ids` at time t."""
        if name not in self._continuous_spec:
            raise BeliefInputError(f"{name!r} is not a continuous attribute of the schema")
        return self._continuous_at(name, self._ids(ids), t)

    def discrete_beliefs(
        self, ids: np.ndarray | Sequence[int] | None = None, t: float | None = None
    ) -> dict[str, np.ndarray]:
        """Every discrete attribute of objects `ids` (all if None) at t: name -> (k, n)."""
        return self._all_discrete_at(self._ids(ids), t)

    def continuous_beliefs(
        self, ids: np.ndarray | Sequence[int] | None = None, t: float | None = None
    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Every continuous attribute of objects `ids` (all if None) at t: name -> (mean, var)."""
        return self._all_continuous_at(self._ids(ids), t)

    def interest(
        self, ids: np.ndarray | Sequence[int] | None = None, t: float | None = None
    ) -> np.ndarray:
        """Interest heuristic h (eq. 2) of objects `ids` (all if None) at time t: (k,)."""
        ids = self._ids(ids)
        entropies = [
            continuous.entropy_normalised(self._continuous_at(name, ids, t)[1], spec.max - spec.min)
            for name, spec in self._continuous_spec.items()
        ]
        beliefs = self._all_discrete_at(ids, t).values()
        return heuristic.interest(self._n_meas[ids], beliefs, entropies, self.config)

    # ------------------------------------------------------------------------ updates

    def _check_discrete(self, name: str, m: object) -> tuple[float, float]:
        """(value index, p) of a valid discrete measurement; ValueError saying what is wrong."""
        if not isinstance(m, DiscreteMeasurement):
            raise ValueError(f"expected a discrete measurement, got {m!r}")
        try:
            index = self._value_index[name].get(m.value)
        except TypeError:  # an unhashable value
            index = None
        if index is None:
            raise ValueError(f"value {m.value!r} not in {self._discrete_spec[name].values}")
        p = m.p
        if not ((type(p) is float or isinstance(p, numbers.Real)) and 0.0 <= p <= 1.0):
            raise ValueError(f"p = {p!r} is not in [0, 1]")
        return float(index), float(p)

    @staticmethod
    def _check_continuous(m: object) -> tuple[float, float]:
        """(value, variance) of a valid continuous measurement; ValueError otherwise."""
        if not isinstance(m, ContinuousMeasurement):
            raise ValueError(f"expected a continuous measurement, got {m!r}")
        value, var = m.value, m.var
        if not ((type(value) is float or isinstance(value, numbers.Real)) and math.isfinite(value)):
            raise ValueError(f"value {value!r} is not a finite number")
        if not ((type(var) is float or isinstance(var, numbers.Real)) and 0.0 <= var < math.inf):
            raise ValueError(f"variance {var!r} is not a finite number >= 0")
        return float(value), float(var)

    def _validate(
        self, ids: np.ndarray, measurements: Sequence[Mapping[str, Measurement]]
    ) -> dict[str, _Collected]:
        """Check every measurement before anything changes; group them by attribute."""
        collected: dict[str, _Collected] = {}
        for k, mapping in enumerate(measurements):
            for name, m in mapping.items():
                try:
                    if name in self._value_index:
                        value, spread = self._check_discrete(name, m)
                    elif name in self._continuous_spec:
                        value, spread = self._check_continuous(m)
                    else:
                        known = sorted(self._value_index) + sorted(self._continuous_spec)
                        raise ValueError(
                            f"unknown attribute (the schema has: {', '.join(known) or 'none'})"
                        )
                except ValueError as err:
                    where = f"object {int(ids[k])}, attribute {name!r}"
                    raise BeliefInputError(f"{where}: {err}") from None
                group = collected.get(name)
                if group is None:
                    group = collected[name] = _Collected([], [], [])
                group.rows.append(k)
                group.values.append(value)
                group.spread.append(spread)
        return collected

    def update(
        self,
        ids: np.ndarray | Sequence[int],
        measurements: Sequence[Mapping[str, Measurement]],
        t: float,
    ) -> UpdateReport:
        """Apply one mapping of measurements per object id at time t (sec. 2.5).

        Each object is first brought to t (time update), then updated by Bayes (discrete,
        Assumption 1) or Kalman (continuous); its measurement count grows by one per
        occurrence, even for an empty mapping (a detection without semantics). An id may
        appear more than once; it then gets every update, in order. Everything is
        validated first: bad input raises BeliefInputError and changes nothing.
        """
        ids = self._ids(ids)
        if len(measurements) != len(ids):
            raise BeliefInputError(
                f"{len(ids)} object ids but {len(measurements)} measurement mappings"
            )
        if not math.isfinite(t):
            raise BeliefInputError(f"time t = {t!r} is not finite")
        collected = self._validate(ids, measurements)

        unique_ids, position = np.unique(ids, return_inverse=True)
        repeats = len(unique_ids) < len(ids)
        beliefs = self._all_discrete_at(unique_ids, t)
        gaussians = self._all_continuous_at(unique_ids, t)
        applied, ignored = {}, {}
        floor = self.config.probability_floor
        for name, group in collected.items():
            local = position[np.asarray(group.rows, dtype=np.int64)]
            values, spread = np.asarray(group.values), np.asarray(group.spread)
            if name in beliefs:
                skip = discrete.ignored_measurements(spread, self._discrete_spec[name].n_values)
                ignored[name] = int(skip.sum())
                local, values, spread = local[~skip], values[~skip].astype(np.int64), spread[~skip]
                belief = beliefs[name]
                for r in _rounds(local, repeats):
                    rows = local[r]
                    belief[rows] = discrete.bayes_update(belief[rows], values[r], spread[r], floor)
            else:
                mean, var = gaussians[name]
                for r in _rounds(local, repeats):
                    rows = local[r]
                    mean[rows], var[rows] = continuous.kalman_update(
                        mean[rows], var[rows], values[r], spread[r]
                    )
                np.maximum(var, self._var_floor[name], out=var)
            applied[name] = len(local)

        for name, belief in beliefs.items():
            self._p[name][unique_ids] = belief
        for name, (mean, var) in gaussians.items():
            self._mean[name][unique_ids], self._var[name][unique_ids] = mean, var
        for name, count in ignored.items():
            self.n_ignored[name] += count
        self._n_meas[unique_ids] += np.bincount(position, minlength=len(unique_ids))
        self._last_update[unique_ids] = np.maximum(self._last_update[unique_ids], t)
        self._belief_time[unique_ids] = np.maximum(self._belief_time[unique_ids], t)
        return UpdateReport(applied=applied, ignored=ignored)

    def fuse(self, keep: int, drop: int) -> None:
        """Merge object `drop`'s beliefs into `keep` as independent evidence (sec. 2.6.3).

        Both are brought to the later of their belief times; discrete beliefs multiply and
        the shared prior is divided out once, Gaussians combine in information form (the
        continuous prior divided out likewise); measurement counts add. Row `drop` stays
        as it was: marking it merged is the caller's business.
        """
        pair = self._ids(np.array([keep, drop]))
        if pair[0] == pair[1]:
            raise BeliefInputError(f"cannot fuse object {keep} with itself")
        t = float(self._belief_time[pair].max())
        floor = self.config.probability_floor
        for name, belief in self._all_discrete_at(pair, t).items():
            fused = discrete.fuse(belief[:1], belief[1:], self._prior[name], floor)
            self._p[name][keep] = fused[0]
        for name, (mean, var) in self._all_continuous_at(pair, t).items():
            spec = self._continuous_spec[name]
            m, v = continuous.fuse(
                mean[0], var[0], mean[1], var[1], spec.initial_mean, spec.initial_var
            )
            self._mean[name][keep], self._var[name][keep] = m, max(v, self._var_floor[name])
        self._n_meas[keep] += self._n_meas[drop]
        self._last_update[keep] = self._last_update[pair].max()
        self._belief_time[keep] = t

    # --------------------------------------------------------------------- persistence

    def state(self) -> dict[str, np.ndarray]:
        """Copies of every array (n rows), keyed `n_meas`, `last_update`, `belief_time`,
        `p/<name>`, `mean/<name>`, `var/<name>`, `n_ignored/<name>`; `from_state` reads them."""
        n = self._n
        out = {
            "n_meas": self._n_meas[:n].copy(),
            "last_update": self._last_update[:n].copy(),
            "belief_time": self._belief_time[:n].copy(),
        }
        out.update({f"p/{k}": v[:n].copy() for k, v in self._p.items()})
        out.update({f"mean/{k}": v[:n].copy() for k, v in self._mean.items()})
        out.update({f"var/{k}": v[:n].copy() for k, v in self._var.items()})
        out.update({f"n_ignored/{k}": np.array(v) for k, v in self.n_ignored.items()})
        return out

    @classmethod
    def from_state(
        cls, schema: FieldSchema | None, config: SemanticsConfig, state: Mapping[str, np.ndarray]
    ) -> BeliefTable:
        """A table holding `state` (as `state()` wrote it) for the same schema."""
        n = len(state["n_meas"])
        table = cls(schema, config, capacity=max(n, 1))
        table._n = n
        wanted = {
            "n_meas": (table._n_meas, (n,)),
            "last_update": (table._last_update, (n,)),
            "belief_time": (table._belief_time, (n,)),
        }
        for name, spec in table._discrete_spec.items():
            wanted[f"p/{name}"] = (table._p[name], (n, spec.n_values))
        for name in table._continuous_spec:
            wanted[f"mean/{name}"] = (table._mean[name], (n,))
            wanted[f"var/{name}"] = (table._var[name], (n,))
        for key, (target, shape) in wanted.items():
            if key not in state:
                raise BeliefInputError(f"belief state lacks {key!r}")
            array = np.asarray(state[key])
            if array.shape != shape or not np.all(np.isfinite(array)):
                raise BeliefInputError(
                    f"belief state {key!r}: expected finite values of shape {shape}, "
                    f"got shape {array.shape}"
                )
            target[:n] = array
        for name in table.n_ignored:
            table.n_ignored[name] = int(state.get(f"n_ignored/{name}", 0))
        return table
