"""Row prior knowledge (sec. 2.6.2): parallel rows a known distance apart fitted to the
mapped plants, as lines n . p = offset + m * row_spacing, each a node in the graph that
holds the plants near it across the row only."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from agrislam.backend import GraphBackend
from agrislam.config import RowsConfig
from agrislam.geometry.noise import row_normal
from agrislam.geometry.se2 import wrap_row_angle
from agrislam.records import FieldPrior
from agrislam.snapshot import RowLines

# coarse-to-fine search for the row angle when none is known: 1 deg, then 0.05 deg steps
COARSE_STEP = math.radians(1.0)
FINE_STEP = math.radians(0.05)
GAUSS_NEWTON_ITERATIONS = 5
# objects a fit uses at most
FIT_POINTS = 3000
# a refit that turns the rows by more than this rebuilds the row constraints
REBUILD_ANGLE = math.radians(0.2)
# a given row angle at which the plants are less periodic than this share of their best
# angle's periodicity is contradicted by them: the fitted angle replaces it
CONTRADICTED = 0.5


def periodicity(points: np.ndarray, angles: np.ndarray, spacing: float) -> np.ndarray:
    """|mean of exp(2 pi i n(a) . p / spacing)| per angle: 1 when every point sits on a row
    of the lattice at angle a, near 0 for points spread evenly across the rows."""
    normals = np.stack([-np.sin(angles), np.cos(angles)], axis=1)  # (k, 2)
    phase = 2 * np.pi * (points @ normals.T) / spacing  # (n, k)
    return np.abs(np.exp(1j * phase).mean(axis=0))


def lattice_offset(d: np.ndarray, spacing: float) -> float:
    """Offset o in [0, spacing) that best explains projections d as o + m * spacing."""
    return spacing * (np.angle(np.exp(2j * np.pi * d / spacing).mean()) / (2 * np.pi)) % spacing


def search_angle(points: np.ndarray, spacing: float) -> float:
    """Row angle maximising the periodicity of the projections (coarse, then fine)."""
    coarse = np.arange(-math.pi / 2, math.pi / 2, COARSE_STEP)
    best = coarse[np.argmax(periodicity(points, coarse, spacing))]
    fine = best + np.arange(-COARSE_STEP, COARSE_STEP + FINE_STEP, FINE_STEP)
    return float(fine[np.argmax(periodicity(points, fine, spacing))])


def ambiguity(points: np.ndarray, angle: float, spacing: float) -> float:
    """The highest rival peak of the points' periodicity over the row angle, relative to
    theirs at `angle` (the best): near 1 when another row direction explains them as well
    (a few points lie on a lattice at many angles), low once many points across rows agree.
    A rival is a local maximum of the periodicity other than the one at `angle`."""
    angles = angle + np.arange(COARSE_STEP / 2, math.pi, COARSE_STEP / 2)  # half a turn on
    p = periodicity(points, np.r_[angle, angles], spacing)
    rising, falling = p[1:-1] > p[:-2], p[1:-1] >= p[2:]
    rivals = p[1:-1][rising & falling]
    return float(rivals.max() / max(p[0], 1e-9)) if len(rivals) else 0.0


def fit_rows(
    points: np.ndarray,
    spacing: float,
    angle0: float | None,
    offset0: float | None = None,
    angle_prior: float | None = None,
    angle_sigma: float = 0.0,
    inlier: float = 0.2,
    point_sigma: float = 0.05,
) -> tuple[float, float]:
    """Least-squares row angle and offset (sec. 2.6.2) for points (n, 2), spacing known.

    Starts from `angle0` (searched when None); residuals r_i = n(a) . p_i - o - m_i s with
    m_i the nearest row, points farther than `inlier` (m) from it left out, each residual
    with std `point_sigma`. A known `angle_prior` is a prior on a with std `angle_sigma`;
    `angle_sigma` 0 fixes the angle to it."""
    fixed = angle_prior is not None and angle_sigma == 0.0
    if fixed:
        angle0 = angle_prior
    angle = search_angle(points, spacing) if angle0 is None else float(angle0)
    offset = lattice_offset(points @ row_normal(angle), spacing) if offset0 is None else offset0
    for _ in range(GAUSS_NEWTON_ITERATIONS):
        d = points @ row_normal(angle)
        r = d - offset - np.round((d - offset) / spacing) * spacing
        use = np.abs(r) < inlier
        if use.sum() < 2:
            break
        if fixed:
            offset += r[use].mean()
            continue
        # d r / d a = p . dn/da = -p . (cos a, sin a); d r / d o = -1
        da = -(points[use] @ np.array([math.cos(angle), math.sin(angle)]))
        jac = np.column_stack([da, -np.ones(use.sum())])
        lhs, rhs = jac.T @ jac, -jac.T @ r[use]
        if angle_prior is not None:
            weight = (point_sigma / angle_sigma) ** 2
            lhs[0, 0] += weight
            rhs[0] -= weight * math.remainder(angle - angle_prior, math.pi)
        step = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        angle, offset = angle + step[0], offset + step[1]
    return wrap_row_angle(angle), float(offset)


class RowTracker:
    """Decides when to fit rows, which plants belong to which row, and adds the row nodes
    and constraints to the back end (sec. 2.6.2)."""

    def __init__(self, config: RowsConfig, issues: Counter[str] | None = None) -> None:
        self.config = config
        self.issues = Counter() if issues is None else issues  # a prior replaced is one
        self.spacing = config.row_spacing
        self.angle_prior = (
            None if config.row_angle_deg is None else math.radians(config.row_angle_deg)
        )
        self.angle: float | None = None
        self.offset = 0.0
        self.n_detections = 0
        self.next_fit = config.n_det_est
        self.fits = 0
        self._row_of_index: dict[int, int] = {}  # lattice index m -> back-end row id
        self._next_row = 0
        self._backend: GraphBackend | None = None

    def use_prior(self, field: FieldPrior) -> None:
        """Field knowledge from a log's meta: row spacing, and a row angle unless configured."""
        if field.row_spacing is not None and self.angle is None:
            self.spacing = float(field.row_spacing)
        if field.row_angle_deg is not None and self.angle_prior is None:
            self.angle_prior = math.radians(field.row_angle_deg)

    # ------------------------------------------------------------------ per step
    def after_step(
        self,
        backend: GraphBackend,
        touched_object_ids: np.ndarray,
        n_new_detections: int,
        frames_seen: np.ndarray,
    ) -> None:
        """Count the step's detections; fit (or refit) rows when due; give touched plants
        near a row their row constraint. `frames_seen[i]`: frames object i was seen in."""
        self._backend = backend
        self.n_detections += int(n_new_detections)
        touched = np.asarray(touched_object_ids, dtype=np.int64)
        if self.n_detections >= self.next_fit:
            unfitted = self.angle is None
            self._fit(backend, frames_seen)
            if self.angle is None:  # no unambiguous angle yet: try again soon
                self.next_fit = self.n_detections + self.config.n_det_est
            else:  # refit as the evidence doubles
                self.next_fit = 2 * self.n_detections
                if unfitted:  # the first fit: the objects seen before it join their rows
                    touched = backend.object_ids()
        if self.angle is not None:
            self._assign(backend, touched, frames_seen)

    def _fit_points(
        self, backend: GraphBackend, frames_seen: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Objects seen often enough, evenly thinned to at most FIT_POINTS: a refit of a
        large field then costs no more than one of a mid-sized one."""
        ids = backend.object_ids()
        ids = ids[frames_seen[ids] >= self.config.min_detections]
        ids = ids[:: max(1, -(-len(ids) // FIT_POINTS))]
        return ids, backend.object_positions(ids)

    def _fit(self, backend: GraphBackend, frames_seen: np.ndarray) -> None:
        ids, points = self._fit_points(backend, frames_seen)
        previous = self.angle
        if previous is None and len(ids) < self.config.min_fit_objects:
            return
        if previous is None and self.angle_prior is not None and not self._prior_holds(points):
            return
        angle0 = previous if previous is not None else self.angle_prior
        if angle0 is None:  # the first fit: kept only once no other angle rivals it
            angle0 = search_angle(points, self.spacing)
            if ambiguity(points, angle0, self.spacing) > self.config.first_fit_ambiguity:
                return
        sigma = math.radians(self.config.angle_prior_sigma_deg)
        angle, offset = fit_rows(
            points,
            self.spacing,
            angle0=angle0,
            offset0=None if previous is None else self.offset,
            angle_prior=self.angle_prior,
            angle_sigma=sigma,
            inlier=self.config.max_offset,
            point_sigma=self.config.sigma_cross,
        )
        if previous is not None:
            # keep the lattice numbering: the new offset nearest the old one
            offset = self.offset + math.remainder(offset - self.offset, self.spacing)
        self.angle, self.offset = angle, offset
        self.fits += 1
        if previous is not None and abs(math.remainder(angle - previous, math.pi)) > REBUILD_ANGLE:
            self._rebuild(backend)

    def _prior_holds(self, points: np.ndarray) -> bool:
        """Whether the given row angle may be fitted from: the plants are as periodic at it
        as at their best angle, nearly. If not, and that best angle is unambiguous, it
        replaces the given one (reported); False while it is ambiguous (the first fit waits)."""
        assert self.angle_prior is not None
        best = search_angle(points, self.spacing)
        at = periodicity(points, np.array([self.angle_prior, best]), self.spacing)
        if at[0] >= CONTRADICTED * at[1]:
            return True
        if ambiguity(points, best, self.spacing) > self.config.first_fit_ambiguity:
            return False
        given, fitted = math.degrees(self.angle_prior), math.degrees(best)
        self.issues[
            f"row angle {given:g} deg given, but the plants lie in rows at about {fitted:.0f} "
            "deg: the fitted angle used"
        ] += 1
        self.angle_prior = None
        return True

    def _rebuild(self, backend: GraphBackend) -> None:
        """The rows turned: their constraints are replaced by ones at the new angle."""
        for row in self._row_of_index.values():
            backend.set_row_angle(row, self.angle)

    def _assign(
        self, backend: GraphBackend, object_ids: np.ndarray, frames_seen: np.ndarray
    ) -> None:
        """Plants within max_offset of a row get a constraint to it (none along it)."""
        if len(object_ids) == 0:
            return
        candidates = object_ids[frames_seen[object_ids] >= self.config.min_detections]
        candidates = candidates[backend.rows_of(candidates) < 0]
        if len(candidates) == 0:
            return
        normal = row_normal(self.angle)
        lines = _Lines(self, backend, normal)
        positions = backend.object_positions(candidates)
        for object_id, point in zip(candidates.tolist(), positions, strict=True):
            row = lines.row_for(point)
            if row is not None:
                backend.add_row_constraint(object_id, row)

    def _new_row(self, backend: GraphBackend, index: int, point: np.ndarray) -> int:
        """A row node for lattice row `index` at `point` on its line, with spacing
        constraints to its existing neighbours."""
        row = self._next_row
        self._next_row += 1
        backend.add_row(row, point, self.angle)
        self._row_of_index[index] = row
        for neighbour in (index - 1, index + 1):
            if neighbour in self._row_of_index:
                lower, upper = sorted((index, neighbour))
                backend.add_row_spacing(
                    self._row_of_index[lower], self._row_of_index[upper], self.spacing
                )
        return row

    # ------------------------------------------------------------------ map out
    def _rows_in_order(self) -> np.ndarray:
        """Back-end row ids sorted across the field (by lattice index)."""
        return np.array([self._row_of_index[m] for m in sorted(self._row_of_index)], np.int64)

    def row_of(self, object_ids: np.ndarray) -> np.ndarray:
        """Index of each object's row in `lines().offsets`, -1 for none."""
        ids = np.asarray(object_ids, dtype=np.int64)
        if self._backend is None or not self._row_of_index:
            return np.full(len(ids), -1, dtype=np.int64)
        rows = self._backend.rows_of(ids)
        order = self._rows_in_order()
        rank = np.full(self._next_row, -1, dtype=np.int64)
        rank[order] = np.arange(len(order))
        return np.where(rows >= 0, rank[np.maximum(rows, 0)], -1)

    def lines(self) -> RowLines | None:
        """The rows across the field as lines n . p = offsets[k], from the optimised row
        nodes; `row_of` indexes them."""
        if self.angle is None or self._backend is None:
            return None
        points = self._backend.row_points(self._rows_in_order())
        return RowLines(self.angle, points @ row_normal(self.angle))


class _Lines:
    """The current row lines during one assignment pass: existing rows as optimised (their
    nodes move with the map, so a drifting map still finds its rows), new rows one row
    spacing from the nearest existing one, or on the fitted lattice while there is none."""

    def __init__(self, tracker: RowTracker, backend: GraphBackend, normal: np.ndarray) -> None:
        self.tracker, self.backend, self.normal = tracker, backend, normal
        self.indices = sorted(tracker._row_of_index)
        rows = np.array([tracker._row_of_index[m] for m in self.indices], dtype=np.int64)
        self.rows = rows.tolist()
        self.offsets = (backend.row_points(rows) @ normal).tolist() if len(rows) else []

    def row_for(self, point: np.ndarray) -> int | None:
        tracker, spacing = self.tracker, self.tracker.spacing
        max_offset = tracker.config.max_offset
        d = float(point @ self.normal)
        if self.offsets:
            k = int(np.argmin(np.abs(np.asarray(self.offsets) - d)))
            if abs(d - self.offsets[k]) < max_offset:
                return self.rows[k]
            steps = round((d - self.offsets[k]) / spacing)
            index, base = self.indices[k] + steps, self.offsets[k] + steps * spacing
            if index in tracker._row_of_index:
                return None  # that row exists, and the plant is not on it
        else:
            index = round((d - tracker.offset) / spacing)
            base = tracker.offset + index * spacing
        if abs(d - base) >= max_offset:
            return None
        row = tracker._new_row(self.backend, index, point - (d - base) * self.normal)
        self.indices.append(index)
        self.rows.append(row)
        self.offsets.append(base)
        return row
