"""Data association (sec. 2.4): spatial gating, the association matrix, and GNN.

The association matrix entry of detection m and object n is

    a_mn = prod_{i in Y_m} (1 - w_sem * SSS_imn) * min(|e|^2 / d_inter^2, e^T K_n^-1 e)

with e = z_n - z_m, K_n the object's marginal position covariance; entries above 1
are forbidden; the assignment minimises the sum (scipy's linear_sum_assignment).
Only objects within the largest distance the formula can still accept are looked
at, found through the spatial index (mapping/spatial_index.py), so a frame's cost does not grow
with it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from agrislam.config import AssociationConfig
from agrislam.estimation.noise_calibration import mahalanobis
from agrislam.geometry.placed import PlacedDetections
from agrislam.records import DiscreteMeasurement, Measurement
from agrislam.semantics.beliefs import BeliefTable

FORBIDDEN = 1e6  # cost of an assignment the paper forbids (a_mn > 1)
RIVAL_REACH = 3.0  # in d_inter: a detection's rivals, compared on one metric


def semantic_term(
    beliefs: BeliefTable,
    object_ids: np.ndarray,
    measurements: Sequence[Mapping[str, Measurement]],
    w_sem: float,
    t: float,
) -> np.ndarray:
    """prod_i (1 - w_sem * SSS_imn) over each detection's measured attributes: (m, k)."""
    schema = beliefs.schema
    term = np.ones((len(measurements), len(object_ids)))
    if schema is None or len(object_ids) == 0:
        return term
    for name, spec in schema.attributes.items():
        rows = [j for j, ms in enumerate(measurements) if name in ms]
        if not rows:
            continue
        got = [measurements[j][name] for j in rows]
        if isinstance(got[0], DiscreteMeasurement):
            index = {v: i for i, v in enumerate(spec.values)}  # type: ignore[union-attr]
            value_idx = np.array([index[m.value] for m in got])  # type: ignore[union-attr]
            p = np.array([m.p for m in got])  # type: ignore[union-attr]
            belief = beliefs.probabilities(name, object_ids, t)  # (k, n)
            sss = belief[:, value_idx].T * p[:, None]  # SSS^d = P(x_n = s_m) p_m
        else:
            mean, var = beliefs.gaussian(name, object_ids, t)
            value = np.array([m.value for m in got])[:, None]  # type: ignore[union-attr]
            var_m = np.array([m.var for m in got])[:, None]  # type: ignore[union-attr]
            s2 = var[None, :] + var_m
            # SSS^c = tanh(N(s_n - s_m; 0, sigma_n^2 + sigma_m^2)), sec. 2.4
            sss = np.tanh(
                np.exp(-0.5 * (mean[None, :] - value) ** 2 / s2) / np.sqrt(2 * np.pi * s2)
            )
        term[rows] *= 1.0 - w_sem * sss
    return term


def distance_term(
    detection_xy: np.ndarray,
    object_xy: np.ndarray,
    covariance: np.ndarray,
    d_inter: float,
    gate_chi2: float = 1.0,
) -> np.ndarray:
    """min(|e|^2 / d_inter^2, e^T K^-1 e / gate_chi2) for every detection x object pair:
    (m, k). `covariance` is K_n per object (k, 2, 2), as sec. 2.4, or per pair (m, k, 2, 2)."""
    e = object_xy[None, :, :] - detection_xy[:, None, :]  # e_mn = z_n - z_m
    euclidean = np.einsum("mki,mki->mk", e, e) / d_inter**2
    k = np.broadcast_to(covariance, (*e.shape[:2], 2, 2))
    return np.minimum(euclidean, mahalanobis(e, k) / gate_chi2)


def innovation_covariance(
    detections: PlacedDetections,
    object_cov: np.ndarray,
    drift_cov: np.ndarray | None = None,
    drift_known: np.ndarray | None = None,
) -> np.ndarray:
    """(m, k, 2, 2) covariance of e_mn, the tighter of two upper bounds (a deviation from
    sec. 2.4's K_n, see `association.innovation_gate`):

    - absolute: K_n + R_m + the robot pose marginal at the detection, which ignores that
      the robot and an object it saw lately are uncertain together;
    - relative (where the robot's chain since it last saw n is known): R_m for the
      detection, R_m again for the object relative to the pose that last saw it, and the
      chain's drift in between (geometry/drift.py).
    """
    pose_cov = detections.pose_cov if detections.pose_cov is not None else 0.0
    absolute = object_cov[None, :, :, :] + (detections.cov + pose_cov)[:, None, :, :]
    if drift_cov is None or drift_known is None or not drift_known.any():
        return absolute
    relative = 2.0 * detections.cov[:, None, :, :] + drift_cov
    trace = np.trace(relative, axis1=2, axis2=3) < np.trace(absolute, axis1=2, axis2=3)
    tighter = drift_known[None, :] & trace
    return np.where(tighter[..., None, None], relative, absolute)


