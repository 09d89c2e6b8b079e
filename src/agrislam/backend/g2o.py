"""g2o files: how pose graphs are exchanged and inspected (the paper's back end, sec. 2.6).

Written (one line each, information matrices as their upper triangle, row by row):

    VERTEX_SE2 id x y theta            robot poses, each robot's poses consecutive
    VERTEX_XY id x y                   objects, then row nodes
    EDGE_PRIOR_SE2 id x y theta I(6)   start-pose prior
    EDGE_SE2 a b dx dy dtheta I(6)     odometry, delta in pose a's frame
    EDGE_SE2_XY pose obj x y I(3)      detection: the object in the pose's frame
    EDGE_POINTXY row obj 0 0 I(3)      row constraint (sec. 2.6.2): rank-one information
                                       n n^T / sigma^2, across the row only
    EDGE_POINTXY row_a row_b dx dy I(3)  row spacing: n . (p_b - p_a) = distance
    EDGE_PRIOR_XY row x y I(3)         where along its line a row node sits (gauge)
    FIX id                             a fixed vertex (read as a very tight prior)

EDGE_POINTXY, EDGE_PRIOR_XY and EDGE_PRIOR_SE2 are g2o's own slam2d types. What g2o has
no type for is in comment lines at the end of the file, which g2o skips:
`# agrislam robot NAME FIRST COUNT`, `# agrislam times NAME t0 t1 ...`,
`# agrislam object VERTEX ID`, `# agrislam row VERTEX ID ANGLE`, and a GNSS fix
`# agrislam gnss POSE ZX ZY LX LY K KERNEL I(3)` (antenna in the map, lever
arm, kernel). GTSAM's readG2o reads
the poses, objects and odometry of such a file (it skips the edge types it has no
parser for). A detection is solved as bearing and range (its 2x2 covariance carried
over to first order); its robust kernel is solver configuration, not part of the file.
g2o's EDGE_SE2 error is (z^-1 a^-1 b) as (x, y, theta), GTSAM's the SE(2) logarithm of
it: the same to first order, so a solved graph stays solved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agrislam.backend.base import BackendBase
from agrislam.backend.graph import (
    DETECTION,
    GNSS,
    ODOMETRY,
    PRIOR_POINT,
    PRIOR_POSE,
    ROW_ANCHOR,
    ROW_MEMBER,
    ROW_SPACING,
    Factor,
    RowNode,
    SurveyGraph,
    key_index,
    key_kind,
    object_key,
    row_key,
)
from agrislam.geometry.noise import (
    range_bearing_to_relative,
    relative_to_range_bearing,
    row_direction,
    row_normal,
)
from agrislam.geometry.se2 import wrap_row_angle

# FIX as a prior: this tight (m, m, rad), far below any measurement's noise
FIX_SIGMA = 1e-6
# the robot name of poses in a file without agrislam comments
DEFAULT_ROBOT = "robot"


def _num(x: float) -> str:
    return repr(float(x))


def _upper(info: np.ndarray) -> str:
    n = info.shape[0]
    return " ".join(_num(info[i, j]) for i in range(n) for j in range(i, n))


def _from_upper(values: list[float], n: int, where: str) -> np.ndarray:
    if len(values) != n * (n + 1) // 2:
        raise ValueError(f"{where}: expected {n * (n + 1) // 2} information values")
    info = np.zeros((n, n))
    info[np.triu_indices(n)] = values
    return info + np.triu(info, 1).T


def _rank_one(direction: np.ndarray, sigma: float) -> np.ndarray:
    return np.outer(direction, direction) / sigma**2


# ----------------------------------------------------------------------------- write
def write_g2o(backend: BackendBase, path: str | Path, fix_first: bool = False) -> None:
    """The back end's graph at its current estimate as a g2o file; `fix_first` also writes
    `FIX` for the first pose (for tools that read no priors). The agrislam comments come
    last: GTSAM's readG2o stops at the first comment line."""
    graph = backend.graph
    vertex: dict[int, int] = {}
    lines: list[str] = []
    notes = ["# agrislam graph (sec. 2.6): robot poses, objects, rows; agrislam.backend.g2o"]
    for name, chain in graph.robots.items():
        notes.append(f"# agrislam robot {name} {len(vertex)} {len(chain.keys)}")
        notes.append(f"# agrislam times {name} " + " ".join(_num(t) for t in chain.times))
        for key in chain.keys:
            vertex[key] = len(vertex)
            x, y, theta = backend.estimate(key)
            lines.append(f"VERTEX_SE2 {vertex[key]} {_num(x)} {_num(y)} {_num(theta)}")
    for object_id in graph.objects:
        key = object_key(object_id)
        vertex[key] = len(vertex)
        x, y = backend.estimate(key)
        notes.append(f"# agrislam object {vertex[key]} {object_id}")
        lines.append(f"VERTEX_XY {vertex[key]} {_num(x)} {_num(y)}")
    for row, node in graph.rows.items():
        key = row_key(row)
        vertex[key] = len(vertex)
        x, y = backend.estimate(key)
        notes.append(f"# agrislam row {vertex[key]} {row} {_num(node.angle)}")
        lines.append(f"VERTEX_XY {vertex[key]} {_num(x)} {_num(y)}")
    for factor in graph.factors.values():
        if factor.kind == GNSS:  # g2o has no such edge: a comment agrislam reads back
            ids, info = vertex[factor.keys[0]], _upper(np.linalg.inv(factor.cov))
            notes.append(f"# agrislam gnss {ids} {' '.join(map(_num, factor.value))} {info}")
        else:
            lines.append(_edge_line(factor, vertex))
    if fix_first and graph.robots:  # after the edges: GTSAM's reader stops at FIX too
        lines.append(f"FIX {vertex[next(iter(graph.robots.values())).keys[0]]}")
    Path(path).write_text("\n".join(lines + notes) + "\n", encoding="utf-8")


