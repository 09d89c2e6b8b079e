import numpy as np
import pytest

from agrislam.geometry.se2 import compose
from agrislam.io.sources.sync import (
    AFTER_LAST,
    BEFORE_FIRST,
    interpolate_increment,
    se2_exp,
    se2_log,
    synchronise,
)
from agrislam.records import Detection, Detections, Odometry, TruthPose

COV = np.diag([1e-2, 4e-3, 1e-3])


def _det(t, robot="r1"):
    return Detections(t=t, robot=robot, objects=(Detection(xy=np.array([1.0, 0.0])),))


def _odom(t, robot="r1", **kw):
    return Odometry(t=t, robot=robot, **kw)


def test_log_exp_round_trip_and_straight_line():
    d = np.array([0.7, -0.2, 0.9])
    np.testing.assert_allclose(se2_exp(se2_log(d)), d, atol=1e-12)
    # straight motion: a quarter of the time is a quarter of the way
    np.testing.assert_allclose(interpolate_increment(np.array([2.0, 0.0, 0.0]), 0.25), [0.5, 0, 0])


def test_interpolation_on_a_circle_is_exact():
    # driving a quarter circle of radius 1 (left): (1, 1, pi/2); half way is 45 deg round it
    half = interpolate_increment(np.array([1.0, 1.0, np.pi / 2]), 0.5)
    np.testing.assert_allclose(half, [np.sin(np.pi / 4), 1 - np.cos(np.pi / 4), np.pi / 4])


def test_frame_between_odometry_gets_an_odometry_record_at_its_time():
    out = list(
        synchronise(
            [
                _odom(0.0, delta=np.zeros(3)),
                _det(0.5),
                _odom(2.0, delta=np.array([2.0, 0.0, 0.0]), cov=COV),
            ]
        )
    )
    kinds = [(type(r).__name__, r.t) for r in out]
    assert kinds == [("Odometry", 0.0), ("Odometry", 0.5), ("Detections", 0.5), ("Odometry", 2.0)]
    np.testing.assert_allclose(out[1].delta, [0.5, 0.0, 0.0])  # a quarter of the interval
    np.testing.assert_allclose(out[3].delta, [1.5, 0.0, 0.0])
    np.testing.assert_allclose(out[1].cov, 0.25 * COV)
    np.testing.assert_allclose(out[3].cov, 0.75 * COV)
    # a robot's first delta record passes as it is
    np.testing.assert_array_equal(out[0].delta, np.zeros(3))
    assert out[0].cov is None


def test_pieces_compose_back_and_covariances_sum_back():
    delta = np.array([1.3, 0.4, 0.8])
    times = [0.3, 0.3, 1.1, 2.9]  # two frames at one time share one odometry record
    out = list(
        synchronise(
            [
                _odom(0.0, delta=np.zeros(3)),
                *[_det(t) for t in times],
                _odom(3.0, delta=delta, cov=COV),
            ]
        )
    )
    odo = [r for r in out if isinstance(r, Odometry)][1:]
    assert [o.t for o in odo] == [0.3, 1.1, 2.9, 3.0]
    pose = np.zeros(3)
    for o in odo:
        pose = compose(pose, o.delta)
    np.testing.assert_allclose(pose, delta, atol=1e-12)
    np.testing.assert_allclose(sum(o.cov for o in odo), COV)
    np.testing.assert_allclose([o.cov[0, 0] / COV[0, 0] for o in odo], [0.1, 0.8 / 3, 0.6, 0.1 / 3])
    # every frame follows an odometry record of its robot at its own time
    last = None
    for r in out:
        if isinstance(r, Odometry):
            last = r.t
        else:
            assert r.t == last


def test_pose_records_become_deltas():
    p0, p1 = np.array([1.0, 1.0, np.pi / 2]), np.array([1.0, 3.0, np.pi / 2])
    out = list(synchronise([_odom(0.0, pose=p0, cov=COV), _det(1.0), _odom(2.0, pose=p1, cov=COV)]))
    assert all(r.pose is None for r in out if isinstance(r, Odometry))
    # the first pose only starts the odometry frame: zero motion, with its covariance
    np.testing.assert_array_equal(out[0].delta, np.zeros(3))
    np.testing.assert_array_equal(out[0].cov, COV)
    np.testing.assert_allclose(out[1].delta, [1.0, 0.0, 0.0], atol=1e-12)  # forward in its frame
    np.testing.assert_allclose(out[3].delta, [1.0, 0.0, 0.0], atol=1e-12)


def test_frame_at_an_odometry_time_needs_no_interpolation():
    sync = synchronise(
        [
            _odom(0.0, delta=np.zeros(3)),
            _det(0.0),
            _det(1.0),
            _odom(1.0, delta=np.array([1.0, 0, 0]), cov=COV),
        ]
    )
    out = list(sync)
    assert [(type(r).__name__, r.t) for r in out] == [
        ("Odometry", 0.0),
        ("Detections", 0.0),
        ("Odometry", 1.0),
        ("Detections", 1.0),
    ]
    np.testing.assert_allclose(out[2].cov, COV)
    assert sync.n_interpolated == 0


def test_held_back_across_interleaved_robots_and_unplaced_at_the_ends():
    sync = synchronise(
        [
            _det(-1.0, "r2"),  # before r2's first odometry: never placeable
            _odom(0.0, "r1", delta=np.zeros(3)),
            _odom(0.0, "r2", delta=np.zeros(3)),
            _det(0.5, "r1"),  # held back until r1's odometry at 1.0
            TruthPose(t=0.5, robot="r1", pose=np.zeros(3)),
            _odom(0.6, "r2", delta=np.array([0.6, 0, 0])),
            _odom(1.0, "r1", delta=np.array([1.0, 0, 0])),
            _det(1.5, "r1"),  # after r1's last odometry
        ]
    )
    out = list(sync)
    names = [(type(r).__name__, r.robot, r.t) for r in out]
    assert names == [
        ("Odometry", "r1", 0.0),
        ("Odometry", "r2", 0.0),
        ("TruthPose", "r1", 0.5),
        ("Odometry", "r2", 0.6),
        ("Odometry", "r1", 0.5),
        ("Detections", "r1", 0.5),
        ("Odometry", "r1", 1.0),
    ]
    assert [(d.robot, d.t, why) for d, why in sync.unplaced] == [
        ("r2", -1.0, BEFORE_FIRST),
        ("r1", 1.5, AFTER_LAST),
    ]


def test_missing_covariance_takes_the_default_or_stays_missing():
    recs = [_odom(0.0, delta=np.zeros(3)), _det(1.0), _odom(4.0, delta=np.array([4.0, 0, 0]))]
    out = list(synchronise(recs))
    assert out[1].cov is None and out[3].cov is None
    out = list(synchronise(recs, default_cov=COV))
    np.testing.assert_allclose(out[1].cov + out[3].cov, COV)
    np.testing.assert_allclose(out[1].cov, 0.25 * COV)


def test_pose_after_delta_is_an_error():
    with pytest.raises(ValueError, match="one kind"):
        list(synchronise([_odom(0.0, delta=np.zeros(3)), _odom(1.0, pose=np.ones(3))]))