def accepted_nis(
    detections: PlacedDetections,
    chosen: np.ndarray,
    object_xy: np.ndarray,
    object_cov: np.ndarray,
    own: np.ndarray | None = None,
) -> np.ndarray:
    """(m,) the normalised innovation squared e^T S^-1 e of each detection the GNN put on a
    candidate (`chosen`, as `assign` returns it), NaN for the others: S the detection's own
    innovation covariance `own` (m, k, 2, 2) where the gate compared the whole innovation,
    else the absolute bound K_n + R_m + the pose marginal. For a consistent map it follows
    chi2 with 2 dof: the run's health reads it."""
    nis = np.full(len(chosen), np.nan)
    rows = np.flatnonzero(chosen >= 0)
    cols = chosen[rows]
    if own is not None:
        s = own[rows, cols]
    else:
        pose_cov = detections.pose_cov[rows] if detections.pose_cov is not None else 0.0
        s = object_cov[cols] + detections.cov[rows] + pose_cov
    nis[rows] = mahalanobis(object_xy[cols] - detections.xy[rows], s)
    return nis


def rivals_on_one_metric(
    innovation: np.ndarray, detection_xy: np.ndarray, object_xy: np.ndarray, d_inter: float
) -> np.ndarray:
    """(m, k, 2, 2) `innovation` with each detection's rivals, the candidates within
    RIVAL_REACH d_inter of it, given their mean: close neighbours are measured alike and
    the nearest wins (each with its own, a neighbour with a wider covariance takes a
    detection cheaply; docs/decisions.md)."""
    d = np.linalg.norm(object_xy[None, :, :] - detection_xy[:, None, :], axis=2)
    rivals = d < RIVAL_REACH * d_inter
    share = rivals / np.maximum(rivals.sum(axis=1, keepdims=True), 1)
    mean = np.einsum("mk,mkij->mij", share, innovation)
    return np.where(rivals[..., None, None], mean[:, None], innovation)


def association_matrix(
    detections: PlacedDetections,
    object_ids: np.ndarray,
    object_xy: np.ndarray,
    object_cov: np.ndarray,
    beliefs: BeliefTable,
    config: AssociationConfig,
    d_inter: float,
    t: float,
    innovation: np.ndarray | None = None,
) -> np.ndarray:
    """The matrix A of sec. 2.4 over the frame's detections x candidate objects; with
    `innovation` (m, k, 2, 2) the distance term compares e to it instead of K_n."""
    covariance = object_cov if innovation is None else innovation
    distance = distance_term(detections.xy, object_xy, covariance, d_inter, config.gate_chi2)
    if not config.use_semantics:
        return distance
    semantic = semantic_term(beliefs, object_ids, detections.measurements, config.w_sem, t)
    return semantic * distance


def assign(matrix: np.ndarray) -> np.ndarray:
    """GNN: the minimum-cost assignment with entries above 1 forbidden; for each row the
    chosen column, or -1 where the detection starts a new object."""
    chosen = np.full(matrix.shape[0], -1)
    if matrix.size == 0:
        return chosen
    cost = np.where(matrix <= 1.0, matrix, FORBIDDEN)
    rows, cols = linear_sum_assignment(cost)
    ok = cost[rows, cols] <= 1.0
    chosen[rows[ok]] = cols[ok]
    return chosen


def gated_matches(cost: np.ndarray, gate: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns matched one to one at the least total `cost`, each within `gate`
    (the GNN of `assign` over `cost / gate`)."""
    chosen = assign(cost / gate)
    rows = np.flatnonzero(chosen >= 0)
    return rows, chosen[rows]


def max_association_distance(
    d_inter: float, sigma_max: float, w_sem: float, n_measured: int
) -> float:
    """The farthest a detection can be from an object and still get a_mn <= 1.

    SSS <= 1, so the semantic term is at least (1 - w_sem)^|Y| and the distance term
    may reach (1 - w_sem)^-|Y|: |e| <= max(d_inter, sqrt(lambda_max(K))) (1 - w_sem)^(-|Y|/2).
    (Sec. 2.4 states the looser bound max(d_inter, sqrt(lambda)) w_sem^-|Y|.)
    """
    return max(d_inter, sigma_max) * (1.0 - w_sem) ** (-0.5 * n_measured)
