import numpy as np
import pytest

from agrislam.sim.config import SimConfig
from agrislam.sim.field import make_field
from agrislam.sim.path import frame_times, lane_offsets, lawnmower, rounded_polyline, survey_path


def _setup(**over):
    cfg = SimConfig.model_validate(over)
    return make_field(cfg, np.random.default_rng(1)), cfg


def test_rounded_corner_is_a_quarter_circle():
    # (0,0) -> (2,0) -> (2,2) with radius 0.5: 1.5 + pi/4 + 1.5 m
    path = rounded_polyline(np.array([[0, 0], [2, 0], [2, 2]]), 0.5)
    assert path.length == pytest.approx(3.0 + np.pi / 4)
    mid = path.at_distance(1.5 + np.pi / 8)[0]
    # halfway round the arc centred at (1.5, 0.5): heading 45 deg
    np.testing.assert_allclose(
        mid[:2], [1.5 + 0.5 * np.sin(np.pi / 4), 0.5 - 0.5 * np.cos(np.pi / 4)]
    )
    assert mid[2] == pytest.approx(np.pi / 4)
    np.testing.assert_allclose(path.at_distance(path.length)[0], [2, 2, np.pi / 2], atol=1e-12)


def test_reversal_is_a_turn_on_the_spot_that_takes_time():
    path = rounded_polyline(np.array([[0, 0], [1, 0], [0, 0]]), 0.5)
    assert path.length == pytest.approx(2.0 + np.pi * 0.5)
    during = path.at_distance(np.array([1.0 + 0.1, 1.0 + np.pi * 0.25]))
    np.testing.assert_allclose(during[:, :2], [[1, 0], [1, 0]], atol=1e-12)
    assert abs(during[1, 2]) == pytest.approx(np.pi / 2)


def test_short_legs_shrink_the_radius():
    path = rounded_polyline(np.array([[0, 0], [1, 0], [1, 0.4], [0, 0.4]]), 0.5)
    assert path.radius.max() == pytest.approx(0.2)  # half of the 0.4 m leg per corner


def test_default_lawnmower_drives_between_the_rows_at_speed():
    field, cfg = _setup()
    np.testing.assert_allclose(lane_offsets(field, cfg), np.arange(9) + 0.5)
    poses, t = lawnmower(field, cfg)
    np.testing.assert_allclose(np.diff(t), 0.5)  # 2 Hz
    step = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)
    assert step.max() <= 0.2 + 1e-9 and np.median(step) == pytest.approx(0.2)  # 0.4 m/s
    np.testing.assert_allclose(poses[0], [-1.0, 0.5, 0.0])
    # never on a row: between rows the robot keeps 0.5 m from both
    s, across = field.to_field(poses[:, :2])
    inside = (s > 0) & (s < field.row_length)
    assert np.abs(across[inside] - np.round(across[inside] - 0.5) - 0.5).max() < 1e-9
    # heading along the lane direction while inside the field
    assert np.allclose(np.abs(np.cos(poses[inside, 2])), 1.0)
    # 9 lanes of row length + 2 headlands, each of the 8 U-turns cutting 0.5 m off two lane
    # ends and replacing them by a semicircle of radius 0.5
    assert survey_path(field, cfg).length == pytest.approx(
        9 * (field.row_length + 2) - 8 * 1.0 + 8 * np.pi * 0.5, rel=1e-9
    )


def test_return_to_start_ends_at_the_start():
    field, cfg = _setup(path={"return_to_start": True})
    poses, _ = lawnmower(field, cfg)
    assert np.linalg.norm(poses[-1, :2] - poses[0, :2]) < 0.25
    field, cfg = _setup(path={"return_to_start": True}, field={"n_rows": 9, "n_plants": 360})
    poses, _ = lawnmower(field, cfg)  # 8 lanes: ends on the start headland, drives 3 m in
    np.testing.assert_allclose(poses[-1, 1], 0.5, atol=1e-9)
    assert poses[-1, 0] == pytest.approx(2.0, abs=0.25)


def test_robots_split_the_lanes():
    field, cfg = _setup(path={"n_robots": 3})
    starts = [lawnmower(field, cfg, r)[0][0] for r in range(3)]
    np.testing.assert_allclose([p[1] for p in starts], [0.5, 3.5, 6.5])
    with pytest.raises(ValueError, match="no lanes"):
        lawnmower(*_setup(path={"n_robots": 12}), robot=11)


def test_revisit_waypoints_are_appended():
    field, cfg = _setup(path={"revisit_waypoints": [(5.0, 9.5), (5.0, 3.0)]})
    poses, _ = lawnmower(field, cfg)
    assert np.linalg.norm(poses[-1, :2] - [5.0, 3.0]) < 0.25


def test_frame_times_include_the_end():
    np.testing.assert_allclose(frame_times(1.0, 2.0, 10.0), [10.0, 10.5, 11.0])
