"""Re-localisation in a saved map (and refusal in a wrong one), the prior's
GTSAM factor, the history tables written and read back, survey_start in the log."""

from __future__ import annotations

import json

import numpy as np
import pytest

from agrislam.backend import make_backend
from agrislam.backend.graph import PRIOR_POINT
from agrislam.config import AgrislamConfig, RowsConfig, SeasonConfig, SlamConfig
from agrislam.geometry import se2
from agrislam.geometry.view_area import in_robot_frames
from agrislam.io.sinks.history import History, plant_rows, read_history, write_history
from agrislam.io.sinks.log_lines import record_to_json
from agrislam.io.sources.jsonl import _survey_start
from agrislam.records import Meta
from agrislam.season.relocalise import Relocaliser, cluster, detection_spread, rigid_fit


def _field(seed: int) -> np.ndarray:
    """Rows 1 m apart of plants 0.4-0.5 m apart (the simulator's layout)."""
    rng = np.random.default_rng(seed)
    rows = [
        np.column_stack([np.cumsum(rng.uniform(0.4, 0.5, 40)), np.full(40, float(k))])
        for k in range(10)
    ]
    return np.vstack(rows) + rng.normal(0, 0.01, (400, 2))


def _seen_from(field: np.ndarray, pose: np.ndarray, rng, sd: float = 0.015) -> np.ndarray:
    """The plants within 2.5 m of x in [2, 16] on row lane 3.5, in the frame of `pose`,
    each a mean of detections off by `sd` per axis."""
    near = (field[:, 0] > 2) & (field[:, 0] < 16) & (np.abs(field[:, 1] - 3.5) < 2.0)
    local = field[near]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = local - pose[:2]
    xy = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    return xy + rng.normal(0, sd, xy.shape)


SPREAD = 3 * 0.015**2  # per-axis variance of one detection: plants of 3 off by 0.015 m


def test_relocaliser_finds_the_place_despite_periodic_rows():
    field, rng = _field(1), np.random.default_rng(3)
    pose = np.array([3.0, 3.5, 0.3])
    local = _seen_from(field, pose, rng)
    reloc = Relocaliser(field, SeasonConfig())
    fix = reloc.locate(local, np.full(len(local), 3), SPREAD)
    assert fix.localised, fix.reason
    assert np.allclose(fix.transform[:2], pose[:2], atol=0.05)
    assert abs(fix.transform[2] - pose[2]) < 0.02


def test_relocaliser_refuses_another_field():
    local = _seen_from(_field(1), np.array([3.0, 3.5, 0.3]), np.random.default_rng(3))
    other = Relocaliser(_field(2), SeasonConfig()).locate(local, np.full(len(local), 3), SPREAD)
    assert not other.localised and other.reason.startswith("not localised yet")


def test_relocaliser_fits_to_the_noise_it_predicts_and_never_to_another_field():
    """Saved plants off by 0.025 m per axis and first-frames plants by 0.024 m (5
    detections of 0.053 m), as in the simulated seasons: a right fit's residuals (0.05 m
    RMS) are then above the kernel's 0.04 m, and only their predicted spread may judge
    them; claimed far smaller, the same fit is refused, and another field always is."""
    rng = np.random.default_rng(5)
    truth, map_sd, det_sd, n_det = _field(1), 0.025, 0.053, 5
    saved = truth + rng.normal(0, map_sd, truth.shape)
    pose = np.array([6.0, 3.5, -0.4])
    local = _seen_from(truth, pose, rng, det_sd / np.sqrt(n_det))
    counts = np.full(len(local), n_det)
    reloc = Relocaliser(saved, SeasonConfig(), map_var=np.full(len(saved), map_sd**2))
    fix = reloc.locate(local, counts, det_sd**2)
    assert fix.localised, fix.reason
    assert np.allclose(fix.transform[:2], pose[:2], atol=0.05)
    overconfident = Relocaliser(saved, SeasonConfig()).locate(local, counts, 0.01**2)
    assert not overconfident.localised and "fits only" in overconfident.reason
    for seed in (2, 3, 4):
        other = Relocaliser(_field(seed), SeasonConfig(), map_var=np.full(400, map_sd**2))
        assert not other.locate(local, counts, det_sd**2).localised


