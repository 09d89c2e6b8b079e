"""g2o files: export, import, round trip, GTSAM's own reader on our files, a solved graph
staying solved, FIX, and errors that name the line."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from agrislam.backend import (
    RangeBearing,
    RelativePosition,
    detection_covariance,
    make_backend,
)
from agrislam.backend.g2o import read_g2o, write_g2o
from agrislam.backend.graph import DETECTION, ODOMETRY, ROW_MEMBER, ROW_SPACING
from agrislam.config import RowsConfig, SlamConfig

PLANTS = np.array([[1.0, 0.02], [1.5, 1.01], [2.0, -0.01], [2.5, 0.98], [0.8, 2.03]])


def solved_graph(kind: str = "batch"):
    """Two robots, plants on two rows (with row nodes, constraints and spacing), solved."""
    g = make_backend(SlamConfig(backend=kind), RowsConfig())
    g.add_robot("a", np.zeros(3), np.array([1e-3, 1e-3, 1e-4]), t=0.0)
    g.add_robot("b", np.array([0.0, 1.0, 0.0]), np.array([1e-2, 1e-2, 1e-3]), t=0.5)
    for i, p in enumerate(PLANTS):
        g.add_object(i, p + 0.03)
    for step in range(3):
        for robot, start in (("a", np.zeros(2)), ("b", np.array([0.0, 1.0]))):
            if step:
                g.add_odometry(robot, float(step), np.array([0.2, 0.0, 0.01]), np.eye(3) * 1e-4)
            pose = g.current_pose(robot)
            for i, p in enumerate(PLANTS):
                c, s = np.cos(pose[2]), np.sin(pose[2])
                xy = np.array([[c, s], [-s, c]]) @ (p - start - np.array([0.2 * step, 0.0]))
                if robot == "b" and i == 4:
                    g.add_observation(
                        robot, i, RangeBearing(np.hypot(*xy), np.arctan2(xy[1], xy[0]), 0.05, 0.01)
                    )
                else:
                    g.add_observation(
                        robot, i, RelativePosition(xy, detection_covariance(xy, 0.08, 0.02))
                    )
            g.update()
    g.add_row(0, np.array([0.0, 0.0]), 0.0)
    g.add_row(1, np.array([0.0, 1.0]), 0.0)
    for i, row in ((0, 0), (2, 0), (1, 1), (3, 1)):
        g.add_row_constraint(i, row)
    g.add_row_spacing(0, 1, 1.0)
    g.update()
    g.update()
    return g


def test_round_trip_keeps_every_node_and_factor(tmp_path):
    g = solved_graph()
    path = tmp_path / "survey.g2o"
    write_g2o(g, path)
    back = read_g2o(path)
    assert list(back.graph.robots) == ["a", "b"]
    assert back.graph.robots["b"].times.tolist() == [0.5, 1.0, 2.0]
    assert sorted(back.graph.objects) == list(range(5))
    assert sorted(back.graph.rows) == [0, 1]
    assert back.graph.row_of == g.graph.row_of
    original = list(g.graph.factors.values())
    read = list(back.graph.factors.values())
    assert [f.kind for f in read] == [f.kind for f in original]
    for a, b in zip(original, read, strict=True):
        assert a.keys == b.keys  # same node keys: robots, objects and rows numbered alike
        np.testing.assert_allclose(np.atleast_1d(b.value), np.atleast_1d(a.value), atol=1e-12)
        np.testing.assert_allclose(b.cov, a.cov, rtol=1e-9, atol=1e-15)
    for key, value in back.values.items():
        np.testing.assert_allclose(value, g.estimate(key), atol=1e-15)


def test_reoptimising_an_exported_solved_graph_does_not_move_it(tmp_path):
    g = solved_graph()
    path = tmp_path / "solved.g2o"
    write_g2o(g, path)
    back = read_g2o(path)
    for slam in (SlamConfig(backend="batch"), SlamConfig(window=0), SlamConfig(window=1)):
        fresh = make_backend(slam, RowsConfig())
        fresh.load(read_g2o(path).graph, back.values)
        fresh.update()  # with window 1 this folds everything onto the keyframes
        for key, value in back.values.items():
            np.testing.assert_allclose(fresh.estimate(key), value, atol=1e-6)


def test_gtsam_reads_our_poses_and_odometry(tmp_path):
    g = solved_graph()
    path = tmp_path / "gtsam.g2o"
    write_g2o(g, path)
    graph, values = gtsam.readG2o(str(path))
    poses = [k for c in g.graph.robots.values() for k in c.keys]
    assert values.size() == len(poses) + 5 + 2
    for vertex, key in enumerate(poses):
        np.testing.assert_allclose(
            [
                values.atPose2(vertex).x(),
                values.atPose2(vertex).y(),
                values.atPose2(vertex).theta(),
            ],
            g.estimate(key),
            atol=1e-12,
        )
    odometry = [f for f in g.graph.factors.values() if f.kind == ODOMETRY]
    assert graph.size() == len(odometry)
    for n, f in enumerate(odometry):
        between = graph.at(n)
        assert list(between.keys()) == [poses.index(k) for k in f.keys]
        measured = between.measured()
        np.testing.assert_allclose([measured.x(), measured.y(), measured.theta()], f.value)
        np.testing.assert_allclose(between.noiseModel().covariance(), f.cov, rtol=1e-9)


def test_a_plain_g2o_file_with_fix_and_a_loop(tmp_path):
    """A square driven once round, the last edge closing the loop with an error of 0.2 m;
    FIX 0 holds the first pose. GTSAM's own reader and LM give the reference."""
    path = tmp_path / "square.g2o"
    info = "100.0 0.0 0.0 100.0 0.0 1000.0"
    path.write_text(
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 1.5707963\nVERTEX_SE2 2 1 1 3.1415926\n"
        "VERTEX_SE2 3 0 1 -1.5707963\nVERTEX_XY 7 0.5 0.5\n"
        f"EDGE_SE2 0 1 1 0 1.5707963 {info}\nEDGE_SE2 1 2 1 0 1.5707963 {info}\n"
        f"EDGE_SE2 2 3 1 0 1.5707963 {info}\nEDGE_SE2 3 0 1.2 0 1.5707963 {info}\n"
        "EDGE_SE2_XY 0 7 0.5 0.5 100.0 0.0 100.0\nFIX 0\n",
        encoding="utf-8",
    )
    back = read_g2o(path)
    assert list(back.graph.robots) == ["robot"]
    assert back.graph.objects.keys() == {7}
    kinds = [f.kind for f in back.graph.factors.values()]
    assert kinds.count(ODOMETRY) == 4 and kinds.count(DETECTION) == 1
    g = make_backend(SlamConfig(backend="batch", robust_kernel="none"), RowsConfig())
    g.load(back.graph, back.values)
    g.update()
    ref_graph, read_values = gtsam.readG2o(str(path))  # poses and odometry only
    fix = gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)
    ref_graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), fix))
    ref_values = gtsam.Values()
    for vertex in range(4):
        ref_values.insert(vertex, read_values.atPose2(vertex))
    ref = gtsam.LevenbergMarquardtOptimizer(ref_graph, ref_values).optimize()
    assert ref.atPose2(1).y() > 0.02  # the loop's error is spread round the square
    _, poses = g.trajectory("robot")
    for vertex in range(4):
        p = ref.atPose2(vertex)
        np.testing.assert_allclose(poses[vertex], [p.x(), p.y(), p.theta()], atol=1e-4)
    np.testing.assert_allclose(poses[0], np.zeros(3), atol=1e-5)


def test_row_edges_come_back_as_row_constraints(tmp_path):
    g = solved_graph()
    write_g2o(g, tmp_path / "rows.g2o")
    text = (tmp_path / "rows.g2o").read_text()
    assert text.count("EDGE_POINTXY") == 5 and text.count("EDGE_PRIOR_XY") == 2
    kinds = [f.kind for f in read_g2o(tmp_path / "rows.g2o").graph.factors.values()]
    assert kinds.count(ROW_MEMBER) == 4 and kinds.count(ROW_SPACING) == 1


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("EDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1", "unknown g2o tag 'EDGE_SE3:QUAT'"),
        ("EDGE_SE2 0 9 1 0 0 1 0 0 1 0 1", "vertex 9 is not defined"),
        ("EDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1", "not positive definite"),
        ("EDGE_SE2 0 1 1 0 0 1 0 0", "expected 6 information values"),
        ("VERTEX_SE2 4 x 0 0", "could not convert"),
    ],
)
def test_bad_lines_are_named(tmp_path, line, message):
    path = tmp_path / "bad.g2o"
    path.write_text(f"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n{line}\n", encoding="utf-8")
    with pytest.raises(ValueError, match=f"bad.g2o:3: .*{message}"):
        read_g2o(path)
