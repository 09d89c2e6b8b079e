"""The graph back ends (sec. 2.6): the same small problems through the batch baseline,
plain iSAM2 and iSAM2 with keyframes (folding every step, so that retired objects and
their anchors are exercised), and a simulated survey through all three."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from agrislam.backend import (
    GraphBackend,
    RangeBearing,
    RelativePosition,
    detection_covariance,
    make_backend,
)
from agrislam.backend.batch import BatchBackend
from agrislam.backend.graph import OBJECT, key_kind, object_key
from agrislam.backend.incremental.backend import IncrementalBackend
from agrislam.backend.incremental.conditioning import FREE_SIGMA
from agrislam.backend.incremental.isam_state import PendingUpdate
from agrislam.backend.incremental.marginal_cache import STALE
from agrislam.config import RowsConfig, SlamConfig
from agrislam.geometry.se2 import rotation
from benchmark_module import load_benchmark

BACKENDS = {
    "batch": dict(backend="batch"),
    "isam2": dict(backend="incremental", window=0),
    "keyframes": dict(backend="incremental", window=1),
}
TIGHT = np.array([1e-4, 1e-4, 1e-5])
EXACT_ODOMETRY = np.diag([1e-8, 1e-8, 1e-10])


def backend(kind: str, **slam):
    return make_backend(SlamConfig(**{**BACKENDS[kind], **slam}), RowsConfig())


def observe_from(pose: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Where a point of the map appears in the robot frame of `pose`."""
    return rotation(pose[2]).T @ (truth - pose[:2])


@pytest.fixture(params=list(BACKENDS))
def kind(request):
    return request.param


def test_factory_builds_the_configured_back_end():
    assert isinstance(backend("batch"), BatchBackend)
    assert isinstance(backend("keyframes"), IncrementalBackend)


def test_every_back_end_is_what_the_protocol_lists(kind):
    """The batch and the incremental back end, and a saved map's prior wrapping one, have
    everything GraphBackend lists (what callers outside the back end use)."""
    from agrislam.season.prior_backend import PriorBackend

    g = backend(kind)
    assert isinstance(g, GraphBackend)
    assert isinstance(
        PriorBackend(g, np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2, 2))), GraphBackend
    )


def test_line_intersection_poor_depth_good_bearing(kind):
    """Sec. 2.6.1: one plant seen from two poses, depth 0.4 m off each time (sigma 0.5 m)
    but bearing sharp (0.005 m across): the graph puts it near the ray intersection."""
    truth = np.array([1.0, 2.0])
    poses = [np.zeros(3), np.array([2.0, 0.0, 0.0])]
    g = backend(kind, robust_kernel="none")
    g.add_robot("r", poses[0], TIGHT)
    single = []
    for n, (pose, depth_error) in enumerate(zip(poses, (0.4, -0.4), strict=True)):
        if n:
            g.add_odometry("r", float(n), poses[1] - poses[0], EXACT_ODOMETRY)
        rel = observe_from(pose, truth)
        xy = rel * (1 + depth_error / np.linalg.norm(rel))
        single.append(pose[:2] + rotation(pose[2]) @ xy)
        if n == 0:
            g.add_object(0, single[0])
        g.add_observation("r", 0, RelativePosition(xy, detection_covariance(xy, 0.5, 0.005)))
        g.update()
    for n in range(2, 12):  # the robot stands still: iSAM2 relinearises every 10th step
        g.add_odometry("r", float(n), np.zeros(3), EXACT_ODOMETRY)
        g.update()
    error = np.linalg.norm(g.object_positions(np.array([0]))[0] - truth)
    assert min(np.linalg.norm(s - truth) for s in single) == pytest.approx(0.4)
    assert error < 0.02


def test_object_covariance_is_the_detection_covariance_turned_into_the_map(kind):
    theta = 0.7
    xy = np.array([2.0, 0.5])
    cov = detection_covariance(xy, 0.1, 0.03)
    g = backend(kind, robust_kernel="none")
    g.add_robot("r", np.array([1.0, -1.0, theta]), TIGHT)
    g.add_object(3, np.array([1.0, -1.0]) + rotation(theta) @ xy)
    g.add_observation("r", 3, RelativePosition(xy, cov))
    g.update()
    expected = rotation(theta) @ cov @ rotation(theta).T  # + the tiny start-pose prior
    np.testing.assert_allclose(g.object_covariances(np.array([3]))[0], expected, atol=2e-6)
    # a second, identical detection halves it (Gaussian fusion)
    g.add_odometry("r", 1.0, np.zeros(3), EXACT_ODOMETRY)
    g.add_observation("r", 3, RelativePosition(xy, cov))
    g.update()
    np.testing.assert_allclose(g.object_covariances(np.array([3]))[0], expected / 2, atol=2e-6)