def test_detection_spread_pools_the_scatter_about_each_plant():
    rng = np.random.default_rng(0)
    centres = np.repeat(np.arange(50.0)[:, None] * [1.0, 0.0], 8, axis=0)
    xy = centres + rng.normal(0, 0.03, centres.shape)
    means, counts, label = cluster(xy, 0.3)
    assert len(means) == 50
    assert np.sqrt(detection_spread(xy, means, counts, label)) == pytest.approx(0.03, rel=0.1)
    one = np.array([[0.0, 0.0], [5.0, 5.0]])
    assert detection_spread(one, *cluster(one, 0.1)) == 0.0


def test_relocaliser_waits_for_enough_plants():
    fix = Relocaliser(_field(1), SeasonConfig()).locate(np.zeros((3, 2)), np.full(3, 5))
    assert not fix.localised and "needed" in fix.reason


def test_cluster_and_rigid_fit():
    xy = np.array([[0, 0], [0.05, 0], [1, 1], [1.02, 1.0], [3, 0]], float)
    means, counts, _ = cluster(xy, 0.1)
    assert sorted(counts.tolist()) == [1, 2, 2]
    assert any(np.allclose(m, [1.01, 1.0]) for m in means)
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


def test_history_rows_are_made_as_read_in_parts(monkeypatch):
    """A whole field's rows are not held as tuples: they are made from the
    survey's arrays each time they are read, a part at a time, the same every time."""
    from agrislam.io.sinks import history

    n = 7
    rows = plant_rows(
        2,
        np.arange(n),
        ["seen"] * n,
        np.arange(2 * n, dtype=float).reshape(n, 2),
        np.tile(np.array([[1.0, 0.5], [0.5, 2.0]]), (n, 1, 1)),
        np.full(n, 3),
        np.linspace(0.0, 1.0, n),
        np.full(n, np.nan),
        {"size": np.full((n, 3), 1 / 3)},
    )
    whole = list(rows)
    monkeypatch.setattr(history, "ROWS_AT_ONCE", 3)
    assert list(rows) == whole and list(rows) == whole  # read again, in parts of 3
    assert len(whole) == n and whole[6][:10] == (6, 2, "seen", 12.0, 13.0, 1.0, 0.5, 2.0, 3, 1.0)
    assert whole[6][10] is None and json.loads(whole[6][11]) == {"size": [0.333333] * 3}


def test_survey_start_is_written_and_read_as_utc():
    line = record_to_json(Meta(survey_start=1_775_030_400.0))
    assert line["survey_start"] == "2026-04-01T08:00:00Z"
    assert _survey_start(line) == 1_775_030_400.0
    assert _survey_start({}) is None
    with pytest.raises(Exception, match="time zone"):
        _survey_start({"survey_start": "2026-04-01T08:00:00"})


def test_config_has_a_season_section():
    assert AgrislamConfig().advanced.season.max_ambiguity < 1.0


# ------------------------------------------------------------------ the prior in the world


def _prior_schema():
    from agrislam.config import FieldSchema

    growth = {"kind": "growth", "rate_per_day": 0.04, "l_max": 0.6, "variance_per_day": 1e-4}
    return FieldSchema.model_validate(
        {
            "attributes": {
                "size": {"kind": "discrete", "values": ["s", "m", "b"], "time_model": growth},
                "length": {"kind": "continuous", "min": 0.0, "max": 0.6, "time_model": growth},
            }
        }
    )


def _prior(t_abs: float = 1.7e9):
    from agrislam.season.prior_map import PriorMap

    ids = np.array([0, 2, 5])
    return PriorMap(
        schema=_prior_schema(),
        ids=ids,
        xy=np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.5]]),
        cov=np.tile(np.eye(2) * 0.01, (3, 1, 1)),
        n_meas=np.array([4, 5, 6]),
        discrete={"size": np.array([[0.8, 0.1, 0.1], [0.1, 0.8, 0.1], [0.2, 0.3, 0.5]])},
        continuous={"length": (np.array([0.1, 0.2, 0.3]), np.array([0.01, 0.01, 0.02]))},
        t_abs=t_abs,
    )


