"""The reference a mapper is measured against on a real log: a batch GTSAM solve given the
TRUE association (each detection's `truth_id`), nothing else of the truth, which is used
only to score the solve afterwards.

    python benchmarks/real_reference.py LOG [--t-max 300] [--passes 3]

Two kinds of log:

- range and bearing detections (MRCLAM): one Pose2 node per robot at each frame and on a
  1 s grid between, odometry factors from the integrated track, and per robot a
  calibration node c = (a, s, k, b0, dt) with weak priors: the range read as
  r_meas = a + s r - k r (1 - cos beta) (depth-like for k ~ s), the bearing offset b0 and the
  camera's clock dt seconds after the odometry's (the pose moved on by the odometry's body
  velocity). A detection factor (gtsam.CustomFactor, analytic Jacobians) per sighting under
  a robust kernel (Huber, then Cauchy: a misread label's bearing must weigh nothing), its
  sigmas estimated pass by pass from the solve's own residuals;
- xy detections (Victoria Park): a node per odometry record with the log's increments and
  covariances, each detection a bearing-range factor of its xy and covariance, solved by
  Levenberg-Marquardt.

The solve is scored by agrislam's own evaluation (real_scoring.py), like agrislam's map."""

from __future__ import annotations

import argparse
import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np

from agrislam.geometry.se2 import compose
from agrislam.records import Detections, Odometry, RobotStart
from agrislam.snapshot import Trajectory
from real_scoring import (
    Row,
    Survey,
    console,
    read_survey,
    row_cells,
    score_against,
    solution_snapshot,
    table,
)

X = gtsam.symbol_shorthand.X
L = gtsam.symbol_shorthand.L
C = gtsam.symbol_shorthand.C

GRID_S = 1.0  # s between pose nodes where no frame puts one
NO_CALIBRATION = np.array([0.0, 1.0, 0.0, 0.0, 0.0])  # (a, s, k, b0, dt)
CALIBRATION_SIGMA = np.array([0.2, 0.1, 0.5, 0.05, 0.5])  # the weak priors around it
# the odometry of integrated commanded velocities: sigma^2 = (per sqrt s)^2 dt + (share of
# the motion)^2, for the position (m) and the heading (rad)
ODOMETRY = {"xy_per_sqrt_s": 0.005, "xy_share": 0.05, "th_per_sqrt_s": 0.03, "th_share": 0.08}
NOISE_SAMPLE = 1500  # detections whose leverage is computed for the noise estimate
HUBER, CAUCHY = 1.345, 2.3849  # kernel widths, in sigmas
SOLVER_ITERATIONS, SOLVER_TOLERANCE = 60, 1e-6


@dataclass
class Reference:
    """A solve by true association: each landmark's position, each robot's trajectory and
    its dead reckoning (the initial values), what the solve estimated and its wall time."""

    landmarks: dict[str, np.ndarray]
    trajectories: dict[str, Trajectory]
    dead_reckoning: dict[str, Trajectory]
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)

    def row(self, survey: Survey) -> Row:
        """The solve's row against the log's truth; against itself where the log has none
        (then only its size and wall time say anything). Its association is the truth's."""
        truth = {r.id: r.xy for r in survey.truth_objects()} or self.landmarks
        tracks = _truth_tracks(survey) or self.trajectories
        snapshot = solution_snapshot(self.landmarks, self.trajectories, self.dead_reckoning)
        metrics = score_against(snapshot, truth, tracks)
        metrics["association"] = {"purity": 1.0, "completeness": 1.0}
        return Row.of(metrics, len(truth), self.wall_s)


def _truth_tracks(survey: Survey) -> dict[str, Trajectory]:
    """Each robot's true trajectory in time order."""
    out: dict[str, list] = {}
    for pose in survey.truth_poses():
        out.setdefault(pose.robot, []).append((pose.t, *pose.pose))
    tracks = {}
    for robot, rows in out.items():
        a = np.array(sorted(rows))
        tracks[robot] = Trajectory(robot, a[:, 0], a[:, 1:])
    return tracks