def test_range_bearing_measurement(kind):
    g = backend(kind)
    g.add_robot("r", np.array([0.0, 0.0, math.pi / 2]), TIGHT)
    g.add_object(0, np.array([0.1, 2.9]))
    g.add_observation("r", 0, RangeBearing(3.0, 0.0, 0.05, 0.01))
    g.update()
    for n in range(1, 11):  # iSAM2 relinearises every 10th step
        g.add_odometry("r", float(n), np.zeros(3), EXACT_ODOMETRY)
        g.update()
    np.testing.assert_allclose(g.object_positions(np.array([0]))[0], [0.0, 3.0], atol=1e-3)


def test_huber_kernel_resists_an_outlier(kind):
    truth = np.array([3.0, 1.0])
    estimates = {}
    for kernel in ("huber", "none"):
        g = backend(kind, robust_kernel=kernel)
        g.add_robot("r", np.zeros(3), TIGHT)
        g.add_object(0, truth + 0.05)
        for n in range(7):
            pose = np.array([0.2 * n, 0.0, 0.0])
            if n:
                g.add_odometry("r", float(n), np.array([0.2, 0.0, 0.0]), EXACT_ODOMETRY)
            xy = observe_from(pose, truth) + (np.array([0.0, 1.0]) if n == 6 else 0.0)
            g.add_observation("r", 0, RelativePosition(xy, detection_covariance(xy, 0.1, 0.03)))
            g.update()
        estimates[kernel] = np.linalg.norm(g.object_positions(np.array([0]))[0] - truth)
    assert estimates["huber"] < 0.5 * estimates["none"]


def two_copies(kind: str, merged: bool):
    """A plant seen 4 times; with `merged` the last 2 detections first made a duplicate."""
    truth = np.array([2.0, 0.5])
    g = backend(kind, robust_kernel="none")
    g.add_robot("r", np.zeros(3), TIGHT)
    offsets = [
        np.array([0.05, 0.0]),
        np.array([-0.03, 0.02]),
        np.array([0.0, -0.04]),
        np.array([0.02, 0.03]),
    ]
    for n, offset in enumerate(offsets):
        pose = np.array([0.3 * n, 0.0, 0.0])
        if n:
            g.add_odometry("r", float(n), np.array([0.3, 0.0, 0.0]), EXACT_ODOMETRY)
        obj = 1 if merged and n >= 2 else 0
        if n == 0 or (obj == 1 and n == 2):
            g.add_object(obj, truth + offset)
        xy = observe_from(pose, truth + offset)
        g.add_observation("r", obj, RelativePosition(xy, detection_covariance(xy, 0.1, 0.03)))
        g.update()
    return g


def test_merge_moves_every_factor_to_the_kept_object(kind):
    single = two_copies(kind, merged=False)
    g = two_copies(kind, merged=True)
    g.merge_objects(0, 1)
    assert np.all(np.isfinite(g.object_covariances(np.array([0]))))  # asked before update
    g.update()
    assert g.object_ids().tolist() == [0]
    assert all(1 not in f.keys for f in g.graph.factors.values())
    expected = single.object_positions(np.array([0]))
    np.testing.assert_allclose(g.object_positions(np.array([0])), expected, atol=2e-3)
    np.testing.assert_allclose(
        g.object_covariances(np.array([0])), single.object_covariances(np.array([0])), atol=1e-4
    )
    with pytest.raises(KeyError, match="object 1"):
        g.object_positions(np.array([1]))


def test_objects_merged_while_retired_fold_again_on_their_own_keyframes(kind):
    """Two copies retired by folds and merged before either is seen again: the kept object
    comes back on its anchors alone, while the pose it was last seen from is long retired;
    the next fold retires it on a keyframe its factors reach (it once looked for the newest
    keyframe of the robot that saw it last, which its factors did not touch)."""
    g = two_copies(kind, merged=True)
    truth = np.array([2.0, 0.5])
    for n in range(4, 10):  # driving on past other plants: the copies stay retired
        g.add_odometry("r", float(n), np.array([0.3, 0.0, 0.0]), EXACT_ODOMETRY)
        g.add_object(n, np.array([0.3 * n + 1.0, -1.0]))
        g.add_observation("r", n, RelativePosition(np.array([1.0, -1.0]), np.eye(2) * 1e-2))
        g.update()
    g.merge_objects(0, 1)
    for n in range(10, 13):
        g.add_odometry("r", float(n), np.array([0.3, 0.0, 0.0]), EXACT_ODOMETRY)
        g.update()
    np.testing.assert_allclose(g.object_positions(np.array([0]))[0], truth, atol=0.05)
    assert np.all(np.isfinite(g.object_covariances(np.array([0]))))


def test_remove_object_drops_it_and_keeps_the_rest(kind):
    g = two_copies(kind, merged=True)
    g.remove_object(1)
    g.update()
    assert g.object_ids().tolist() == [0]
    g.add_odometry("r", 9.0, np.zeros(3), EXACT_ODOMETRY)
    g.add_observation("r", 0, RelativePosition(np.array([1.1, 0.5]), np.eye(2) * 1e-2))
    g.update()
    assert np.all(np.isfinite(g.object_positions(np.array([0]))))