def test_world_takes_the_prior_with_ids_and_beliefs_carried_by_app_b():
    from agrislam.config import SECONDS_PER_DAY
    from agrislam.semantics.growth import grown_mean, grown_variance, transition_matrix
    from agrislam.snapshot import STATUS_ACTIVE
    from agrislam.world import WorldModel

    prior = _prior()
    world = WorldModel(AgrislamConfig())
    world.use_prior(prior)
    dt = 7 * SECONDS_PER_DAY
    world.configure(Meta(schema=prior.schema, survey_start=prior.t_abs + dt))
    assert world.active_ids().tolist() == [0, 2, 5]  # ids kept, rows between retired
    assert (world.objects.status[[1, 3, 4]] != STATUS_ACTIVE).all()
    model = prior.schema.discrete["size"].time_model
    a = transition_matrix(3, model, dt)
    assert np.allclose(world.beliefs.probabilities("size", [2], 0.0)[0], a @ [0.1, 0.8, 0.1])
    mean, var = world.beliefs.gaussian("length", [5], 0.0)
    assert mean[0] == pytest.approx(grown_mean(np.array(0.3), model, dt))
    assert var[0] == pytest.approx(grown_variance(np.array(0.02), model, dt))
    snap = world.snapshot(t=0.0, with_surface=False)
    assert np.allclose(snap.objects.xy, prior.xy)  # held plants answer from the saved map


def test_a_held_plant_enters_the_graph_with_its_saved_prior_when_seen():
    from agrislam.backend import RelativePosition
    from agrislam.season.prior_backend import PriorBackend

    prior = _prior()
    inner = make_backend(SlamConfig(), RowsConfig(enabled=False))
    backend = PriorBackend(inner, prior.ids, prior.xy, prior.cov)
    backend.add_robot("r", np.array([-1.0, 0.0, 0.0]), np.full(3, 0.01), 0.0)
    assert backend.held(np.array([0, 2])).all()
    z = RelativePosition(xy=np.array([2.0, 0.0]), cov=np.eye(2) * 1e-4)
    backend.add_observation("r", 2, z)
    backend.update()
    assert not backend.held(np.array([2]))[0] and backend.entered == {2}
    kinds = [f.kind for f in inner.graph.factors.values()]
    assert kinds.count(PRIOR_POINT) == 1
    assert np.allclose(
        backend.object_positions(np.array([2, 5])), [[1.0, 0.0], [2.0, 0.5]], atol=0.02
    )


def test_changes_by_the_binomial_posterior():
    from agrislam.season.changes import ViewArea, find_changes

    poses = np.column_stack([np.linspace(0, 10, 51), np.zeros(51), np.zeros(51)])
    area = ViewArea((0.3, 2.0), (-0.7, 0.7))
    saved = np.array([[5.0, 0.5], [6.0, 0.5], [7.0, -0.5], [5.0, 30.0]])
    seen = np.array([9, 1, 0, 0])  # there; one stray detection; none; never in view
    new = (np.array([10, 11]), np.array([[8.0, 0.3], [9.0, 0.2]]), np.array([8, 1]))
    there, stray = (np.flatnonzero(area.contains(in_robot_frames(poses, p))) for p in saved[:2])
    seen_from = (np.r_[there, stray[:1]], np.r_[np.zeros(len(there), dtype=int), 1])
    ch = find_changes(np.arange(4), saved, seen, new, poses, seen_from, area, SeasonConfig())
    assert ch.kept.tolist() == [0] and ch.gone.tolist() == [1, 2] and ch.unseen.tolist() == [3]
    assert (ch.p_gone > 0.95).all()
    assert ch.new.tolist() == [10] and ch.unconfirmed.tolist() == [11]