def solve_reference(
    survey: Survey, passes: int = 3, log: Callable[[str], None] = print
) -> Reference:
    """The reference solve of the survey, by the kind of its detections."""
    start = time.perf_counter()
    detections = [d for f in survey.frames for d in f.objects]
    if any(d.range is not None for d in detections):
        reference = RangeBearingProblem(survey).solve(passes, log)
    else:
        reference = solve_points(survey)
    reference.wall_s = time.perf_counter() - start
    return reference


# ------------------------------------------------------------- range-bearing: the model


def interpolated(track: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """(n, 3) poses of a (t, x, y, unwrapped heading) track at times `t`."""
    t = np.atleast_1d(t)
    return np.column_stack([np.interp(t, track[:, 0], track[:, i]) for i in (1, 2, 3)])


def body_velocity(track: np.ndarray, t: float, h: float = 0.1) -> tuple[float, float]:
    """The odometry's forward speed and turn rate at `t` (central difference over 2 h)."""
    a, b = interpolated(track, [t - h, t + h])
    d = b - a
    forward = math.cos(a[2]) * d[0] + math.sin(a[2]) * d[1]
    return forward / (2 * h), d[2] / (2 * h)


def pose2(p: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))


def predict(
    pose: gtsam.Pose2, landmark: np.ndarray, cal: np.ndarray, v: float, w: float, jacobians: bool
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """The (bearing, range) the calibrated camera reads of `landmark` from `pose` (the
    robot moved on for the clock offset at forward speed v, turn rate w) and, if asked, the
    Jacobians by the pose's local coordinates (2x3), the landmark (2x2) and the calibration
    (2x5). Plain floats: the solver calls it once per factor and iteration."""
    a, s, k, b0, dt = cal
    x, y, th = pose.x(), pose.y(), pose.theta()
    ux, uth = v * dt, w * dt
    ct, st = math.cos(th), math.sin(th)
    px, py, phi = x + ct * ux, y + st * ux, th + uth
    cp, sp = math.cos(phi), math.sin(phi)
    dx, dy = landmark[0] - px, landmark[1] - py
    qx, qy = cp * dx + sp * dy, -sp * dx + cp * dy  # the landmark in the camera frame
    r2 = qx * qx + qy * qy
    r = math.sqrt(r2)
    beta = math.atan2(qy, qx)
    cb, sb = qx / r, qy / r
    predicted = np.array([beta + b0, a + s * r - k * r * (1.0 - cb)])
    if not jacobians:
        return predicted, None
    # (bearing, range) by the camera-frame point q
    bq = (-qy / r2, qx / r2)
    drm_dr, drm_db = s - k * (1.0 - cb), -k * r * sb
    mq = (bq, (drm_dr * cb + drm_db * bq[0], drm_dr * sb + drm_db * bq[1]))
    # q by the camera pose (px, py, phi): [-R^T | (qy, -qx)]
    qp = ((-cp, -sp, qy), (sp, -cp, -qx))
    mp = [[mq[i][0] * qp[0][j] + mq[i][1] * qp[1][j] for j in range(3)] for i in range(2)]
    # the camera pose by the robot pose's local coordinates (translation turned by th)
    hp, hl, hc = np.empty((2, 3)), np.empty((2, 2)), np.zeros((2, 5))
    for i in range(2):
        m0, m1, m2 = mp[i]
        hp[i] = (m0 * ct + m1 * st, -m0 * st + m1 * ct, m2 - m0 * st * ux + m1 * ct * ux)
        hl[i] = (-m0, -m1)  # q by the landmark is R^T: minus q by the position
        hc[i, 4] = m0 * ct * v + m1 * st * v + m2 * w
    hc[1, :3] = (1.0, r, -r * (1.0 - cb))
    hc[0, 3] = 1.0
    return predicted, (hp, hl, hc)


def detection_factor(
    noise: gtsam.noiseModel.Base, keys: tuple[int, int, int], sighting: Sighting
) -> gtsam.CustomFactor:
    """The factor of one sighting on (pose, landmark, calibration)."""
    measured = np.array([sighting.bearing, sighting.range])
    kx, kl, kc = keys

    def error(_: gtsam.CustomFactor, values: gtsam.Values, jacobians: list | None) -> np.ndarray:
        cal = values.atVector(kc)
        predicted, h = predict(
            values.atPose2(kx),
            values.atPoint2(kl),
            cal,
            sighting.v,
            sighting.w,
            jacobians is not None,
        )
        e = predicted - measured
        e[0] = (e[0] + math.pi) % (2 * math.pi) - math.pi
        if jacobians is not None and h is not None:
            jacobians[0], jacobians[1], jacobians[2] = h
        return e

    return gtsam.CustomFactor(noise, list(keys), error)


@dataclass(frozen=True)
class Sighting:
    """One detection of a landmark: by whom, when (a pose node's time), what was read and
    the robot's odometry speed and turn rate then."""

    robot: str
    t: float
    range: float
    bearing: float
    landmark: str
    v: float
    w: float


@dataclass
class NoiseModel:
    """The detection sigmas: bearing (rad) and range r0 + r1 r (m)."""

    sigma_bearing: float
    r0: float
    r1: float = 0.0

    def range_sigma(self, r: np.ndarray | float) -> np.ndarray | float:
        return self.r0 + self.r1 * r

    def __str__(self) -> str:
        return f"sigma_b {self.sigma_bearing:.4f} rad, sigma_r {self.r0:.3f} + {self.r1:.3f} r m"


# ----------------------------------------------------------- range-bearing: the problem


class RangeBearingProblem:
    """The graph of a range-bearing survey by true association (module doc)."""

    def __init__(self, survey: Survey) -> None:
        self.survey = survey
        self.tracks = survey.odometry_tracks()
        self.starts = survey.starts
        self.robots = sorted(self.tracks)
        node_t: dict[str, set[float]] = {r: set() for r in self.robots}
        for frame in survey.frames:
            node_t[frame.robot].add(round(frame.t, 4))
        for robot, track in self.tracks.items():
            node_t[robot].update(np.round(np.arange(track[0, 0], track[-1, 0], GRID_S), 4))
            node_t[robot].add(round(float(track[0, 0]), 4))
        self.node_t = {r: np.array(sorted(node_t[r])) for r in self.robots}
        self.key = {}
        for robot in self.robots:
            for t in self.node_t[robot]:
                self.key[(robot, float(t))] = X(len(self.key))
        self.cal_key = {r: C(i) for i, r in enumerate(self.robots)}
        truth = {r.id for r in survey.truth_objects()}
        ids = [i for i in survey.landmarks_seen() if not truth or i in truth]
        self.landmark_ids = sorted(ids, key=lambda s: (len(s), s))
        self.landmark_key = {name: L(i) for i, name in enumerate(self.landmark_ids)}
        self.sightings = []
        for frame in survey.frames:
            v, w = body_velocity(self.tracks[frame.robot], frame.t)
            t = round(frame.t, 4)
            for d in frame.objects:
                if d.truth_id in self.landmark_key and d.range is not None:
                    sighting = Sighting(frame.robot, t, d.range, d.bearing, d.truth_id, v, w)
                    self.sightings.append(sighting)
        sigmas = [(d.sigma_bearing, d.sigma_range) for f in survey.frames for d in f.objects]
        bearing, rng = np.nanmedian(np.array(sigmas, dtype=float), axis=0)
        self.logged_noise = NoiseModel(float(bearing), float(rng))

    def _keys(self, s: Sighting) -> tuple[int, int, int]:
        return self.key[(s.robot, s.t)], self.landmark_key[s.landmark], self.cal_key[s.robot]

    def dead_reckoning(self) -> dict[str, np.ndarray]:
        """(n, 3) each robot's odometry at its node times, from its start pose."""
        out = {}
        for robot in self.robots:
            track, times = self.tracks[robot], self.node_t[robot]
            start = self.starts.get(robot)
            origin = pose2(start.pose) if start is not None else gtsam.Pose2()
            first = pose2(interpolated(track, track[0, 0])[0])
            poses = [origin.compose(first.between(pose2(p))) for p in interpolated(track, times)]
            out[robot] = np.array([[p.x(), p.y(), p.theta()] for p in poses])
        return out

    def initial(self) -> gtsam.Values:
        """Dead reckoning, no calibration, each landmark where it was first sighted."""
        values = gtsam.Values()
        for robot, poses in self.dead_reckoning().items():
            for t, p in zip(self.node_t[robot], poses, strict=True):
                values.insert(self.key[(robot, float(t))], pose2(p))
            values.insert(self.cal_key[robot], NO_CALIBRATION)
        placed: dict[str, np.ndarray] = {}
        for s in self.sightings:
            if s.landmark not in placed:
                pose = values.atPose2(self.key[(s.robot, s.t)])
                seen = gtsam.Point2(s.range * math.cos(s.bearing), s.range * math.sin(s.bearing))
                placed[s.landmark] = pose.transformFrom(seen)
        for name, key in self.landmark_key.items():
            values.insert(key, placed.get(name, np.zeros(2)))
        return values

    def graph(
        self, noise: NoiseModel, kernel: gtsam.noiseModel.mEstimator.Base | None
    ) -> gtsam.NonlinearFactorGraph:
        """Start priors, calibration priors, odometry and one factor per sighting."""
        graph = gtsam.NonlinearFactorGraph()
        for robot in self.robots:
            start = self.starts.get(robot)
            if start is not None:
                first = self.key[(robot, float(self.node_t[robot][0]))]
                sigmas = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(start.sigma, float))
                graph.add(gtsam.PriorFactorPose2(first, pose2(start.pose), sigmas))
            calibration = gtsam.noiseModel.Diagonal.Sigmas(CALIBRATION_SIGMA)
            graph.add(gtsam.PriorFactorVector(self.cal_key[robot], NO_CALIBRATION, calibration))
        self._odometry(graph)
        for s in self.sightings:
            base = gtsam.noiseModel.Diagonal.Sigmas(
                np.array([noise.sigma_bearing, noise.range_sigma(s.range)])
            )
            model = gtsam.noiseModel.Robust.Create(kernel, base) if kernel is not None else base
            graph.add(detection_factor(model, self._keys(s), s))
        return graph

    def _odometry(self, graph: gtsam.NonlinearFactorGraph) -> None:
        """A between factor for each pair of consecutive nodes of a robot (ODOMETRY)."""
        q = ODOMETRY
        for robot in self.robots:
            times = self.node_t[robot]
            poses = interpolated(self.tracks[robot], times)
            for i in range(len(times) - 1):
                a, b = poses[i], poses[i + 1]
                dt, dist, turn = (
                    times[i + 1] - times[i],
                    np.hypot(*(b[:2] - a[:2])),
                    abs(b[2] - a[2]),
                )
                var_xy = q["xy_per_sqrt_s"] ** 2 * dt + (q["xy_share"] * dist) ** 2 + 1e-8
                var_th = q["th_per_sqrt_s"] ** 2 * dt + (q["th_share"] * turn) ** 2 + 1e-10
                sigmas = gtsam.noiseModel.Diagonal.Sigmas(np.sqrt([var_xy, var_xy, var_th]))
                keys = self.key[(robot, float(times[i]))], self.key[(robot, float(times[i + 1]))]
                graph.add(gtsam.BetweenFactorPose2(*keys, pose2(a).between(pose2(b)), sigmas))

    def residuals(self, values: gtsam.Values, sightings: list[Sighting]) -> np.ndarray:
        """(n, 2) measured minus predicted (bearing wrapped, range) of the sightings."""
        out = np.empty((len(sightings), 2))
        for i, s in enumerate(sightings):
            kx, kl, kc = self._keys(s)
            cal = values.atVector(kc)
            predicted, _ = predict(values.atPose2(kx), values.atPoint2(kl), cal, s.v, s.w, False)
            out[i] = (s.bearing - predicted[0], s.range - predicted[1])
        out[:, 0] = (out[:, 0] + np.pi) % (2 * np.pi) - np.pi
        return out

    def estimate_noise(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, noise: NoiseModel
    ) -> NoiseModel:
        """The detection sigmas from the solve's own residuals (nothing from the truth), as
        variance components: sum e^2 / sum (1 - h), h the share of a residual its own pose
        node absorbs (the pose marginal through the factor's Jacobian); without that the
        poses between odometry nodes soak up the residuals and the estimate collapses pass by
        pass. Residuals beyond 3 sigma (the kernel's outliers) are left out; the range sigma
        is fitted as a line in the range over six bins. A sample of the sightings suffices."""
        marginals = gtsam.Marginals(graph, values)
        order = np.random.default_rng(0).permutation(len(self.sightings))[:NOISE_SAMPLE]
        sample = [self.sightings[i] for i in order]
        e = self.residuals(values, sample)
        rng = np.array([s.range for s in sample])
        range_sigma = noise.range_sigma(rng)
        leverage = np.empty((len(sample), 2))
        for i, s in enumerate(sample):
            kx, kl, kc = self._keys(s)
            _, h = predict(
                values.atPose2(kx), values.atPoint2(kl), values.atVector(kc), s.v, s.w, True
            )
            assert h is not None
            hp = h[0]
            absorbed = hp @ marginals.marginalCovariance(kx) @ hp.T
            leverage[i] = np.diag(absorbed) / (noise.sigma_bearing**2, range_sigma[i] ** 2)
        redundancy = 1.0 - np.minimum(leverage, 0.95)
        ok = np.abs(e[:, 0]) < 3 * noise.sigma_bearing
        sigma_bearing = math.sqrt(np.sum(e[ok, 0] ** 2) / np.sum(redundancy[ok, 0]))
        edges = np.percentile(rng, np.linspace(0, 100, 7))
        middles, spreads = [], []
        for lo, hi in itertools.pairwise(edges):
            inside = (rng >= lo) & (rng <= hi) & (np.abs(e[:, 1]) < 3 * range_sigma)
            if inside.sum() > 20:
                middles.append(np.median(rng[inside]))
                spreads.append(math.sqrt(np.sum(e[inside, 1] ** 2) / np.sum(redundancy[inside, 1])))
        if len(middles) < 2:
            return NoiseModel(sigma_bearing, noise.r0, noise.r1)
        r1, r0 = np.polyfit(middles, spreads, 1)
        return NoiseModel(sigma_bearing, max(float(r0), 0.01), max(float(r1), 0.0))

    def solve(self, passes: int = 3, log: Callable[[str], None] = print) -> Reference:
        """Huber from dead reckoning under the logged sigmas, then passes of: the sigmas
        from the residuals, a solve under the kernel (Huber on the first pass, Cauchy after)."""
        noise = self.logged_noise
        huber = gtsam.noiseModel.mEstimator.Huber.Create(HUBER)
        graph = self.graph(noise, huber)
        values = gauss_newton(graph, self.initial())
        for i in range(passes):
            noise = self.estimate_noise(graph, values, noise)
            kernel = huber if i == 0 else gtsam.noiseModel.mEstimator.Cauchy.Create(CAUCHY)
            graph = self.graph(noise, kernel)
            values = gauss_newton(graph, values)
            log(f"  pass {i + 1}: {noise}")
        return self._reference(graph, values, noise)

    def _reference(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, noise: NoiseModel
    ) -> Reference:
        landmarks = {n: np.asarray(values.atPoint2(k)) for n, k in self.landmark_key.items()}
        trajectories, dead = {}, {}
        for robot, poses in self.dead_reckoning().items():
            times = self.node_t[robot]
            solved = [values.atPose2(self.key[(robot, float(t))]) for t in times]
            xyt = np.array([[p.x(), p.y(), p.theta()] for p in solved])
            trajectories[robot] = Trajectory(robot, times, xyt)
            dead[robot] = Trajectory(robot, times, poses)
        marginals = gtsam.Marginals(graph, values)
        notes = [f"detection noise: {noise}", "calibration (a m, s, k, b0 rad, dt s) +- 1 sigma:"]
        for robot, key in self.cal_key.items():
            value, sd = values.atVector(key), np.sqrt(np.diag(marginals.marginalCovariance(key)))
            pairs = "  ".join(f"{x:+.4f}+-{e:.4f}" for x, e in zip(value, sd, strict=True))
            notes.append(f"  {robot}: {pairs}")
        return Reference(landmarks, trajectories, dead, notes=notes)