def test_second_robot_without_start_pose_is_placed_by_shared_objects(kind):
    plants = np.array([[2.0, 1.0], [3.0, -1.0], [4.0, 0.5]])
    g = backend(kind, robust_kernel="none")
    g.add_robot("a", np.zeros(3), TIGHT)
    for i, p in enumerate(plants):
        g.add_object(i, p)
        xy = observe_from(np.zeros(3), p)
        g.add_observation("a", i, RelativePosition(xy, detection_covariance(xy, 0.02, 0.01)))
    g.update()
    b_truth = np.array([1.0, 0.8, 0.4])  # Gauss-Newton (iSAM2) needs a start this near
    g.add_robot("b", None, np.array([10.0, 10.0, math.pi]))  # as the world does
    for i, p in enumerate(plants):
        xy = observe_from(b_truth, p)
        g.add_observation("b", i, RelativePosition(xy, detection_covariance(xy, 0.02, 0.01)))
    g.update()
    for _ in range(12):  # iSAM2 relinearises every 10th step: from the far-off start
        g.add_odometry("b", 1.0, np.zeros(3), EXACT_ODOMETRY)
        g.update()
    np.testing.assert_allclose(g.current_pose("b")[:2], b_truth[:2], atol=0.05)
    times, poses = g.trajectory("a")
    assert poses.shape == (1, 3) and times.shape == (1,)


def test_bad_input_names_what_and_where():
    g = backend("keyframes")
    g.add_robot("r", np.zeros(3))
    with pytest.raises(KeyError, match="robot 'x'"):
        g.add_odometry("x", 1.0, np.zeros(3), np.eye(3))
    with pytest.raises(ValueError, match=r"odometry of robot 'r' at t=1\.0.*positive definite"):
        g.add_odometry("r", 1.0, np.zeros(3), -np.eye(3))
    with pytest.raises(ValueError, match="delta must be 3 finite"):
        g.add_odometry("r", 1.0, np.array([0.0, np.nan, 0.0]), np.eye(3))
    with pytest.raises(KeyError, match="object 5"):
        g.add_observation("r", 5, RelativePosition(np.ones(2), np.eye(2)))
    g.add_object(5, np.ones(2))
    with pytest.raises(ValueError, match="already exists"):
        g.add_object(5, np.ones(2))
    with pytest.raises(ValueError, match="non-negative"):
        g.add_object(-1, np.ones(2))
    with pytest.raises(ValueError, match=r"observation of object 5 by 'r'.*symmetric"):
        g.add_observation("r", 5, RelativePosition(np.ones(2), np.array([[1.0, 0.2], [0.0, 1.0]])))
    with pytest.raises(ValueError, match=r"observation of object 5 by 'r'.*range must be > 0"):
        g.add_observation("r", 5, RangeBearing(-1.0, 0.0, 0.1, 0.01))
    with pytest.raises(ValueError, match="object 5 has no observation"):
        g.object_covariances(np.array([5]))
    with pytest.raises(ValueError, match="already in the graph"):
        g.add_robot("r")


# ------------------------------------------------------------------ simulated survey
def bench():
    """benchmarks/bench_geometry.py: its simulated surveys and driver, tested here too."""
    return load_benchmark("bench_geometry")


@pytest.fixture(scope="module")
def small_survey():
    b = bench()
    return b, b.make_survey(60, n_rows=3)


def test_keyframes_stay_close_to_batch_and_refine_is_batch(small_survey):
    b, survey = small_survey
    maps = {}
    for name, slam in {
        "batch": SlamConfig(backend="batch"),
        "keyframes": SlamConfig(window=20),
    }.items():
        g = make_backend(slam, RowsConfig())
        _, ids, complete, _ = b.drive(g, survey, None, float("inf"))
        assert complete
        maps[name] = b.positions(g, ids)
        if name == "keyframes":
            assert g.rolls >= len(survey.steps) // 20
            n_nodes = sum(len(c.keys) for c in g.graph.robots.values()) + len(ids)
            assert g.live_size() < n_nodes / 3  # the past is folded away
            online = dict(maps[name])
            g.refine()
            maps["refined"] = b.positions(g, ids)
    ids = list(maps["batch"])
    gap = [np.linalg.norm(online[k] - maps["batch"][k]) for k in ids]
    refined = [np.linalg.norm(maps["refined"][k] - maps["batch"][k]) for k in ids]
    assert np.sqrt(np.mean(np.square(gap))) < 0.05
    assert max(refined) < 1e-3
    err = {name: b.rms_error(m, survey.truth) for name, m in maps.items()}
    assert err["keyframes"] < 1.1 * err["batch"]