def _sightings_in_and_beyond_the_area(area, poses, xy, miss_every: int):
    """A detector that sees each plant in its in-area frames but every `miss_every`-th,
    and also in the frames just beyond the area's far edge (where the shrunk area does not
    count a view): (pose rows, plant rows)."""
    rows, plants = [], []
    for k, point in enumerate(xy):
        inside = np.flatnonzero(area.contains(in_robot_frames(poses, point)))
        seen = inside[np.arange(len(inside)) % miss_every != miss_every - 1]
        r = np.hypot(*(point[None, :] - poses[:, :2]).T)
        beyond = np.flatnonzero((r > area.range[1]) & (r < area.range[1] + 0.5))
        rows.append(np.r_[seen, beyond])
        plants.append(np.full(len(seen) + len(beyond), k))
    return np.concatenate(rows), np.concatenate(plants)


def test_the_detection_rate_counts_sightings_and_views_in_the_same_area():
    """Counted frame by frame in the same area, p_d is the detector's, a weed seen in 3 of its
    in-area frames stays and a removed plant with clear views is still gone (plants seen beyond
    the shrunk area once drove p_d to its clip and marked such a weed gone)."""
    from agrislam.season.changes import ViewArea, find_changes

    poses = np.column_stack([np.linspace(0, 30, 151), np.zeros(151), np.zeros(151)])
    area = ViewArea((0.3, 2.0), (-0.7, 0.7))
    plants = np.column_stack([np.arange(3.0, 25.0, 0.5), np.full(44, 0.5)])
    pose_row, plant_row = _sightings_in_and_beyond_the_area(area, poses, plants, 5)
    weed, removed = np.array([26.0, 0.5]), np.array([27.5, -0.5])
    weed_views = np.flatnonzero(area.contains(in_robot_frames(poses, weed)))
    assert len(weed_views) >= 6 and area.contains(in_robot_frames(poses, removed)).sum() >= 6
    pose_row = np.r_[pose_row, weed_views[:6:2]]  # the weed: 3 of its first 6 in-area frames
    plant_row = np.r_[plant_row, np.full(3, 44)]
    xy = np.vstack([plants, weed, removed])
    ids = np.arange(len(xy))
    seen = np.bincount(plant_row, minlength=len(xy))
    nothing = (np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros(0, dtype=np.int64))
    ch = find_changes(ids, xy, seen, nothing, poses, (pose_row, plant_row), area, SeasonConfig())
    assert ch.p_detect == pytest.approx(6 / 7, abs=0.02)  # 6 of 7 in-area frames, not 0.99
    assert ch.gone.tolist() == [45]  # the removed plant; the weed (44) is kept
    assert 44 in ch.kept.tolist()


def test_the_seen_area_is_shrunk_at_its_far_edge_and_sides_only():
    """The margin keeps views off the edges where the detection rate falls; the near edge
    (the highest rate, the views of headland turns) keeps its learned bound."""
    from agrislam.season.changes import ViewArea

    r, b = np.meshgrid(np.linspace(1.0, 2.5, 31), np.linspace(-0.6, 0.6, 25))
    robot_xy = np.column_stack([(r * np.cos(b)).ravel(), (r * np.sin(b)).ravel()])
    plain, shrunk = ViewArea.learned(robot_xy, 0.0), ViewArea.learned(robot_xy, 0.2)
    assert shrunk.range[0] == plain.range[0]
    assert shrunk.range[1] == pytest.approx(plain.range[1] - 0.2)
    assert shrunk.bearing[1] == pytest.approx(plain.bearing[1] - 0.2 / plain.range[1])
    assert shrunk.bearing[0] == pytest.approx(plain.bearing[0] + 0.2 / plain.range[1])


