"""Rows (sec. 2.6.2): the least-squares row fit, the row tracker's nodes and constraints,
and their effect on a simulated survey (crops pulled onto their rows, weeds left alone)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agrislam.backend import RelativePosition, detection_covariance, make_backend
from agrislam.backend.graph import ROW_MEMBER, ROW_SPACING
from agrislam.config import RowsConfig, SlamConfig
from agrislam.estimation.rows import (
    RowTracker,
    ambiguity,
    fit_rows,
    lattice_offset,
    periodicity,
)
from agrislam.geometry.se2 import wrap_row_angle
from agrislam.records import FieldPrior
from benchmark_module import load_benchmark

ANGLE = math.radians(10.0)
NORMAL = np.array([-math.sin(ANGLE), math.cos(ANGLE)])
ALONG = np.array([math.cos(ANGLE), math.sin(ANGLE)])


def rows_of_points(n_rows=5, per_row=20, offset=0.3, noise=0.01, weeds=(), seed=0) -> np.ndarray:
    """Plants on rows at 10 deg, 1 m apart, the first at n . p = offset; weeds given as
    (along, across) pairs."""
    rng = np.random.default_rng(seed)
    s = np.tile(np.arange(per_row) * 0.45, n_rows)
    k = np.repeat(np.arange(n_rows), per_row)
    across = offset + k + rng.normal(0.0, noise, len(s))
    plants = s[:, None] * ALONG + across[:, None] * NORMAL
    extra = [a * ALONG + c * NORMAL for a, c in weeds]
    return np.vstack([plants, *extra]) if extra else plants


def test_periodicity_and_lattice_offset_by_hand():
    # projections 0 and 0.5 with spacing 1: e^0 + e^{i pi} = 0
    pts = np.array([[0.0, 0.0], [0.0, 0.5]])
    assert periodicity(pts, np.array([0.0]), 1.0)[0] == pytest.approx(0.0, abs=1e-12)
    on_rows = np.array([[0.0, 0.3], [1.0, 1.3], [5.0, 2.3]])
    assert periodicity(on_rows, np.array([0.0]), 1.0)[0] == pytest.approx(1.0)
    assert lattice_offset(np.array([0.3, 1.3, 2.3]), 1.0) == pytest.approx(0.3)
    assert lattice_offset(np.array([-0.2, 0.8]), 1.0) == pytest.approx(0.8)
    assert wrap_row_angle(math.pi + 0.1) == pytest.approx(0.1)


def test_fit_finds_angle_and_offset_and_ignores_weeds():
    weeds = [(1.0, 0.8), (3.0, 1.8), (5.0, 2.75), (2.0, 3.8)]  # between the rows
    angle, offset = fit_rows(rows_of_points(weeds=weeds), 1.0, angle0=None)
    assert math.degrees(angle) == pytest.approx(10.0, abs=0.05)
    assert math.remainder(offset - 0.3, 1.0) == pytest.approx(0.0, abs=0.01)


def test_given_angle_is_a_prior_or_fixed():
    points = rows_of_points()
    prior = ANGLE + math.radians(2.0)
    fixed, _ = fit_rows(points, 1.0, angle0=None, angle_prior=prior, angle_sigma=0.0)
    assert fixed == pytest.approx(prior)
    soft, _ = fit_rows(points, 1.0, angle0=None, angle_prior=prior, angle_sigma=math.radians(1))
    assert ANGLE < soft < prior  # pulled towards the data from the prior
    assert math.degrees(soft - ANGLE) < 0.1  # 100 points outweigh a 1 deg prior


def backend_with_objects(points: np.ndarray):
    """Each point an object seen (once, precisely) from a robot at the origin."""
    g = make_backend(SlamConfig(), RowsConfig())
    g.add_robot("r", np.zeros(3), np.array([1e-4, 1e-4, 1e-5]))
    for i, p in enumerate(points):
        g.add_object(i, p)
        g.add_observation("r", i, RelativePosition(p, detection_covariance(p, 0.005, 0.005)))
    g.update()
    return g


def test_tracker_adds_row_nodes_constraints_and_spacing():
    weeds = [(2.0, 1.8), (4.0, 2.75)]
    points = rows_of_points(n_rows=4, per_row=6, noise=0.0, weeds=weeds)
    g = backend_with_objects(points)
    tracker = RowTracker(RowsConfig(n_det_est=12, min_detections=1))
    assert tracker.lines() is None
    tracker.after_step(g, np.arange(len(points)), len(points), np.ones(len(points), int))
    lines = tracker.lines()
    assert math.degrees(lines.angle) == pytest.approx(10.0, abs=0.01)
    np.testing.assert_allclose(lines.offsets, 0.3 + np.arange(4), atol=1e-3)
    rows = tracker.row_of(np.arange(len(points)))
    np.testing.assert_array_equal(rows[:24], np.repeat(np.arange(4), 6))
    np.testing.assert_array_equal(rows[24:], [-1, -1])  # weeds between the rows
    kinds = [f.kind for f in g.graph.factors.values()]
    assert kinds.count(ROW_MEMBER) == 24
    assert kinds.count(ROW_SPACING) == 3  # between neighbouring rows only
    g.update()
    np.testing.assert_allclose(tracker.lines().offsets, 0.3 + np.arange(4), atol=1e-3)


def test_first_fit_waits_until_the_angle_is_unambiguous():
    # two plants of one row lie on a 1 m lattice at many angles: fitted then, the rows of a
    # cluttered survey locked 30 deg off the field's (seed 5, 50 % clutter)
    points = rows_of_points(n_rows=3, per_row=6, noise=0.0)
    two = points[[0, 13]]
    assert periodicity(two, np.radians([10.0, 58.5]), 1.0) == pytest.approx([1.0, 1.0], 0.01)
    assert ambiguity(two, ANGLE, 1.0) == pytest.approx(1.0, abs=0.01)
    assert ambiguity(points, ANGLE, 1.0) < 0.3  # three rows of six: one angle only
    ambiguous = RowTracker(RowsConfig(n_det_est=2, min_detections=1, min_fit_objects=2))
    few = RowTracker(RowsConfig(n_det_est=2, min_detections=1))  # min_fit_objects 10
    for tracker, first in ((ambiguous, [0, 13]), (few, np.arange(9))):
        g = backend_with_objects(points)
        seen = np.zeros(len(points), int)
        seen[first] = 1
        tracker.after_step(g, np.asarray(first), len(first), seen)
        assert tracker.lines() is None
        tracker.after_step(g, np.arange(9, len(points)), 100, np.ones(len(points), int))
        assert math.degrees(tracker.lines().angle) == pytest.approx(10.0, abs=0.01)
        # the objects of earlier steps join their rows at the first fit too
        assert np.all(tracker.row_of(np.arange(len(points))) >= 0)


def test_a_given_angle_the_plants_contradict_is_replaced_and_reported():
    """Rows at 10 deg, given at 100 deg (the meta's x and y swapped): the first fit finds
    the plants' angle and says so; one given about right is a prior, as before."""
    points = rows_of_points(n_rows=4, per_row=6, noise=0.0)
    said = {}
    for given in (100.0, 10.5):
        g = backend_with_objects(points)
        tracker = RowTracker(RowsConfig(n_det_est=12, min_detections=1, row_angle_deg=given))
        tracker.after_step(g, np.arange(len(points)), len(points), np.ones(len(points), int))
        assert math.degrees(tracker.lines().angle) == pytest.approx(10.0, abs=0.3)
        said[given] = list(tracker.issues)
    (replaced,) = said[100.0]
    assert replaced.startswith("row angle 100 deg given, but the plants lie in rows at about 10")
    assert said[10.5] == []


def test_meta_prior_sets_spacing_and_angle():
    tracker = RowTracker(RowsConfig())
    tracker.use_prior(FieldPrior(row_spacing=0.75, row_angle_deg=30.0))
    assert tracker.spacing == 0.75
    assert tracker.angle_prior == pytest.approx(math.radians(30.0))


# ------------------------------------------------------------------ simulated survey
def bench():
    return load_benchmark("bench_geometry")


@pytest.fixture(scope="module")
def survey_runs():
    b = bench()
    survey = b.make_survey(100, n_rows=4, weed_fraction=0.1)
    out = {}
    for rows in (False, True):
        g = make_backend(SlamConfig(), RowsConfig())
        tracker = RowTracker(RowsConfig()) if rows else None
        _, ids, complete, _ = b.drive(g, survey, tracker, float("inf"))
        assert complete
        out[rows] = (g, tracker, ids, b.positions(g, ids))
    return survey, out


def cross_row_error(survey, estimates, keys) -> float:
    err = [(estimates[k] - survey.truth[k]) @ survey.row_normal for k in keys]
    return float(np.sqrt(np.mean(np.square(err))))


def test_rows_cut_the_cross_row_error_of_crops(survey_runs):
    survey, runs = survey_runs
    crops = [k for k in runs[True][2] if k not in survey.weeds]
    off, on = (cross_row_error(survey, runs[r][3], crops) for r in (False, True))
    assert on < 0.7 * off


def test_weeds_off_the_rows_are_not_pulled_onto_them(survey_runs):
    survey, runs = survey_runs
    _, tracker, ids, estimates = runs[True]
    weeds = [k for k in ids if k in survey.weeds]
    assert len(weeds) >= 5
    assert np.all(tracker.row_of(np.array([ids[k] for k in weeds])) == -1)
    crops = np.array([ids[k] for k in ids if k not in survey.weeds])
    assert np.mean(tracker.row_of(crops) >= 0) > 0.95
    offsets = tracker.lines().offsets
    for k in weeds:  # off the rows, and as far off them as mapped without rows
        d_est, d_alone, d_true = (
            np.min(np.abs(xy[k] @ survey.row_normal - offsets))
            for xy in (estimates, runs[False][3], survey.truth)
        )
        assert d_est > RowsConfig().max_offset
        assert d_est == pytest.approx(d_alone, abs=0.05)
        assert d_true > RowsConfig().max_offset
    # and the rows did not move them: as far off their truth as without rows
    off, on = (cross_row_error(survey, runs[r][3], weeds) for r in (False, True))
    assert on < off + 0.02


def test_turning_a_row_replaces_its_constraints():
    points = rows_of_points(n_rows=2, per_row=4, noise=0.0)
    g = backend_with_objects(points)
    tracker = RowTracker(RowsConfig(n_det_est=2, min_detections=1, min_fit_objects=2))
    tracker.after_step(g, np.arange(len(points)), len(points), np.ones(len(points), int))
    before = sorted(f.value[0] for f in g.graph.factors.values() if f.kind == ROW_MEMBER)
    assert before == pytest.approx([ANGLE] * 8, abs=1e-3)
    g.set_row_angle(0, 0.0)
    g.update()
    angles = {
        (f.keys[0], round(float(f.value[0]), 6))
        for f in g.graph.factors.values()
        if f.kind in (ROW_MEMBER, ROW_SPACING)
    }
    rows = sorted({k for k, _ in angles})
    assert {a for k, a in angles if k == rows[0]} == {0.0}
    assert g.graph.rows[0].angle == 0.0