def test_keyframes_beyond_the_kept_ones_fold_away_and_hold_what_hangs_on_them(small_survey):
    b, survey = small_survey
    batch = make_backend(SlamConfig(backend="batch"), RowsConfig())
    _, ids, _, _ = b.drive(batch, survey, None, float("inf"))
    g = make_backend(SlamConfig(window=10, keyframes_kept=2), RowsConfig())
    covariances_read = lambda step: g.object_covariances(g.object_ids()) is None  # noqa: E731
    _, ids, complete, _ = b.drive(g, survey, None, float("inf"), covariances_read)
    assert complete and g.rolls >= len(survey.steps) // 10
    for robot in g.graph.robots:  # the first pose and the newest two
        assert len(g.keyframes(robot)) <= 3
    anchors = set(g.anchor_keyframes().tolist())
    frozen = {k for k in anchors if g.node_state(k) == "frozen"}
    assert frozen and all(g.node_state(k) == "live" for k in anchors - frozen)  # or held
    # no covariance kept per retired node
    assert all(g.kept_covariance(k) is None for k in g.node_keys("retired").tolist())
    online, exact = b.positions(g, ids), b.positions(batch, ids)
    gap = [np.linalg.norm(online[k] - exact[k]) for k in ids]
    # moved onto the newest keyframe instead, they swung with its heading
    assert np.sqrt(np.mean(np.square(gap))) < 0.015
    g.refine()  # the whole record is kept: the batch solution again
    refined = b.positions(g, ids)
    assert max(np.linalg.norm(refined[k] - exact[k]) for k in ids) < 1e-3
    assert g.whole_refine == g.refines  # a batch: settled objects moved too
    # a fix pulls the live graph 0.5 m: the objects on frozen keyframes stay where they are
    everything = np.array(list(ids.values()))
    settled = g.settled_objects()
    assert 0 < len(settled) < len(everything)
    before, refines = g.object_positions(everything), g.refines  # (a refine moves all)
    robot = next(iter(g.graph.robots))
    fix = np.r_[g.current_pose(robot)[:2] + np.array([0.0, 0.5]), 0.0, 0.0, 1.0, 0.0]
    g.add_gnss(robot, fix, np.eye(2) * 1e-4)
    g.update()
    moved = np.linalg.norm(g.object_positions(everything) - before, axis=1)
    assert g.refines == refines and not moved[settled].any() and moved.max() > 0.1
    before = g.object_positions(everything)
    g.refine(max_factors=0)  # too large for a batch: the keyframe graph alone moves
    assert g.refines == refines + 1 and g.whole_refine < g.refines
    assert not np.any(g.object_positions(everything)[settled] - before[settled])
    with pytest.raises(ValueError, match="keyframes_kept"):
        SlamConfig(keyframes_kept=-1)


def loop_survey(g, bias: float = 0.02):
    """A robot drives a circle of radius 4 m (80 steps) past 12 landmarks, its odometry
    turning `bias` rad too little per step, and at the end sees the first ones again."""
    landmarks = [5.0 * np.array([np.cos(a), np.sin(a)]) for a in np.linspace(0, 2 * np.pi, 13)[:-1]]
    step = 2 * np.pi / 80
    g.add_robot("r", np.array([4.0, 0.0, np.pi / 2]), TIGHT)
    truth = np.array([4.0, 0.0, np.pi / 2])
    chord = 2 * 4.0 * np.sin(step / 2)
    for n in range(90):
        if n:
            truth = np.array([4.0 * np.cos(n * step), 4.0 * np.sin(n * step), np.pi / 2 + n * step])
            delta = np.array([chord, 0.0, step - bias])
            g.add_odometry("r", float(n), delta, np.diag([1e-4, 1e-4, 1e-4]))
        for i, p in enumerate(landmarks):
            xy = observe_from(truth, p)
            if np.hypot(*xy) < 2.5 and xy[0] > 0:
                if i not in g.graph.objects:
                    g.add_object(i, compose_xy(g.current_pose("r"), xy))
                g.add_observation(
                    "r", i, RelativePosition(xy, detection_covariance(xy, 0.05, 0.02))
                )
        g.update()
    return np.array(landmarks)


def compose_xy(pose, xy):
    return pose[:2] + rotation(pose[2]) @ xy


def test_a_large_loop_closure_refines_the_folded_history():
    maps = {}
    for name, slam in {
        "batch": SlamConfig(backend="batch"),
        "refining": SlamConfig(window=5),
        "linear": SlamConfig(window=5, refine_turn_deg=0.0),
    }.items():
        g = make_backend(slam, RowsConfig())
        loop_survey(g)
        ids = g.object_ids()
        maps[name] = (g, g.object_positions(ids))
    assert maps["refining"][0].refines >= 1 and maps["linear"][0].refines == 0
    gap = {n: np.abs(maps[n][1] - maps["batch"][1]).max() for n in ("refining", "linear")}
    assert gap["refining"] < 0.05
    assert gap["refining"] < gap["linear"]


def test_a_loop_closure_in_a_large_graph_does_not_stall_the_step_with_a_batch(monkeypatch):
    """Past TURN_REFINE_MAX_FACTORS the refine a turn starts mid-survey relinearises the
    keyframe graph only (bounded work); an explicit refine() still solves the batch."""
    import agrislam.backend.incremental.refine as incremental

    batches = []
    solve = incremental.solve
    monkeypatch.setattr(incremental, "solve", lambda *a: batches.append(1) or solve(*a))
    monkeypatch.setattr(incremental, "TURN_REFINE_MAX_FACTORS", 10)
    g = make_backend(SlamConfig(window=5), RowsConfig())
    loop_survey(g)
    assert g.refines >= 1 and not batches
    g.refine()
    assert len(batches) == 1


