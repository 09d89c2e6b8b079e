"""Time update of size-like attributes by the asymptotic growth model of App. B,
dx/dt = alpha (l_max - x): the exact mean/variance propagation of a continuous attribute
and the transition matrix A(dt) of a discrete one (its values read as n equal length cells).

Records count time in seconds, the model's rate is per day (config.SECONDS_PER_DAY).
"""

from __future__ import annotations

import numpy as np

from agrislam.config import SECONDS_PER_DAY, GrowthModel


def _days(dt_s: np.ndarray | float) -> np.ndarray:
    # a belief is never propagated backwards: the growth map has no stochastic inverse
    return np.maximum(np.asarray(dt_s, dtype=float), 0.0) / SECONDS_PER_DAY


def grown_mean(mean: np.ndarray, model: GrowthModel, dt_s: np.ndarray | float) -> np.ndarray:
    """f(x, dt) = l_max - (l_max - x) e^{-alpha dt} (App. B)."""
    # written as x + (l_max - x)(1 - e^{-alpha dt}): exact at dt = 0, accurate for small dt
    return mean - (model.l_max - mean) * np.expm1(-model.rate_per_day * _days(dt_s))


def grown_variance(var: np.ndarray, model: GrowthModel, dt_s: np.ndarray | float) -> np.ndarray:
    """Variance after dt: the Jacobian e^{-alpha dt} squared times var, plus process noise.

    The noise is white with `variance_per_day` intensity q, integrated exactly through the
    same linear ODE: q (1 - e^{-2 alpha dt}) / (2 alpha), which is q dt to first order. Exact
    integration makes two steps equal one (dt1 + dt2), so when a lazily updated belief is
    brought forward does not change it.
    """
    grown = -np.expm1(-2.0 * model.rate_per_day * _days(dt_s))  # 1 - e^{-2 alpha dt}
    return (1.0 - grown) * var + model.variance_per_day * grown / (2.0 * model.rate_per_day)


def transition_matrices(n: int, model: GrowthModel, dt_s: np.ndarray) -> np.ndarray:
    """A(dt) of App. B for each dt (k,): (k, n, n), column j = where cell j's mass goes.

    The paper's recursion a_ij = p_ij - sum_{k<i} a_kj, with 0 for p_ij <= 0 and the
    cumulative capped at 1 for p_ij >= 1, is a difference of the clipped cumulative
    fractions: a_ij = clip(p_ij) - clip(p_{i-1,j}). (Read literally, "a_ij = 1 for
    p_ij >= 1" would put mass 1 in every cell above the first full one.) p_ij is the
    fraction of cell j that stays below the top of cell i after dt:
    p_ij = (f^{-1}(i l_max / n, dt) - (j - 1) l_max / n) / (l_max / n)
         = n - (n - i) e^{alpha dt} - (j - 1), independent of l_max.
    Optional process noise leaks 1 - (1 - w)^dt of the mass uniformly over the cells.
    """
    days = _days(dt_s)
    # e^{alpha dt}; beyond n + 1 every p_ij with i < n is already <= 0, so capping it there
    # changes no entry and keeps a long dt from overflowing to inf (0 * inf = nan at i = n)
    growth = np.exp(np.minimum(model.rate_per_day * days, np.log(n + 1.0)))[:, None, None]
    i = np.arange(1, n + 1, dtype=float)[None, :, None]
    j = np.arange(1, n + 1, dtype=float)[None, None, :]
    p = n - (n - i) * growth - (j - 1.0)  # App. B p_ij
    cumulative = np.clip(p, 0.0, 1.0)
    A = np.diff(cumulative, axis=1, prepend=0.0)  # App. B a_ij
    leak = (1.0 - (1.0 - model.process_noise) ** days)[:, None, None]
    return (1.0 - leak) * A + leak / n


def transition_matrix(n: int, model: GrowthModel, dt_s: float) -> np.ndarray:
    """A(dt) for a single dt: (n, n)."""
    return transition_matrices(n, model, np.array([dt_s], dtype=float))[0]


class TransitionCache:
    """A(dt) of one discrete attribute, kept per dt: objects seen in the same frame share
    their dt, so a frame or an export needs only a few distinct matrices."""

    def __init__(self, n: int, model: GrowthModel, max_entries: int = 4096) -> None:
        self.n, self.model, self.max_entries = n, model, max_entries
        self._cache: dict[float, np.ndarray] = {}

    def __call__(self, dt_s: np.ndarray) -> np.ndarray:
        """A(dt) for each dt (k,): (k, n, n)."""
        unique, inverse = np.unique(np.maximum(dt_s, 0.0), return_inverse=True)
        if len(unique) == 0:  # no objects to bring forward (np.stack needs one array)
            return np.empty((0, self.n, self.n))
        if len(unique) > self.max_entries // 4:  # a bulk read: computing beats looking up
            return transition_matrices(self.n, self.model, unique)[inverse]
        wanted = unique.tolist()
        missing = [dt for dt in wanted if dt not in self._cache]
        if len(self._cache) + len(missing) > self.max_entries:
            self._cache.clear()  # dts drift with the survey: old ones are not coming back
            missing = wanted
        if missing:
            computed = transition_matrices(self.n, self.model, np.array(missing))
            self._cache.update(zip(missing, computed, strict=True))
        matrices = np.stack([self._cache[dt] for dt in wanted])
        return matrices[inverse]


def propagate(belief: np.ndarray, A: np.ndarray) -> np.ndarray:
    """xi(t + dt) = A(dt) xi(t) for each belief (k, n) with its own A (k, n, n)."""
    return np.einsum("kij,kj->ki", A, belief)
