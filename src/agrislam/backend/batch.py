"""The paper's back end (sec. 2.6): Levenberg-Marquardt or Powell's dog leg over the whole
graph at every step, warm-started from the previous solution. The baseline of every
benchmark."""

from __future__ import annotations

import gtsam
import numpy as np

from agrislam.backend.base import BackendBase
from agrislam.backend.graph import make_factor
from agrislam.backend.values import insert_value, value_array
from agrislam.config import RowsConfig, SlamConfig

# convergence of one step's solve; the graph starts at the previous optimum, so a step
# usually takes a few iterations (g2o's defaults are in the same range)
MAX_ITERATIONS = 100
RELATIVE_ERROR_TOL = 1e-5
ABSOLUTE_ERROR_TOL = 1e-5


def optimizer_params(slam: SlamConfig) -> gtsam.NonlinearOptimizerParams:
    """LM (lambda starts small: the warm start is near the optimum) or Dogleg parameters."""
    params = (
        gtsam.LevenbergMarquardtParams() if slam.batch_optimizer == "lm" else gtsam.DoglegParams()
    )
    params.setMaxIterations(MAX_ITERATIONS)
    params.setRelativeErrorTol(RELATIVE_ERROR_TOL)
    params.setAbsoluteErrorTol(ABSOLUTE_ERROR_TOL)
    return params


def solve(
    graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, slam: SlamConfig
) -> gtsam.Values:
    """One whole-graph solve with the configured optimiser."""
    params = optimizer_params(slam)
    if slam.batch_optimizer == "lm":
        return gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    return gtsam.DoglegOptimizer(graph, initial, params).optimize()


class BatchBackend(BackendBase):
    """Whole-graph optimisation every step (the paper's g2o LM/Dogleg, on GTSAM)."""

    def __init__(self, slam: SlamConfig, rows: RowsConfig) -> None:
        super().__init__(slam, rows)
        self._factors = gtsam.NonlinearFactorGraph()
        self._slot: dict[int, int] = {}  # factor id -> index in self._factors
        self._values = gtsam.Values()  # solution of the last update (+ new guesses)
        self._guess: dict[int, np.ndarray] = {}  # nodes no factor uses yet
        self._marginals: gtsam.Marginals | None = None
        self._cov_cache: dict[int, np.ndarray] = {}
        self._dirty = False

    # -------------------------------------------------------- pickle (checkpoints)
    def __getstate__(self) -> dict:
        """The state to pickle: the graph and the solution in GTSAM's serialisation (exact
        to the last bit), the marginals dropped (they are computed again when asked)."""
        state = self.__dict__.copy()
        state.update(_factors=self._factors.serialize(), _values=self._values.serialize())
        state.update(_marginals=None, _cov_cache={})
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._factors = gtsam.NonlinearFactorGraph()
        self._factors.deserialize(state["_factors"])
        self._values = gtsam.Values()
        self._values.deserialize(state["_values"])

    # ------------------------------------------------------------ solver hooks
    def _insert(self, key: int, value: np.ndarray) -> None:
        self._guess[key] = np.asarray(value, dtype=float)

    def _add(self, fid: int) -> None:
        factor = self.graph.factors[fid]
        for key in factor.keys:
            if key in self._guess:
                insert_value(self._values, key, self._guess.pop(key))
        self._slot[fid] = self._factors.size()
        self._factors.push_back(make_factor(factor, self.slam))
        self._changed()

    def _remove(self, fid: int) -> None:
        self._factors.remove(self._slot.pop(fid))
        self._changed()

    def _changed(self) -> None:
        self._dirty = True
        self._marginals = None
        self._cov_cache.clear()

    def _forget(self, key: int, into: int | None) -> None:
        self._guess.pop(key, None)
        if self._values.exists(key):
            self._values.erase(key)

    def estimate(self, key: int) -> np.ndarray:
        if key in self._guess:
            return self._guess[key]
        return value_array(self._values, key)

    # ------------------------------------------------------------------ solving
    def update(self) -> bool:
        """Solve the whole graph, warm-started from the last solution (no window to fold)."""
        if self._dirty:
            self._values = solve(self._factors, self._values, self.slam)
            self._changed()
            self._dirty = False
        return False

    def refine(self) -> None:
        self.update()

    def current_pose_covariance(self, robot: str) -> np.ndarray:
        """(3, 3) marginal covariance of the robot's latest pose (x, y, theta)."""
        key = self.graph.robot(robot).keys[-1]
        if key not in self._cov_cache:
            if self._marginals is None:
                self._marginals = gtsam.Marginals(self._factors, self._values)
            self._cov_cache[key] = self._marginals.marginalCovariance(key)
        return self._cov_cache[key]

    def object_covariances(self, object_ids: np.ndarray) -> np.ndarray:
        """(k, 2, 2) marginal covariances; one factorisation of the graph per step, cached."""
        out = np.empty((len(object_ids), 2, 2))
        for n, object_id in enumerate(object_ids):
            key = self.graph.require_object(int(object_id))
            if key in self._guess:
                raise ValueError(f"object {object_id} has no observation yet")
            if key not in self._cov_cache:
                if self._marginals is None:
                    self._marginals = gtsam.Marginals(self._factors, self._values)
                self._cov_cache[key] = self._marginals.marginalCovariance(key)
            out[n] = self._cov_cache[key]
        return out

    def live_size(self) -> int:
        """Nodes in the solve: every one a factor uses."""
        return self._values.size()

    # for g2o export and tests: the solver's graph and solution
    def solution(self) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        return self._factors, self._values