def test_dogleg_batch_reaches_the_lm_solution():
    lm = two_copies("batch", merged=False)
    dogleg = make_backend(SlamConfig(backend="batch", batch_optimizer="dogleg"), RowsConfig())
    dogleg.load(lm.graph, {k: lm.estimate(k) + 0.01 for k in lm.graph.all_keys()})
    dogleg.update()
    np.testing.assert_allclose(
        dogleg.object_positions(np.array([0])), lm.object_positions(np.array([0])), atol=1e-5
    )


def test_qr_and_cholesky_reach_the_same_map():
    maps = {}
    for factorization in ("qr", "cholesky"):
        g = make_backend(SlamConfig(window=5, factorization=factorization), RowsConfig())
        loop_survey(g)
        maps[factorization] = g.object_positions(g.object_ids())
    np.testing.assert_allclose(maps["qr"], maps["cholesky"], atol=1e-6)


def line_survey(g) -> None:
    """A robot drives 40 steps along a line of plants on both sides, seeing each for a
    few steps; everything is linear enough that keyframes change nothing."""
    plants = np.array([[0.5 * i, 1.0 if i % 2 else -1.0] for i in range(30)])
    g.add_robot("r", np.zeros(3), TIGHT)
    pose = np.zeros(3)
    for n in range(40):
        if n:
            pose = pose + np.array([0.4, 0.0, 0.0])
            g.add_odometry("r", float(n), np.array([0.4, 0.0, 0.0]), np.diag([1e-3, 1e-3, 1e-4]))
        for i, p in enumerate(plants):
            xy = observe_from(pose, p)
            if 0 < xy[0] < 2.0:
                if i not in g.graph.objects:
                    g.add_object(i, compose_xy(g.current_pose("r"), xy))
                cov = detection_covariance(xy, 0.05, 0.02)
                g.add_observation("r", i, RelativePosition(xy, cov))
        g.update()


def test_retired_nodes_are_where_plain_isam2_puts_them():
    maps = {}
    for window in (0, 5):
        g = make_backend(SlamConfig(window=window, refine_turn_deg=0.0), RowsConfig())
        line_survey(g)
        maps[window] = (g, g.object_positions(g.object_ids()), g.trajectory("r")[1])
    retired = maps[5][0].node_keys("retired")
    objects = np.array([key_kind(k) == OBJECT for k in retired.tolist()], dtype=bool)
    assert objects.sum() >= 20 and (~objects).sum() >= 25
    np.testing.assert_allclose(maps[5][1], maps[0][1], atol=1e-9)
    np.testing.assert_allclose(maps[5][2], maps[0][2], atol=1e-9)


def test_a_folds_covariances_wait_a_step_and_do_not_depend_on_when_they_are_read():
    """The fold step leaves its objects' covariances to the next steps; a back end that
    reads every covariance after every step ends with the same ones."""
    read_each_step = make_backend(SlamConfig(window=5, refine_turn_deg=0.0), RowsConfig())
    update = read_each_step.update

    def update_and_read() -> None:
        update()
        if read_each_step.deferred_covariances():  # a fold just now
            read_each_step.object_covariances(read_each_step.object_ids())

    read_each_step.update = update_and_read
    lazy = make_backend(SlamConfig(window=5, refine_turn_deg=0.0), RowsConfig())
    waiting = []
    lazy_update = lazy.update

    def update_and_count() -> None:
        lazy_update()
        waiting.append(lazy.deferred_covariances())

    lazy.update = update_and_count
    for g in (read_each_step, lazy):
        line_survey(g)
    assert max(waiting) >= 1 and 0 in waiting  # a fold defers, the next steps settle
    ids = lazy.object_ids()
    # equal but for the keyframes' own marginals, read from iSAM2 at other steps
    np.testing.assert_allclose(
        lazy.object_covariances(ids), read_each_step.object_covariances(ids), rtol=1e-9
    )


def lone_on_a_bearing(g, monkeypatch) -> tuple[int, int]:
    """An object seen from the robot's latest pose whose detection iSAM2 gets as a bearing
    alone: held by one bearing, as a row is whose members left, the next update is
    indeterminate near it. Returns the pose and it."""
    import agrislam.backend.incremental.backend as incremental

    pose, lone, make_factor = g.graph.robot("r").keys[-1], object_key(999), incremental.make_factor

    def bearing_only(factor, slam):
        if lone not in factor.keys:
            return make_factor(factor, slam)
        noise = gtsam.noiseModel.Isotropic.Sigma(1, 0.01)
        return gtsam.BearingFactor2D(pose, lone, gtsam.Rot2(0.3), noise)

    monkeypatch.setattr(incremental, "make_factor", bearing_only)
    xy = np.array([17.0, 1.0])
    g.add_object(999, xy)
    z = observe_from(g.current_pose("r"), xy)
    g.add_observation("r", 999, RelativePosition(z, detection_covariance(z, 0.05, 0.01)))
    return pose, lone


