"""Survey paths: the paper's predefined lawnmower route between the rows (sec. 2.7), split
over several robots, optionally back to the start (loop closure, App. C) and on to revisit
points. A path is a polyline whose corners are rounded by arcs, driven at constant speed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agrislam.geometry.se2 import wrap_angle
from agrislam.sim.config import SimConfig
from agrislam.sim.field import Field

_LINE, _ARC, _SPIN = 0, 1, 2


@dataclass(frozen=True, slots=True)
class SurveyPath:
    """A route as segments; `length` is in metres (a turn on the spot counts as the arc of
    radius `spin_radius` it replaces, so it takes time at the same speed)."""

    kind: np.ndarray  # (k,) _LINE, _ARC or _SPIN
    start: np.ndarray  # (k, 2) segment start point
    heading: np.ndarray  # (k,) heading at the segment start
    turn: np.ndarray  # (k,) signed heading change over the segment (0 for a line)
    seg_length: np.ndarray  # (k,) m
    radius: np.ndarray  # (k,) arc radius (lines: 0)

    @property
    def length(self) -> float:
        return float(self.seg_length.sum())

    def at_distance(self, d: np.ndarray) -> np.ndarray:
        """Poses (m, 3) after driving distance(s) d along the path (clipped to its ends)."""
        d = np.clip(np.atleast_1d(np.asarray(d, float)), 0.0, self.length)
        ends = np.cumsum(self.seg_length)
        k = np.minimum(np.searchsorted(ends, d, side="left"), len(ends) - 1)
        u = d - (ends[k] - self.seg_length[k])  # distance into the segment
        frac = np.divide(u, self.seg_length[k], out=np.zeros_like(u), where=self.seg_length[k] > 0)
        th0, p0 = self.heading[k], self.start[k]
        theta = th0 + frac * self.turn[k]
        xy = p0 + u[:, None] * np.column_stack([np.cos(th0), np.sin(th0)])  # lines
        arc = self.kind[k] == _ARC
        if arc.any():
            sgn, r = np.sign(self.turn[k][arc]), self.radius[k][arc]
            # centre to the turning side of the start; on the circle the heading is tangent
            c = p0[arc] + (sgn * r)[:, None] * np.column_stack(
                [-np.sin(th0[arc]), np.cos(th0[arc])]
            )
            t = theta[arc]
            xy[arc] = c + (sgn * r)[:, None] * np.column_stack([np.sin(t), -np.cos(t)])
        spin = self.kind[k] == _SPIN
        xy[spin] = p0[spin]
        return np.column_stack([xy, wrap_angle(theta)])

    def sample(self, times: np.ndarray, speed: float) -> np.ndarray:
        return self.at_distance(speed * np.asarray(times, float))

    def duration(self, speed: float) -> float:
        return self.length / speed


def rounded_polyline(
    waypoints: np.ndarray, radius: float, spin_above: float = np.pi - 1e-6
) -> SurveyPath:
    """Straight legs between waypoints, each corner replaced by an arc of `radius` (smaller if
    the legs are too short: a corner may use at most half of each leg); a corner turning more
    than `spin_above` rad (by default only a reversal) is a turn on the spot."""
    w = np.asarray(waypoints, float)
    keep = np.r_[True, np.linalg.norm(np.diff(w, axis=0), axis=1) > 1e-9]
    w = w[keep]
    if len(w) < 2:
        raise ValueError("a path needs at least two distinct waypoints")
    leg = np.diff(w, axis=0)
    leg_len = np.linalg.norm(leg, axis=1)
    head = np.arctan2(leg[:, 1], leg[:, 0])
    turn = wrap_angle(head[1:] - head[:-1])  # at each interior waypoint
    spin = np.abs(turn) > spin_above
    tan_half = np.where(spin, 0.0, np.tan(np.abs(turn) / 2))
    avail = 0.5 * np.minimum(leg_len[:-1], leg_len[1:])
    r = np.where(tan_half > 1e-12, np.minimum(radius, avail / np.maximum(tan_half, 1e-12)), 0.0)
    cut = r * tan_half  # leg length given to the arc at each interior waypoint
    cut_in = np.r_[cut, 0.0]  # trimmed from the end of leg i
    cut_out = np.r_[0.0, cut]  # trimmed from the start of leg i
    segs: list[tuple[int, np.ndarray, float, float, float, float]] = []
    for i in range(len(leg)):
        d = leg[i] / leg_len[i]
        segs.append(
            (_LINE, w[i] + d * cut_out[i], head[i], 0.0, leg_len[i] - cut_out[i] - cut_in[i], 0.0)
        )
        if i < len(turn) and abs(turn[i]) > 1e-12:
            start = w[i + 1] - d * cut[i]
            if spin[i]:
                segs.append((_SPIN, w[i + 1], head[i], turn[i], abs(turn[i]) * radius, radius))
            else:
                segs.append((_ARC, start, head[i], turn[i], abs(turn[i]) * r[i], r[i]))
    kind, start, heading, dturn, length, rad = zip(*segs, strict=True)
    return SurveyPath(
        kind=np.array(kind),
        start=np.array(start),
        heading=np.array(heading),
        turn=np.array(dturn),
        seg_length=np.array(length),
        radius=np.array(rad),
    )


def lane_offsets(field: Field, cfg: SimConfig) -> np.ndarray:
    """Across-row offsets of the lanes: between neighbouring rows (and outside the outer ones)."""
    sp = field.row_spacing
    first = -1 if cfg.path.lanes == "all" or field.n_rows == 1 else 0
    last = field.n_rows - 1 if cfg.path.lanes == "all" or field.n_rows == 1 else field.n_rows - 2
    return (np.arange(first, last + 1) + 0.5) * sp


def lawnmower_waypoints(field: Field, cfg: SimConfig, robot: int = 0) -> np.ndarray:
    """Map-frame waypoints of one robot's block of lanes, driven back and forth, then the way
    back to the start (if asked) and the revisit points."""
    h = cfg.path.headland
    blocks = np.array_split(lane_offsets(field, cfg), cfg.path.n_robots)
    lanes = blocks[robot]
    if len(lanes) == 0:
        raise ValueError(f"robot {robot}: no lanes left ({cfg.path.n_robots} robots, fewer lanes)")
    ends = np.array([-h, field.row_length + h])
    sl: list[tuple[float, float]] = []
    for j, across in enumerate(lanes):
        a, b = ends if j % 2 == 0 else ends[::-1]
        sl += [(a, across), (b, across)]
    if cfg.path.return_to_start:
        last_s, l0 = sl[-1][0], lanes[0]
        if last_s > 0:  # on the far headland: back along it and down the first lane
            sl += [(last_s, l0), (-h, l0)]
        else:  # on the start headland: along it, then into the first lane again
            sl += [(-h, l0), (-h + cfg.path.closure_length, l0)]
    s, across = np.array(sl).T
    xy = field.to_map(s, across)
    if cfg.path.revisit_waypoints:
        xy = np.vstack([xy, np.asarray(cfg.path.revisit_waypoints, float)])
    return xy


def survey_path(field: Field, cfg: SimConfig, robot: int = 0) -> SurveyPath:
    return rounded_polyline(lawnmower_waypoints(field, cfg, robot), cfg.path.turn_radius)


def frame_times(duration: float, rate_hz: float, t0: float = 0.0) -> np.ndarray:
    """Times t0, t0 + 1/rate, ... up to and including the end of the path."""
    n = int(np.floor(duration * rate_hz + 1e-9)) + 1
    return t0 + np.arange(n) / rate_hz


def lawnmower(field: Field, cfg: SimConfig, robot: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """One robot's true survey poses (m, 3) at the camera frame times (m,), from t = 0."""
    path = survey_path(field, cfg, robot)
    t = frame_times(path.duration(cfg.path.speed), cfg.path.frame_rate_hz)
    return path.sample(t, cfg.path.speed), t