def gauss_newton(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
    """Gauss-Newton with step halving, driven from Python: gtsam's optimizers call Python
    factors through a much slower path."""
    ordering = gtsam.Ordering.ColamdNonlinearFactorGraph(graph)
    error = graph.error(values)
    for _ in range(SOLVER_ITERATIONS):
        delta = graph.linearize(values).optimize(ordering)
        step = 1.0
        for _ in range(8):
            trial = values.retract(delta.scale(step))
            trial_error = graph.error(trial)
            if trial_error <= error:
                break
            step *= 0.5
        else:
            break  # no step lowers the error
        change = (error - trial_error) / max(error, 1e-12)
        values, error = trial, trial_error
        if change < SOLVER_TOLERANCE:
            break
    return values


# ---------------------------------------------------------------------- xy detections


def solve_points(survey: Survey) -> Reference:
    """A node per odometry record (its increment and covariance), each detection a
    bearing-range factor of its xy and covariance, fed to iSAM2 in the log's order and
    polished by one batch Levenberg-Marquardt: a batch solve from dead reckoning stops in a
    local minimum on a long drifting log. Every frame needs an odometry record at its time,
    as Victoria Park has."""
    solver, every = PointSolver(survey.starts), gtsam.NonlinearFactorGraph()
    for record in survey.records:
        if isinstance(record, Odometry):
            every.push_back(solver.odometry(record))
        elif isinstance(record, Detections):
            every.push_back(solver.frame(record))
    values = gtsam.LevenbergMarquardtOptimizer(every, solver.isam.calculateEstimate()).optimize()
    trajectories, dead = {}, {}
    for robot, (times, keys, poses) in solver.tracks.items():
        solved = np.array([_xyt(values.atPose2(k)) for k in keys])
        trajectories[robot] = Trajectory(robot, np.array(times), solved)
        dead[robot] = Trajectory(robot, np.array(times), np.array(poses))
    landmarks = {n: np.asarray(values.atPoint2(k)) for n, k in solver.landmark_key.items()}
    return Reference(landmarks, trajectories, dead, notes=["the log's own noise, no kernel"])


class PointSolver:
    """iSAM2 over a log of odometry increments and robot-frame xy detections, record by
    record (`solve_points`); each robot's node times, keys and dead reckoning kept."""

    def __init__(self, starts: dict[str, RobotStart]) -> None:
        self.starts, self.isam = starts, gtsam.ISAM2()
        self.graph, self.values = gtsam.NonlinearFactorGraph(), gtsam.Values()  # not solved yet
        self.keys: dict[tuple[str, float], int] = {}
        self.landmark_key: dict[str, int] = {}
        self.tracks: dict[str, tuple[list[float], list[int], list[tuple]]] = {}
        self._odometry: dict[str, np.ndarray] = {}  # each robot's last odometry-frame pose

    def odometry(self, record: Odometry) -> gtsam.NonlinearFactorGraph:
        """A node for the record: the robot's start prior, or its increment's factor."""
        robot, graph = record.robot, gtsam.NonlinearFactorGraph()
        before = self._odometry.get(robot)
        if record.pose is not None:
            now = np.asarray(record.pose, float)
        else:
            now = compose(before if before is not None else np.zeros(3), record.delta)
        key = self.keys[(robot, round(record.t, 6))] = X(len(self.keys))
        times, keys, dead = self.tracks.setdefault(robot, ([], [], []))
        if before is None:
            start = self.starts.get(robot)
            guess = pose2(start.pose) if start is not None else gtsam.Pose2()
            sigma = start.sigma if start is not None else np.full(3, 1e-3)
            prior = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigma, float))
            graph.add(gtsam.PriorFactorPose2(key, guess, prior))
            reckoned = guess
        else:
            if record.cov is None:
                raise ValueError("the point reference needs each odometry increment's cov")
            motion = pose2(before).between(pose2(now))
            noise = gtsam.noiseModel.Gaussian.Covariance(np.asarray(record.cov, float))
            graph.add(gtsam.BetweenFactorPose2(keys[-1], key, motion, noise))
            guess = self._pose(keys[-1]).compose(motion)
            reckoned = pose2(dead[-1]).compose(motion)
        self.values.insert(key, guess)
        self.graph.push_back(graph)
        self._odometry[robot] = now
        times.append(record.t)
        keys.append(key)
        dead.append(_xyt(reckoned))
        return graph

    def frame(self, frame: Detections) -> gtsam.NonlinearFactorGraph:
        """The frame's factors on its robot's node at its time; then one iSAM2 update."""
        key = self.keys.get((frame.robot, round(frame.t, 6)))
        if key is None:
            raise ValueError(f"no odometry record at the frame of {frame.robot!r} at t={frame.t}")
        graph = gtsam.NonlinearFactorGraph()
        for d in frame.objects:
            if d.truth_id is None or d.xy is None:
                continue
            if d.truth_id not in self.landmark_key:
                landmark = self.landmark_key[d.truth_id] = L(len(self.landmark_key))
                self.values.insert(landmark, self._pose(key).transformFrom(d.xy))
            graph.add(_bearing_range_factor(key, self.landmark_key[d.truth_id], d.xy, d.cov))
        self.graph.push_back(graph)
        self.isam.update(self.graph, self.values)
        self.graph, self.values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        return graph

    def _pose(self, key: int) -> gtsam.Pose2:
        """A node's pose: its guess if not solved yet, else iSAM2's estimate."""
        if self.values.exists(key):
            return self.values.atPose2(key)
        return self.isam.calculateEstimatePose2(key)