@pytest.mark.parametrize("window", [0, 5])
def test_a_node_an_update_leaves_indeterminate_gets_a_weak_prior_and_mapping_goes_on(
    window, monkeypatch
):
    """A node iSAM2 cannot solve (here an object held by one bearing only, as a row is
    whose members left) does not end the run: iSAM2 is rebuilt from the live factors,
    the node held by a weak prior, the update done again, and the isolation counted."""
    g = make_backend(SlamConfig(window=window, refine_turn_deg=0.0), RowsConfig())
    line_survey(g)
    ids = g.object_ids()
    before = g.object_positions(ids)
    pose, lone = lone_on_a_bearing(g, monkeypatch)
    g.update()
    assert g.issues["object held by a weak prior: indeterminate in an iSAM2 update"] == 1
    # the map where it was (the bearing pulls the last pose a little)
    np.testing.assert_allclose(g.object_positions(ids), before, atol=5e-3)
    x, y, theta = g.estimate(pose)  # the lone object turned onto its bearing, held near
    lone_xy = g.estimate(lone)
    assert math.atan2(lone_xy[1] - y, lone_xy[0] - x) - theta == pytest.approx(0.3, abs=0.02)
    g.add_odometry("r", 99.0, np.array([0.4, 0.0, 0.0]), np.diag([1e-3, 1e-3, 1e-4]))
    g.update()  # and the next steps map on
    assert g.live_factor_count() == g.isam_factors().nrFactors()


@pytest.mark.parametrize("throws", [1, 2])
def test_an_update_indeterminate_in_a_fold_reenters_the_nodes_the_window_took_all_factors_of(
    throws, monkeypatch
):
    """A fold's update that throws is redone on a fresh iSAM2 of the live factors. The
    window took all live factors of the new keyframe (its odometry and detections), so
    the fresh iSAM2 lacks it while the fold's marginal needs it: it enters again at the
    estimate it had (else GTSAM ends the run: `x1222 is not in this VectorValues`).
    Thrown again, the fold's marginal gives way to weak priors where its nodes stand."""
    g = make_backend(SlamConfig(window=5, refine_turn_deg=0.0), RowsConfig())
    line_survey(g)
    odometry = np.array([0.4, 0.0, 0.0]), np.diag([1e-3, 1e-3, 1e-4])
    for n in range(5):  # to the step that folds
        g.add_odometry("r", 40.0 + n, *odometry)
        if n < 4:
            assert not g.update()
    before = g.object_positions(g.object_ids())
    keyframe, flush = g.graph.robot("r").keys[-1], PendingUpdate.flush

    def indeterminate_in_the_fold(pending, isam, extra=None):
        if extra is not None and sum(g.issues.values()) < throws:  # as GTSAM throws
            raise RuntimeError(f"Indeterminate linear system ... near variable {keyframe}")
        return flush(pending, isam, extra)

    monkeypatch.setattr(PendingUpdate, "flush", indeterminate_in_the_fold)
    assert g.update()
    assert g.issues["pose held by a weak prior: indeterminate in an iSAM2 update"] == throws
    assert g.issues["a fold's marginal given up: indeterminate in an iSAM2 update"] == throws - 1
    np.testing.assert_allclose(g.object_positions(g.object_ids()), before, atol=1e-6)
    np.testing.assert_allclose(g.estimate(keyframe), [17.6, 0.0, 0.0], atol=1e-6)
    for n in range(6):  # and the next steps map on, through the next fold
        g.add_odometry("r", 45.0 + n, *odometry)
        g.update()
    np.testing.assert_allclose(g.current_pose("r"), [20.0, 0.0, 0.0], atol=1e-6)
    assert g.live_factor_count() == g.isam_factors().nrFactors()


def test_a_retired_objects_covariance_is_its_keyframes_carried_over_plus_its_own():
    """cov(K (+) z) = J cov_K J^T + R cov_z R^T, J = d(K Exp(xi) (+) z)/d xi, checked one
    object at a time with a numeric J against the vectorised back end."""
    g = make_backend(SlamConfig(window=5, refine_turn_deg=0.0), RowsConfig())
    line_survey(g)
    ids = g.object_ids()
    got = g.object_covariances(ids)
    checked = 0
    for object_id, cov in zip(ids, got, strict=True):
        anchor = g.anchor_of(g.graph.require_object(int(object_id)))
        if anchor is None:
            continue
        pose = gtsam.Pose2(*g.estimate(anchor.keyframe))
        jac = np.zeros((2, 3))
        for i in range(3):
            d = np.zeros(3)
            d[i] = 1e-6
            ahead, back = (pose.compose(gtsam.Pose2.Expmap(s * d)) for s in (1, -1))
            jac[:, i] = (ahead.transformFrom(anchor.z) - back.transformFrom(anchor.z)) / 2e-6
        rot = rotation(pose.theta())
        cov_k = g.marginal_covariance(anchor.keyframe)
        np.testing.assert_allclose(cov, jac @ cov_k @ jac.T + rot @ anchor.cov @ rot.T, rtol=1e-6)
        checked += 1
    assert checked >= 20