def _edge_line(factor: Factor, vertex: dict[int, int]) -> str:
    ids = " ".join(str(vertex[k]) for k in factor.keys)
    value, cov = factor.value, factor.cov
    if factor.kind == PRIOR_POSE:
        return f"EDGE_PRIOR_SE2 {ids} {' '.join(map(_num, value))} {_upper(np.linalg.inv(cov))}"
    if factor.kind == ODOMETRY:
        return f"EDGE_SE2 {ids} {' '.join(map(_num, value))} {_upper(np.linalg.inv(cov))}"
    if factor.kind == DETECTION:
        xy, cov_xy = range_bearing_to_relative(value[0], value[1], cov)
        return f"EDGE_SE2_XY {ids} {_num(xy[0])} {_num(xy[1])} {_upper(np.linalg.inv(cov_xy))}"
    if factor.kind == ROW_MEMBER:
        info = _rank_one(row_normal(value[0]), cov)
        return f"EDGE_POINTXY {ids} 0.0 0.0 {_upper(info)}"
    if factor.kind == ROW_SPACING:
        normal = row_normal(value[0])
        d = value[1] * normal
        return f"EDGE_POINTXY {ids} {_num(d[0])} {_num(d[1])} {_upper(_rank_one(normal, cov))}"
    if factor.kind == ROW_ANCHOR:
        info = _rank_one(row_direction(value[2]), cov)
        return f"EDGE_PRIOR_XY {ids} {_num(value[0])} {_num(value[1])} {_upper(info)}"
    if factor.kind == PRIOR_POINT:  # a saved map's plant
        info = np.linalg.inv(cov)
        return f"EDGE_PRIOR_XY {ids} {_num(value[0])} {_num(value[1])} {_upper(info)}"
    raise ValueError(f"cannot write factor kind {factor.kind!r}")


