"""The GNSS factor (estimation/gnss.py): error and Jacobian, lever arm, weighting, gate, and
that float fixes and outliers do not move a map held by RTK fixed fixes, on both back ends."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from agrislam.backend import make_backend
from agrislam.backend.gnss_factor import antenna_jacobian, antenna_position, gnss_factor
from agrislam.config import GnssConfig, RowsConfig, SlamConfig
from agrislam.estimation.gnss import GnssFixes, kernel_width, weighted_covariance
from agrislam.geometry.geodesy import MapFrame
from agrislam.records import Anchor, GnssFix

ANCHOR = Anchor(51.4488, 5.4905, 20.0, 0.0)
ODOM_COV = np.diag([2.5e-3, 2.5e-3, 1e-4])  # 5 cm a step: wider than its 2 % bias


def test_lever_arm_by_hand() -> None:
    # robot at (10, 5) heading north; antenna 0.5 m ahead and 0.2 m left: 0.5 north, 0.2 west
    pose = np.array([10.0, 5.0, math.pi / 2])
    np.testing.assert_allclose(antenna_position(pose, np.array([0.5, 0.2])), [9.8, 5.5])


@pytest.mark.parametrize("lever", [(0.0, 0.0), (0.5, 0.2), (-1.3, 0.7)])
def test_error_and_jacobian_against_numeric_differentiation(lever: tuple) -> None:
    lever_arm = np.array(lever)
    key = gtsam.symbol("x", 0)
    z = np.array([3.0, -1.0])
    factor = gnss_factor(key, np.array([*z, *lever_arm, 1.0, 0]), np.eye(2) * 0.01)
    pose = gtsam.Pose2(2.5, -0.7, 0.9)
    values = gtsam.Values()
    values.insert(key, pose)
    p = np.array([pose.x(), pose.y(), pose.theta()])
    expected = antenna_position(p, lever_arm) - z
    np.testing.assert_allclose(factor.unwhitenedError(values), expected, atol=1e-12)
    numeric = np.zeros((2, 3))
    eps = 1e-6
    for i in range(3):
        xi = np.zeros(3)
        xi[i] = eps
        plus = gtsam.Values()
        plus.insert(key, pose.retract(xi))
        minus = gtsam.Values()
        minus.insert(key, pose.retract(-xi))
        numeric[:, i] = (factor.unwhitenedError(plus) - factor.unwhitenedError(minus)) / (2 * eps)
    np.testing.assert_allclose(antenna_jacobian(p, lever_arm), numeric, atol=1e-8)
    # and the Jacobian GTSAM linearises with (whitened by sigma 0.1)
    linear = factor.linearize(values)
    np.testing.assert_allclose(linear.jacobian()[0], numeric / 0.1, atol=1e-6)


def test_fix_type_floor_weights_the_covariance() -> None:
    cfg = GnssConfig()
    tiny = np.eye(2) * 1e-8
    assert weighted_covariance(tiny, "rtk_fixed", cfg)[0, 0] == pytest.approx(0.01**2)
    assert weighted_covariance(tiny, "single", cfg)[0, 0] == pytest.approx(1.5**2)
    wide = np.eye(2) * 4.0
    np.testing.assert_allclose(weighted_covariance(wide, "rtk_fixed", cfg), wide)


def fix_at(frame: MapFrame, xy, kind: str = "rtk_fixed", sigma: float = 0.02, t: float = 0.0):
    lon, lat, h = frame.to_wgs84(np.array([xy]))[0]
    cov = np.diag([sigma**2, sigma**2, (2 * sigma) ** 2])
    return GnssFix(t=t, robot="r1", lat=lat, lon=lon, alt=h, fix=kind, cov=cov)


def drive(backend: str, extra: list[tuple[int, tuple, str, float]]) -> np.ndarray:
    """A robot driving 20 poses east along y=0 with biased odometry, held by RTK fixed fixes
    at every pose, plus the `extra` fixes (pose index, where, type, sigma)."""
    slam = SlamConfig(backend=backend, window=5)
    be = make_backend(slam, RowsConfig())
    be.add_robot("r1", np.zeros(3), np.array([10.0, 10.0, 1.0]), 0.0)
    frame = MapFrame(ANCHOR)
    gnss = GnssFixes(GnssConfig())
    for i in range(20):
        if i:
            be.add_odometry("r1", float(i), np.array([1.02, 0.0, 0.003]), ODOM_COV)
        dr = be.current_pose("r1")
        gnss.receive(fix_at(frame, (float(i), 0.0)), ANCHOR, dr)
        for j, xy, kind, sigma in extra:
            if j == i:
                gnss.receive(fix_at(frame, xy, kind, sigma), ANCHOR, dr)
        cov = be.current_pose_covariance("r1") if i else None
        gnss.attach(be, "r1", dr, cov)
        be.update()
    be.refine()
    assert gnss.counts["used"] >= 20
    return be.trajectory("r1")[1]


@pytest.mark.parametrize("backend", ["incremental", "batch"])
def test_fixed_fixes_hold_the_map(backend: str) -> None:
    poses = drive(backend, [])
    np.testing.assert_allclose(poses[:, 0], np.arange(20.0), atol=0.02)
    np.testing.assert_allclose(poses[:, 1], 0.0, atol=0.02)


@pytest.mark.parametrize("backend", ["incremental", "batch"])
def test_float_fix_and_outlier_do_not_move_the_map(backend: str) -> None:
    held = drive(backend, [])
    disturbed = drive(
        backend, [(8, (8.4, 0.3), "rtk_float", 0.3), (12, (12.0, 6.0), "rtk_fixed", 0.02)]
    )
    assert np.abs(disturbed[:, :2] - held[:, :2]).max() < 0.01


def test_gate_rejects_an_outlier_and_counts_it() -> None:
    be = make_backend(SlamConfig(), RowsConfig())
    be.add_robot("r1", np.zeros(3), np.array([0.01, 0.01, 0.001]), 0.0)
    frame = MapFrame(ANCHOR)
    gnss = GnssFixes(GnssConfig())
    gnss.receive(fix_at(frame, (5.0, 0.0)), ANCHOR, np.zeros(3))
    gnss.receive(fix_at(frame, (0.01, 0.0)), ANCHOR, np.zeros(3))
    gnss.receive(fix_at(frame, (0.0, 0.0), kind="none"), ANCHOR, np.zeros(3))
    gnss.attach(be, "r1", np.zeros(3), be.current_pose_covariance("r1"))
    assert gnss.summary() == {
        "received": 3,
        "rejected_fix_type": 1,
        "rejected_gate": 1,
        "used": 1,
    }


def test_first_good_fix_anchors_a_survey_without_anchor() -> None:
    gnss = GnssFixes(GnssConfig())
    single = GnssFix(0.0, "r1", 51.0, 5.0, 10.0, "single")
    assert gnss.receive(single, None, np.zeros(3)) is None
    fixed = GnssFix(1.0, "r1", 51.0, 5.0, 10.0, "rtk_fixed")
    assert gnss.receive(fixed, None, np.zeros(3)) == Anchor(51.0, 5.0, 10.0, 0.0)
    np.testing.assert_allclose(gnss.pending["r1"][0].z, [0.0, 0.0], atol=1e-6)


def test_a_graph_with_gnss_fixes_round_trips_through_g2o(tmp_path) -> None:
    from agrislam.backend.g2o import read_g2o, write_g2o

    be = make_backend(SlamConfig(backend="batch"), RowsConfig())
    be.add_robot("r1", np.zeros(3), np.array([1.0, 1.0, 0.1]), 0.0)
    be.add_odometry("r1", 1.0, np.array([1.0, 0.0, 0.0]), ODOM_COV)
    value = np.array([1.2, 0.1, 0.3, 0.05, 2.0, 2.0])
    be.add_gnss("r1", value, np.array([[4e-4, 1e-4], [1e-4, 9e-4]]))
    be.update()
    write_g2o(be, tmp_path / "g.g2o")
    back = read_g2o(tmp_path / "g.g2o").graph
    (fix,) = [f for f in back.factors.values() if f.kind == "gnss"]
    np.testing.assert_allclose(fix.value, value)
    np.testing.assert_allclose(fix.cov, [[4e-4, 1e-4], [1e-4, 9e-4]], rtol=1e-9)
    assert fix.keys == (back.robots["r1"].keys[1],)


def gate_run(fixes: list[tuple[float, float]], cfg: GnssConfig | None = None) -> GnssFixes:
    """A robot driving 1 m east a step on odometry that claims to be near perfect, one RTK
    fixed fix (x, y) a step, as the world feeds them: each fix waits for the next pose."""
    be = make_backend(SlamConfig(), RowsConfig())
    be.add_robot("r1", np.zeros(3), np.array([0.01, 0.01, 0.001]), 0.0)
    frame, gnss = MapFrame(ANCHOR), GnssFixes(cfg or GnssConfig())
    tight = np.diag([1e-6, 1e-6, 1e-8])
    for i, xy in enumerate(fixes):
        if i:
            be.add_odometry("r1", float(i), np.array([1.0, 0.0, 0.0]), tight)
        dr = be.current_pose("r1")
        gnss.receive(fix_at(frame, xy, t=float(i)), ANCHOR, dr)
        gnss.attach(be, "r1", dr, be.current_pose_covariance("r1"))
        be.update()
    return gnss


def test_gate_takes_fixes_that_agree_after_a_drift_beyond_the_covariance() -> None:
    # the odometry says y = 0, its covariance a millimetre; the fixes agree on y = 0.5
    gnss = gate_run([(float(i), 0.5) for i in range(8)])
    # the first two wait for company, the third shows the drift, the rest follow the pull
    assert gnss.counts["rejected_gate"] == 2
    assert gnss.counts["used"] == 6


def test_gate_refuses_multipath_jumps_that_agree_with_nothing() -> None:
    # good fixes on the track, three jumps of metres in a row in different directions
    jumps = {3: (3.0, 5.0), 4: (4.0, -4.0), 5: (9.0, 0.0)}
    gnss = gate_run([jumps.get(i, (float(i), 0.0)) for i in range(9)])
    assert gnss.counts["rejected_gate"] == 3
    assert gnss.counts["used"] == 6


def test_without_consistency_the_gate_waits_for_reacquire() -> None:
    cfg = GnssConfig(gate_consistent=0, gate_reacquire=4)
    gnss = gate_run([(float(i), 0.5) for i in range(8)], cfg)
    assert gnss.counts["rejected_gate"] == 4


def test_fixes_that_agree_on_a_place_farther_than_any_drift_are_refused() -> None:
    """Fixes 30 m north of a robot its start holds, agreeing with each other, after 5 m of
    driving: farther than it can have drifted (5 m + 10 % of 5 m)."""
    gnss = gate_run([(float(i), 30.0) for i in range(6)])
    assert gnss.counts["used"] == 0
    assert gnss.counts["rejected_beyond_drift"] == 4  # the 3rd agreeing one on


def test_gnss_that_disagrees_with_everything_is_rejected_as_a_whole() -> None:
    """Fixes alternating 50 m either side of the track: none agrees with the odometry or
    with another; after 20 refused the robot's GNSS is rejected, and said so."""
    fixes = [(float(i), 50.0 if i % 2 else -50.0) for i in range(30)]
    gnss = gate_run(fixes)
    assert gnss.counts["used"] == 0
    assert gnss.counts["rejected_disagreeing"] == 10  # the rest after the 20th
    (issue,) = gnss.issues
    assert issue.startswith("GNSS fixes of robot 'r1' disagree with its odometry and the plants")


def test_kernel_width_is_in_innovation_standard_deviations() -> None:
    fix = np.eye(2) * 0.02**2
    assert kernel_width(fix, fix, 2.0) == pytest.approx(2.0)
    # a pose uncertain by 0.06 m: the innovation is sqrt(10) fix sigmas wide
    wide = fix + np.diag([0.06**2, 1e-6])
    assert kernel_width(fix, wide, 2.0) == pytest.approx(2.0 * math.sqrt(10.0))