@pytest.mark.parametrize("window", [0, 3])
def test_a_new_poses_covariance_carried_through_its_odometry_is_isam2s(window):
    """current_pose_covariance of a pose just added is the previous pose's carried through
    the increment (no iSAM2 update of its own): the same as iSAM2's after the update."""
    g = make_backend(SlamConfig(window=window, refine_turn_deg=0.0), RowsConfig())
    g.add_robot("r", np.array([1.0, 2.0, 0.4]), np.array([0.1, 0.05, 0.02]))
    xy = np.array([2.0, 0.5])
    g.add_object(0, xy)
    g.add_observation("r", 0, RelativePosition(xy, detection_covariance(xy, 0.05, 0.01)))
    g.update()
    for t in range(1, 6):
        g.add_odometry("r", float(t), np.array([0.3, 0.05, 0.1 * t]), np.diag([1e-3, 4e-4, 2e-4]))
        carried = g.current_pose_covariance("r")
        g.update()
        solved = g.marginal_covariance(g.graph.robot("r").keys[-1])
        np.testing.assert_allclose(carried, solved, rtol=1e-9, atol=1e-12)


def test_a_robots_pose_covariance_is_read_once_at_its_own_update():
    """Five robots' frames each read the previous pose's covariance; read fresh it walked
    the Bayes tree down to where the other robots' updates had sunk the pose. The update
    reads it while the pose is at the top;
    the next frame carries that, which the other robots' frames since can only have made
    the wider (they add information)."""
    g = make_backend(SlamConfig(window=0), RowsConfig())
    landmark = np.array([1.0, 1.0])
    g.add_object(0, landmark)
    starts = {"a": np.array([0.0, 0.0, 0.0]), "b": np.array([2.0, 0.0, np.pi / 2])}
    for robot, start in starts.items():
        g.add_robot(robot, start, np.array([0.1, 0.1, 0.05]))
    read_at, steps = {}, 0
    for t in range(1, 8):
        for robot in starts:
            g.add_odometry(robot, float(t), np.array([0.1, 0.0, 0.02]), np.diag([1e-3, 1e-3, 4e-4]))
            if t > 1:  # the pose its last update read is not read again ...
                previous = g.graph.robot(robot).keys[-2]
                g.current_pose_covariance(robot)
                step, kept = g.kept_covariance(previous)
                assert step == read_at[robot]
                # ... and what was read then is iSAM2's now, or wider (here, a robot that
                # shares its only landmark: one frame of the other narrows it by a third)
                fresh = g.marginal_covariance(previous)
                assert np.linalg.eigvalsh(kept - fresh).min() > -1e-12
                assert np.all(np.diag(kept) <= 2.0 * np.diag(fresh))
            z = observe_from(g.current_pose(robot), landmark)
            g.add_observation(robot, 0, RelativePosition(z, detection_covariance(z, 0.05, 0.01)))
            read_at[robot] = steps  # the step the update reads at
            g.update()
            steps += 1


@pytest.mark.parametrize("kept, per_robot", [(100, 3), (3, 30)])
def test_a_robot_keeps_the_smaller_of_its_share_and_keyframes_per_robot(
    small_survey, kept, per_robot
):
    """A lone robot's many keyframes make each keyframe's marginal read dearer:
    `slam.keyframes_per_robot` caps its share."""
    b, survey = small_survey
    slam = SlamConfig(window=10, keyframes_kept=kept, keyframes_per_robot=per_robot)
    g = make_backend(slam, RowsConfig())
    _, _, complete, _ = b.drive(g, survey, None, float("inf"))
    assert complete and g.rolls > 5
    assert [len(g.keyframes(r)) for r in g.graph.robots] == [4]  # the first and newest 3
    # each other keyframe aged, held where it stood
    assert len(g.node_keys("frozen")) == g.rolls + 1 - 4
    with pytest.raises(ValueError, match="keyframes_per_robot"):
        SlamConfig(keyframes_per_robot=0)


def test_a_graph_above_the_batch_limit_refines_its_folded_keyframe_graph(small_survey):
    """refine() past `refine_max_factors`: no batch over the whole record (its memory grows
    with the field), the keyframe graph is relinearised instead; the map stays close to
    the batch solution and the back end keeps mapping."""
    b, survey = small_survey
    maps = {}
    for name, slam in {
        "batch": SlamConfig(backend="batch"),
        "bounded": SlamConfig(window=20, refine_max_factors=10),
    }.items():
        g = make_backend(slam, RowsConfig())
        _, ids, complete, _ = b.drive(g, survey, None, float("inf"))
        assert complete
        if name == "bounded":
            live = g.live_size()
            g.refine()
            assert g.refines >= 1 and g.live_size() <= live
        maps[name] = b.positions(g, ids)
    gap = [np.linalg.norm(maps["bounded"][k] - maps["batch"][k]) for k in maps["batch"]]
    assert np.sqrt(np.mean(np.square(gap))) < 0.05