def _bearing_range_factor(
    pose: int, landmark: int, xy: np.ndarray, cov: np.ndarray | None
) -> gtsam.BearingRangeFactor2D:
    """A robot-frame point with its covariance (identity if none) as bearing and range:
    the covariance J cov J^T, J of (bearing, range) by the point."""
    x, y = float(xy[0]), float(xy[1])
    r = math.hypot(x, y)
    j = np.array([[-y / r**2, x / r**2], [x / r, y / r]])
    sigma = j @ np.asarray(cov if cov is not None else np.eye(2), float) @ j.T
    noise = gtsam.noiseModel.Gaussian.Covariance(sigma)
    return gtsam.BearingRangeFactor2D(pose, landmark, gtsam.Rot2(math.atan2(y, x)), r, noise)


def _xyt(pose: gtsam.Pose2) -> tuple[float, float, float]:
    return pose.x(), pose.y(), pose.theta()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("--t-max", type=float, default=None, help="s: the log's first part only")
    parser.add_argument("--passes", type=int, default=3, help="noise estimates and solves")
    args = parser.parse_args()
    survey = read_survey(args.log, args.t_max)
    reference = solve_reference(survey, args.passes, console.print)
    out = table(f"{survey.name}, {survey.span}: the reference by true association")
    out.add_row(*row_cells(survey.name, "reference", reference.row(survey)))
    console.print(out)
    for note in reference.notes:
        console.print(note)


if __name__ == "__main__":
    main()
