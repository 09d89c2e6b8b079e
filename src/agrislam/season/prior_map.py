"""A saved map as the prior of the next survey: every plant's position with its covariance,
its beliefs and the absolute time they refer to, which the world carries to the new
survey's time through the growth model (sec. 2.5.2, App. B) when it reads them."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agrislam.config import FieldSchema, SemanticsConfig
from agrislam.semantics.beliefs import BeliefTable
from agrislam.snapshot import MapSnapshot


@dataclass(frozen=True, slots=True)
class PriorMap:
    """The plants of a saved map (struct of arrays, one row per plant).

    `t_abs`: absolute time (Unix s) the beliefs refer to; `survey`: how many surveys the
    map holds (the new one is number `survey`); `row_angle`: the saved rows' direction."""

    schema: FieldSchema | None
    ids: np.ndarray  # (k,) int, the plants' ids, kept across surveys
    xy: np.ndarray  # (k, 2) map frame
    cov: np.ndarray  # (k, 2, 2)
    n_meas: np.ndarray  # (k,)
    discrete: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (k, n)
    continuous: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    t_abs: float = 0.0
    survey: int = 1
    row_angle: float | None = None

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def from_snapshot(cls, snapshot: MapSnapshot, t_abs: float, survey: int = 1) -> PriorMap:
        o = snapshot.objects
        cov = np.asarray(o.cov, dtype=float).reshape(-1, 2, 2)
        bad = ~np.all(np.isfinite(cov.reshape(-1, 4)), axis=1) | ~np.all(np.isfinite(o.xy), axis=1)
        if bad.any():
            raise ValueError(f"saved plants {o.ids[bad][:5].tolist()} have no finite position")
        return cls(
            schema=snapshot.schema,
            ids=np.asarray(o.ids, dtype=np.int64),
            xy=np.asarray(o.xy, dtype=float),
            cov=cov,
            n_meas=np.asarray(o.n_meas, dtype=np.int64),
            discrete=dict(o.discrete),
            continuous=dict(o.continuous),
            t_abs=float(t_abs),
            survey=survey,
            row_angle=None if snapshot.rows is None else float(snapshot.rows.angle),
        )

    def belief_table(self, config: SemanticsConfig, belief_time: float) -> BeliefTable:
        """A belief table whose row `id` holds saved plant `id`'s beliefs, stamped
        `belief_time` (the saved survey's time in the new survey's clock: reading them at
        t applies A(t - belief_time), App. B); rows of no saved plant hold the initial
        beliefs (the world retires them)."""
        n = int(self.ids.max()) + 1 if len(self.ids) else 0
        empty = BeliefTable(self.schema, config)
        empty.add(n, belief_time)
        state = empty.state()
        state["n_meas"][self.ids] = self.n_meas
        for name, p in self.discrete.items():
            state[f"p/{name}"][self.ids] = p
        for name, (mean, var) in self.continuous.items():
            state[f"mean/{name}"][self.ids] = mean
            state[f"var/{name}"][self.ids] = var
        return BeliefTable.from_state(self.schema, config, state)
