"""Issue 15: re-localisation in a saved map (and refusal in a wrong one), the prior's
GTSAM factor, the history tables written and read back, survey_start in the log."""

from __future__ import annotations

import numpy as np
import pytest

from agrislam.config import AgrislamConfig, RowsConfig, SeasonConfig, SlamConfig
from agrislam.geometry.backend import make_backend
from agrislam.geometry.graph import PRIOR_POINT
from agrislam.prior.relocalise import Relocaliser, cluster, rigid_fit
from agrislam.records import Meta
from agrislam.sinks.history import History, plant_rows, read_history, write_history
from agrislam.sinks.log_lines import record_to_json
from agrislam.sources.jsonl import _survey_start


def _field(seed: int) -> np.ndarray:
    """Rows 1 m apart of plants 0.4-0.5 m apart (the simulator's layout)."""
    rng = np.random.default_rng(seed)
    rows = [
        np.column_stack([np.cumsum(rng.uniform(0.4, 0.5, 40)), np.full(40, float(k))])
        for k in range(10)
    ]
    return np.vstack(rows) + rng.normal(0, 0.01, (400, 2))


def _seen_from(field: np.ndarray, pose: np.ndarray, rng) -> np.ndarray:
    """The plants within 2.5 m of x in [2, 16] on row lane 3.5, in the frame of `pose`."""
    near = (field[:, 0] > 2) & (field[:, 0] < 16) & (np.abs(field[:, 1] - 3.5) < 2.0)
    local = field[near]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = local - pose[:2]
    xy = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    return xy + rng.normal(0, 0.015, xy.shape)


def test_relocaliser_finds_the_place_despite_periodic_rows():
    field, rng = _field(1), np.random.default_rng(3)
    pose = np.array([3.0, 3.5, 0.3])
    local = _seen_from(field, pose, rng)
    reloc = Relocaliser(field, SeasonConfig())
    fix = reloc.locate(local, np.full(len(local), 3))
    assert fix.localised, fix.reason
    assert np.allclose(fix.transform[:2], pose[:2], atol=0.05)
    assert abs(fix.transform[2] - pose[2]) < 0.02


def test_relocaliser_refuses_another_field():
    local = _seen_from(_field(1), np.array([3.0, 3.5, 0.3]), np.random.default_rng(3))
    other = Relocaliser(_field(2), SeasonConfig()).locate(local, np.full(len(local), 3))
    assert not other.localised and other.reason.startswith("not localised yet")


def test_relocaliser_waits_for_enough_plants():
    fix = Relocaliser(_field(1), SeasonConfig()).locate(np.zeros((3, 2)), np.full(3, 5))
    assert not fix.localised and "needed" in fix.reason


def test_cluster_and_rigid_fit():
    xy = np.array([[0, 0], [0.05, 0], [1, 1], [1.02, 1.0], [3, 0]], float)
    means, counts, _ = cluster(xy, 0.1)
    assert sorted(counts.tolist()) == [1, 2, 2]
    src = np.random.default_rng(0).uniform(-3, 3, (10, 2))
    t = np.array([1.0, -2.0, 0.7])
    c, s = np.cos(t[2]), np.sin(t[2])
    dst = src @ np.array([[c, -s], [s, c]]).T + t[:2]
    assert np.allclose(rigid_fit(src, dst), t)


def test_prior_point_factor_holds_an_object_in_gtsam():
    backend = make_backend(SlamConfig(), RowsConfig(enabled=False))
    backend.add_robot("r", np.zeros(3), np.full(3, 0.01), 0.0)
    backend.add_object(5, np.array([1.0, 2.0]))
    backend.add_object_prior(5, np.array([1.0, 2.0]), np.diag([0.04, 0.09]))
    backend.update()
    assert any(f.kind == PRIOR_POINT for f in backend.graph.factors.values())
    assert np.allclose(backend.object_positions(np.array([5])), [[1.0, 2.0]])
    assert np.allclose(
        backend.object_covariances(np.array([5]))[0], np.diag([0.04, 0.09]), atol=1e-6
    )


def test_history_tables_round_trip(tmp_path):
    import sqlite3

    path = tmp_path / "map.sqlite"
    sqlite3.connect(path).close()
    rows = plant_rows(
        1,
        np.array([3, 4]),
        ["seen", "gone"],
        np.ones((2, 2)),
        np.tile(np.eye(2), (2, 1, 1)),
        np.array([5, 2]),
        np.array([0.1, 0.2]),
        np.array([np.nan, 0.97]),
        {"length": np.array([[0.2, 0.01], [0.3, 0.02]])},
    )
    write_history(path, History([(0, 100.0, 0, "{}"), (1, 700.0, 1, "{}")], rows))
    back = read_history(path)
    assert back.next_survey == 2 and back.t_abs() == 700.0
    gone = back.plant(4)[0]
    assert gone["status"] == "gone" and gone["p_gone"] == pytest.approx(0.97)
    assert gone["beliefs"]["length"] == [0.3, 0.02]


def test_survey_start_is_written_and_read_as_utc():
    line = record_to_json(Meta(survey_start=1_775_030_400.0))
    assert line["survey_start"] == "2026-04-01T08:00:00Z"
    assert _survey_start(line) == 1_775_030_400.0
    assert _survey_start({}) is None
    with pytest.raises(Exception, match="time zone"):
        _survey_start({"survey_start": "2026-04-01T08:00:00"})


def test_config_has_a_season_section():
    assert AgrislamConfig().season.max_ambiguity < 1.0