def test_isam2_is_rebuilt_when_the_slots_of_factors_it_let_go_pile_up(small_survey, monkeypatch):
    """iSAM2 keeps a slot for every factor it ever held: past slack x live + floor it is
    rebuilt from the live factors half way between folds, and the map is the same."""
    import agrislam.backend.incremental.live as incremental

    b, survey = small_survey
    maps, slots = {}, {}
    for name, floor in {"kept": 10**9, "rebuilt": 0}.items():
        monkeypatch.setattr(incremental, "SLOTS_FLOOR", floor)
        monkeypatch.setattr(incremental, "SLOTS_SLACK", 2)
        g = make_backend(SlamConfig(window=10), RowsConfig())
        _, ids, complete, _ = b.drive(g, survey, None, float("inf"))
        assert complete and g.rolls >= len(survey.steps) // 10
        slots[name] = g.isam_factors().size()
        assert g.live_factor_count() == g.isam_factors().nrFactors()  # the table follows
        maps[name] = b.positions(g, ids)
    assert slots["rebuilt"] < slots["kept"] / 3
    gap = [np.linalg.norm(maps["rebuilt"][k] - maps["kept"][k]) for k in maps["kept"]]
    assert max(gap) < 1e-3


def test_object_keys_are_gtsams_symbols_and_unknown_ids_are_named():
    from agrislam.backend.graph import SurveyGraph, object_key, object_keys

    ids = np.array([0, 7, 123_456_789])
    assert object_keys(ids) == [object_key(int(i)) for i in ids]
    graph = SurveyGraph()
    graph.add_object(7, np.zeros(2))
    assert graph.require_objects(np.array([7])) == [object_key(7)]
    with pytest.raises(KeyError, match="object 8 "):
        graph.require_objects(np.array([7, 8]))


@pytest.mark.parametrize("robots", [1, 3])
def test_a_marginal_read_serves_each_robot_covariance_reuse_steps_steps(robots, monkeypatch):
    """COVARIANCE_REUSE_STEPS counts each robot's steps: robots share the step count, and
    with three a read per that many shared steps would be one every other frame of each,
    a cost growing with the robots. Out of sight, the object's read serves STALE times as
    long."""
    import agrislam.backend.incremental.live as incremental

    monkeypatch.setattr(incremental, "COVARIANCE_REUSE_STEPS", 2)
    g = make_backend(SlamConfig(window=0), RowsConfig())
    xy = np.array([2.0, 2.0])
    g.add_object(0, xy)
    starts = {f"r{n}": np.array([0.0, float(n), 0.0]) for n in range(robots)}
    for name, start in starts.items():
        g.add_robot(name, start, TIGHT)
        rel = observe_from(start, xy)
        g.add_observation(name, 0, RelativePosition(rel, detection_covariance(rel, 0.05, 0.01)))
    g.update()
    key = g.graph.require_objects(np.array([0]))[0]
    first = g.object_covariances(np.array([0]))
    read_at = g.kept_covariance(key)[0]
    steps = 0
    while g.kept_covariance(key)[0] == read_at:  # the robots drive on without seeing it
        name = list(starts)[steps % robots]
        g.add_odometry(name, 1.0 + steps, np.array([0.1, 0.0, 0.0]), np.diag([1e-4, 1e-4, 1e-5]))
        g.update()
        steps += 1
        np.testing.assert_allclose(g.object_covariances(np.array([0])), first, rtol=0.5)
    assert steps == STALE * 2 * robots


def test_a_fold_whose_objects_cannot_be_given_their_keyframe_gives_them_a_weak_covariance(
    monkeypatch,
):
    """Where a fold's deferred job cannot condition its objects on their keyframe (an object
    outside the keyframe's part of the graph, after a merge of objects far apart, as on
    Victoria Park), they get FREE_SIGMA and an issue; the run goes on."""
    import agrislam.backend.incremental.conditioning as conditioning

    def outside(graph, point, keys):
        raise RuntimeError(f"objects {gtsam.DefaultKeyFormatter(keys[0])} are not in the graph")

    monkeypatch.setattr(conditioning, "marginal_covariances", outside)
    g = make_backend(SlamConfig(window=5, refine_turn_deg=0.0), RowsConfig())
    line_survey(g)
    weak = g.issues["object given a weak covariance at a keyframe fold"]
    assert weak >= 20
    retired = [k for k in g.node_keys("retired").tolist() if key_kind(k) == OBJECT]
    covs = np.array([g.anchor_of(k).cov for k in retired])
    np.testing.assert_allclose(covs, np.broadcast_to(np.eye(2) * FREE_SIGMA**2, covs.shape))