# ------------------------------------------------------------------------------ read
@dataclass
class G2oGraph:
    graph: SurveyGraph
    values: dict[int, np.ndarray]  # node key -> estimate in the file


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.graph = SurveyGraph()
        self.values: dict[int, np.ndarray] = {}
        self.key: dict[int, int] = {}  # vertex id -> node key
        self.robots: list[tuple[str, int, int]] = []
        self.times: dict[str, list[float]] = {}
        self.object_of: dict[int, int] = {}
        self.row_of: dict[int, tuple[int, float]] = {}
        self.se2: dict[int, np.ndarray] = {}
        self.xy: dict[int, np.ndarray] = {}
        self.edges: list[tuple[str, list[str], str]] = []
        self.fixed: list[tuple[int, str]] = []
        self.gnss: list[list[str]] = []

    def where(self, n: int) -> str:
        return f"{self.path}:{n}"

    def read(self) -> G2oGraph:
        for n, raw in enumerate(self.path.read_text(encoding="utf-8").splitlines(), 1):
            line = raw.strip()
            if not line:
                continue
            try:
                self._line(line, self.where(n))
            except (ValueError, IndexError) as err:
                raise ValueError(f"{self.where(n)}: {err} in {line!r}") from None
        self._nodes()
        for tag, fields, where in self.edges:
            self._edge(tag, fields, where)
        for fields in self.gnss:
            key, numbers = self._key(int(fields[0]), "gnss"), [float(v) for v in fields[1:]]
            cov = _inverse(_from_upper(numbers[6:], 2, "gnss"), "gnss")
            self.graph.add_factor(Factor(GNSS, (key,), np.array(numbers[:6]), cov))
        for vid, where in self.fixed:
            key = self._key(vid, where)
            if key_kind(key) != "x":
                raise ValueError(f"{where}: FIX of a VERTEX_XY is not supported")
            cov = np.eye(3) * FIX_SIGMA**2
            self.graph.add_factor(Factor(PRIOR_POSE, (key,), self.values[key], cov))
        return G2oGraph(self.graph, self.values)

    def _line(self, line: str, where: str) -> None:
        tag, *fields = line.split()
        if tag == "#":
            if fields[:1] == ["agrislam"]:
                self._comment(fields[1:])
            return
        if tag.startswith("#"):
            return
        if tag == "VERTEX_SE2":
            self.se2[int(fields[0])] = np.array([float(v) for v in fields[1:4]])
        elif tag == "VERTEX_XY":
            self.xy[int(fields[0])] = np.array([float(v) for v in fields[1:3]])
        elif tag == "FIX":
            self.fixed.extend((int(v), where) for v in fields)
        elif tag in ("EDGE_SE2", "EDGE_PRIOR_SE2", "EDGE_SE2_XY", "EDGE_POINTXY", "EDGE_PRIOR_XY"):
            self.edges.append((tag, fields, where))
        else:
            raise ValueError(f"unknown g2o tag {tag!r}")

    def _comment(self, fields: list[str]) -> None:
        kind = fields[0] if fields else ""
        if kind == "robot":
            self.robots.append((fields[1], int(fields[2]), int(fields[3])))
        elif kind == "times":
            self.times[fields[1]] = [float(v) for v in fields[2:]]
        elif kind == "object":
            self.object_of[int(fields[1])] = int(fields[2])
        elif kind == "row":
            self.row_of[int(fields[1])] = (int(fields[2]), float(fields[3]))
        elif kind == "gnss":
            self.gnss.append(fields[1:])

    def _nodes(self) -> None:
        # a plain g2o file: every pose in one chain, by vertex id
        robots = self.robots or [(DEFAULT_ROBOT, min(self.se2, default=0), len(self.se2))]
        for name, first, count in robots:
            chain = self.graph.add_robot(name, math.nan)
            chain.clear()
            ids = list(range(first, first + count)) if self.robots else sorted(self.se2)
            times = self.times.get(name, [math.nan] * len(ids))
            if len(times) != len(ids):
                raise ValueError(f"{self.path}: robot {name}: {len(times)} times, {len(ids)} poses")
            for vid, t in zip(ids, times, strict=True):
                if vid not in self.se2:
                    raise ValueError(f"{self.path}: robot {name}: no VERTEX_SE2 {vid}")
                key = chain.add(t)
                self.key[vid] = key
                self.values[key] = self.se2[vid]
        for vid, xy in self.xy.items():
            if vid in self.row_of:
                row, angle = self.row_of[vid]
                self.graph.rows[row] = RowNode(xy.copy(), angle)
                key = row_key(row)
            else:
                key = self.graph.add_object(self.object_of.get(vid, vid), xy)
            self.key[vid] = key
            self.values[key] = xy

    def _key(self, vid: int, where: str) -> int:
        if vid not in self.key:
            raise ValueError(f"{where}: vertex {vid} is not defined")
        return self.key[vid]

    def _edge(self, tag: str, fields: list[str], where: str) -> None:
        unary = tag in ("EDGE_PRIOR_SE2", "EDGE_PRIOR_XY")
        n_keys = 1 if unary else 2
        keys = tuple(self._key(int(v), where) for v in fields[:n_keys])
        numbers = [float(v) for v in fields[n_keys:]]
        if tag in ("EDGE_SE2", "EDGE_PRIOR_SE2"):
            info = _from_upper(numbers[3:], 3, where)
            kind = ODOMETRY if tag == "EDGE_SE2" else PRIOR_POSE
            self.graph.add_factor(Factor(kind, keys, np.array(numbers[:3]), _inverse(info, where)))
            return
        measured, info = np.array(numbers[:2]), _from_upper(numbers[2:], 2, where)
        if tag == "EDGE_SE2_XY":
            bearing, rng, cov = relative_to_range_bearing(measured, _inverse(info, where))
            self.graph.add_factor(Factor(DETECTION, keys, np.array([bearing, rng]), cov))
            return
        direction, sigma = _rank_one_parts(info, where)
        if tag == "EDGE_PRIOR_XY":
            angle = wrap_row_angle(math.atan2(direction[1], direction[0]))
            self.graph.add_factor(Factor(ROW_ANCHOR, keys, np.r_[measured, angle], sigma))
            return
        angle = wrap_row_angle(math.atan2(-direction[0], direction[1]))  # n = (-sin a, cos a)
        if key_kind(keys[1]) == "r":
            distance = float(measured @ row_normal(angle))
            self.graph.add_factor(Factor(ROW_SPACING, keys, np.array([angle, distance]), sigma))
        else:
            self.graph.add_factor(Factor(ROW_MEMBER, keys, np.array([angle]), sigma))


def _inverse(info: np.ndarray, where: str) -> np.ndarray:
    if np.linalg.eigvalsh(info)[0] <= 0:
        raise ValueError(f"{where}: information matrix is not positive definite")
    return np.linalg.inv(info)


def _rank_one_parts(info: np.ndarray, where: str) -> tuple[np.ndarray, float]:
    """Direction d and sigma of a rank-one information d d^T / sigma^2 (a row edge)."""
    values, vectors = np.linalg.eigh(info)
    if values[1] <= 0 or abs(values[0]) > 1e-9 * values[1]:
        raise ValueError(f"{where}: only row edges (rank-one information) are supported here")
    return vectors[:, 1], 1.0 / math.sqrt(values[1])


def read_g2o(path: str | Path) -> G2oGraph:
    """A g2o file as a graph record and the estimates it holds."""
    return _Reader(Path(path)).read()


__all__ = ["G2oGraph", "key_index", "read_g2o", "write_g2o"]