def test_the_back_end_tells_what_was_seen_from_where():
    from agrislam.backend import RelativePosition

    backend = make_backend(SlamConfig(), RowsConfig(enabled=False))
    backend.add_robot("a", np.zeros(3), np.full(3, 0.01), 0.0)
    backend.add_robot("b", np.array([0.0, 1.0, 0.0]), np.full(3, 0.01), 0.0)
    for k in range(3):
        backend.add_object(k, np.array([1.0 + k, 0.0]))
    z = RelativePosition(xy=np.array([1.0, 0.0]), cov=np.eye(2) * 1e-4)
    backend.add_observation("a", 0, z)
    backend.add_odometry("a", 1.0, np.array([1.0, 0.0, 0.0]), np.eye(3) * 1e-4)
    backend.add_observation("a", 1, z)
    backend.add_observation("b", 2, RelativePosition(xy=np.array([3.0, -1.0]), cov=z.cov))
    backend.update()
    backend.merge_objects(1, 2)
    poses, pose_row, object_id = backend.sightings()
    assert poses.shape == (3, 3)  # a's two poses, then b's one
    pairs = sorted(zip(pose_row.tolist(), object_id.tolist(), strict=True))
    assert pairs == [(0, 0), (1, 1), (2, 1)]  # 2's sighting follows it into 1
    assert np.allclose(poses[pose_row[object_id == 0][0]], [0.0, 0.0, 0.0], atol=0.01)


def test_season_simulator_removes_plants_adds_weeds_and_hides_the_start():
    from agrislam.sim.config import SimConfig
    from agrislam.sim.season import SeasonSimulator, season_config

    sim = SeasonSimulator(season_config(SimConfig(seed=3), [0, 7]), removed=0.1, weeds=5)
    before, after = set(sim.fields[0].ids), set(sim.fields[1].ids)
    assert 20 < len(before - after) < 70 and len(after - before) == 5
    assert (sim.fields[1].length[:10] >= 0).all()
    meta = next(iter(sim.day_records(1)))
    assert meta.robots == {} and meta.survey_start is not None
    assert sim.entry[1] > 0.0


def test_history_command_prints_surveys_and_a_plant(tmp_path):
    from typer.testing import CliRunner

    from agrislam.cli import app
    from agrislam.io.sinks.sqlite import save_map
    from agrislam.snapshot import MapSnapshot, ObjectMap

    schema = _prior_schema()
    snap = MapSnapshot(
        schema=schema,
        objects=ObjectMap(
            ids=np.array([3]),
            xy=np.zeros((1, 2)),
            cov=np.eye(2)[None],
            n_meas=np.array([2]),
            interest=np.zeros(1),
            row=np.array([-1]),
            discrete={"size": np.array([[0.1, 0.2, 0.7]])},
            continuous={"length": (np.array([0.3]), np.array([0.01]))},
        ),
        trajectories={},
        dead_reckoning={},
    )
    path = save_map(snap, tmp_path / "map.sqlite")
    beliefs = {"size": np.array([[0.1, 0.2, 0.7]]), "length": np.array([[0.3, 0.01]])}
    rows = [
        *plant_rows(
            0,
            np.array([3]),
            ["first"],
            np.zeros((1, 2)),
            np.eye(2)[None],
            np.array([1]),
            np.zeros(1),
            np.full(1, np.nan),
            beliefs,
        ),
        *plant_rows(
            1,
            np.array([3]),
            ["seen"],
            np.zeros((1, 2)),
            np.eye(2)[None],
            np.array([2]),
            np.zeros(1),
            np.full(1, np.nan),
            beliefs,
        ),
    ]
    write_history(path, History([(0, 0.0, 0, "{}"), (1, 7 * 86400.0, 1, "{}")], rows))
    runner = CliRunner()
    result = runner.invoke(app, ["history", str(path), "--plot", str(tmp_path / "h.png")])
    assert result.exit_code == 0, result.output
    assert "7.0" in result.output and (tmp_path / "h.png").stat().st_size > 10_000
    result = runner.invoke(app, ["history", str(path), "--plant", "3"])
    assert result.exit_code == 0 and "size b 0.70" in result.output


def test_an_emerged_weed_becomes_one_new_plant(tmp_path):
    """Weeds that emerged between two surveys are confirmed by their sightings as plants
    of the map, each one object, and reported new; nothing else is new."""
    from collections import Counter

    from agrislam.records import Detections
    from agrislam.run.pipeline import run_survey
    from agrislam.run.season_outputs import load_season
    from agrislam.sim.config import SimConfig
    from agrislam.sim.season import SeasonSimulator, season_config
    from agrislam.world import WorldModel

    cfg = SimConfig.model_validate({"seed": 2, "field": {"n_plants": 120}})
    sim = SeasonSimulator(season_config(cfg, [0, 7]), removed=0.0, weeds=4)
    run_survey(list(sim.day_records(0)), WorldModel(AgrislamConfig()), tmp_path / "d0")
    season = load_season(tmp_path / "d0" / "map.sqlite", AgrislamConfig())
    world, sightings = WorldModel(AgrislamConfig()), Counter()
    step = world.step

    def spy(frame: Detections):
        report = step(frame)
        ids = report.object_ids.tolist()
        sightings.update(zip((d.truth_id for d in frame.objects), ids, strict=True))
        return report

    world.step = spy
    run_survey(list(sim.day_records(1)), world, tmp_path / "d1", season=season)
    new = season.changes.new.tolist()
    owner = [
        Counter({t: n for (t, o), n in sightings.items() if o == obj}).most_common(1)[0][0]
        for obj in new
    ]
    seen = Counter()
    for (t, _), n in sightings.items():
        seen[t] += n
    weeds = {t for t, n in seen.items() if t and t.startswith("w") and n >= 3}
    assert sorted(owner) == sorted(weeds)  # each weed one new object, nothing else new
    assert not world.objects.tentative[new].any()
    assert world.stages.maintainer.existence.report()["confirmed"] >= len(weeds)


# ------------------------------------------------------------------ the gate, every robot


def _drive(name: str, start: np.ndarray, field: np.ndarray, t0: float, rng) -> list:
    """A robot driving straight ahead at 0.5 m/s for 20 s from `start`, odometry and a
    frame every 0.5 s: the plants 0.5-2.5 m ahead within 35 deg, in its frame, 0.03 m off."""
    from agrislam.records import Detection, Detections, Odometry

    out, step = [], np.array([0.25, 0.0, 0.0])
    for k in range(41):
        pose = se2.compose(start, np.array([0.25 * k, 0.0, 0.0]))
        t = t0 + 0.5 * k
        if k:
            out.append(Odometry(t=t, robot=name, delta=step, cov=np.diag([1e-4, 1e-4, 1e-5])))
        local = se2.to_robot_frame(pose, field)
        r, b = np.hypot(local[:, 0], local[:, 1]), np.arctan2(local[:, 1], local[:, 0])
        seen = local[(r > 0.5) & (r < 2.5) & (np.abs(b) < np.radians(35))]
        dets = [Detection(xy=xy + rng.normal(0, 0.03, 2), cov=np.eye(2) * 0.03**2) for xy in seen]
        out.append(Detections(t=t, robot=name, objects=dets, sensor="front"))
    return out


def test_every_robot_of_a_survey_is_relocalised_by_its_own_first_frames():
    """Two robots on lanes 3 m apart, driving opposite ways, the second starting later:
    the records are released with both start poses from their own fixes."""
    from agrislam.records import Odometry
    from agrislam.run.season import SeasonRun
    from agrislam.season.prior_map import PriorMap
    from agrislam.world import WorldModel

    field, rng = _field(1), np.random.default_rng(2)
    prior = PriorMap(
        schema=None,
        ids=np.arange(len(field)),
        xy=field,
        cov=np.tile(np.eye(2) * 0.02**2, (len(field), 1, 1)),
        n_meas=np.full(len(field), 5),
    )
    starts = {"r1": np.array([2.0, 3.5, 0.0]), "r2": np.array([16.0, 6.5, np.pi])}
    records = _drive("r1", starts["r1"], field, 0.0, rng)
    records += _drive("r2", starts["r2"], field, 3.0, rng)
    records = [Meta(), *sorted(records, key=lambda r: (r.t, not isinstance(r, Odometry)))]
    run = SeasonRun(prior, AgrislamConfig())
    out = list(run.gate(records, WorldModel(AgrislamConfig())))
    assert len(out) == len(records) and run.merged
    for name, start in starts.items():
        given = out[0].robots[name]
        assert np.allclose(given.pose[:2], start[:2], atol=0.1), name
        assert abs(se2.wrap_angle(given.pose[2] - start[2])) < 0.03, name
        assert run.robots[name].after <= 10.0
    assert set(run.summary()["robots"]) == {"r1", "r2"}
