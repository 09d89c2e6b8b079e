import numpy as np
import pytest

from agrislam.sim.config import SimConfig
from agrislam.sim.detector import Detector, confusion_weights, ray_covariance
from agrislam.sim.field import make_field

N = 2000


def _one_plant(**detector):
    cfg = SimConfig.model_validate(
        {"field": {"n_plants": 1, "n_rows": 1, "row_jitter": 0.0}, "detector": detector}
    )
    field = make_field(cfg, np.random.default_rng(0))
    return field, Detector(field, cfg.detector), cfg.detector


def _look(detector, field, r, bearing=0.0, n=N, seed=1):
    """Frames from a robot whose camera (0.3 m ahead of the base) sees the plant at range r."""
    heading = 0.4
    cam = field.xy[0] - r * np.array([np.cos(heading + bearing), np.sin(heading + bearing)])
    pose = np.array([*(cam - 0.3 * np.array([np.cos(heading), np.sin(heading)])), heading])
    rng = np.random.default_rng(seed)
    return [detector.frame(pose, rng) for _ in range(n)]


def _plant_dets(frames):
    return [d for f in frames for d in f if d.truth_id is not None]


def test_detection_probability_falls_with_range():
    field, det, _ = _one_plant(clutter_rate=0.0, double_detection_p=0.0)
    for r, expected in ((0.5, 0.95 - 0.2 * 0.5 / 2.5), (2.0, 0.95 - 0.2 * 2.0 / 2.5)):
        seen = np.mean([len(f) for f in _look(det, field, r)])
        assert seen == pytest.approx(expected, abs=0.025)
    assert det.p_detect(np.array([0.0, 2.5])).tolist() == pytest.approx([0.95, 0.75])


def test_nothing_outside_the_view_or_beyond_the_cut_off():
    field, det, _ = _one_plant(clutter_rate=0.0)
    assert not any(_look(det, field, 2.6, n=200))  # App. A: 2.5 m cut-off
    assert not any(_look(det, field, 0.2, n=200))  # below the image
    assert not any(_look(det, field, 1.0, bearing=np.deg2rad(50), n=200))  # 90 deg FOV
    assert any(_look(det, field, 1.0, bearing=np.deg2rad(40), n=200))


def test_depth_is_biased_towards_the_robot_and_noisier_far_away():
    field, det, _ = _one_plant(clutter_rate=0.0, double_detection_p=0.0)
    bias = 0.1 * field.length[0]  # mask averaging sees the near side (sec. 2.3)
    errors = {}
    for r in (0.8, 2.2):
        ds = _plant_dets(_look(det, field, r))
        ranges = np.array([np.hypot(*(d.xy - [0.3, 0.0])) for d in ds])
        errors[r] = ranges - r
        sd = 0.02 + 0.015 * r**2
        assert errors[r].mean() == pytest.approx(-bias, abs=4 * sd / np.sqrt(len(ds)))
        assert errors[r].std() == pytest.approx(sd, rel=0.1)
        # the reported covariance along the ray covers noise and bias, 1.5x
        d = ds[0]
        ray = (d.xy - [0.3, 0.0]) / np.linalg.norm(d.xy - [0.3, 0.0])
        assert ray @ d.cov @ ray == pytest.approx(1.5**2 * (sd**2 + bias**2), rel=0.05)
    assert errors[2.2].std() > 2 * errors[0.8].std()


def test_bearing_is_precise():
    field, det, _ = _one_plant(clutter_rate=0.0, double_detection_p=0.0)
    ds = _plant_dets(_look(det, field, 2.0, bearing=0.3))
    bearings = np.array([np.arctan2(*(d.xy - [0.3, 0.0])[::-1]) for d in ds])
    expected = np.hypot(0.01, np.arctan(0.01 / 2.0))  # bearing noise + centroid jitter
    assert bearings.std() == pytest.approx(expected, rel=0.1)
    assert bearings.mean() == pytest.approx(0.3, abs=0.002)


def test_size_is_confused_more_than_colour_and_p_is_calibrated():
    field, det, _ = _one_plant(clutter_rate=0.0, double_detection_p=0.0)
    schema = field.schema
    truth = {n: schema.discrete[n].values[field.discrete[n][0]] for n in ("colour", "size")}
    ds = _plant_dets(_look(det, field, 1.25, n=5000))
    acc = {}
    for name in ("colour", "size"):
        right = np.array([d.attributes[name].value == truth[name] for d in ds])
        p = np.array([d.attributes[name].p for d in ds])
        acc[name] = right.mean()
        # accuracy at half the cut-off is halfway between near and far
        near, far = {"colour": (0.97, 0.90), "size": (0.82, 0.65)}[name]
        assert right.mean() == pytest.approx((near + far) / 2, abs=0.015)
        # calibrated on average: the mean reported p matches the hit rate, also per p bin
        assert p.mean() == pytest.approx(right.mean(), abs=0.015)
        for lo in (0.6, 0.8):
            sel = (p >= lo) & (p < lo + 0.2)
            if sel.sum() > 300:
                assert right[sel].mean() == pytest.approx(p[sel].mean(), abs=0.06)
    assert acc["size"] < acc["colour"] - 0.1


def test_ray_covariance_is_the_rotated_diagonal():
    b = np.array([0.0, np.pi / 2, 0.3])
    cov = ray_covariance(b, np.array([0.2, 0.2, 0.2]), np.array([0.01, 0.01, 0.01]))
    np.testing.assert_allclose(cov[0], np.diag([0.04, 1e-4]))
    np.testing.assert_allclose(cov[1], np.diag([1e-4, 0.04]), atol=1e-15)
    rot = np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
    np.testing.assert_allclose(cov[2], rot @ np.diag([0.04, 1e-4]) @ rot.T)


def test_size_errors_fall_on_neighbouring_sizes():
    w = confusion_weights(3, ordinal=True)
    np.testing.assert_allclose(w, [[0, 1, 0.25], [1, 0, 1], [0.25, 1, 0]])
    np.testing.assert_allclose(confusion_weights(3, ordinal=False), 1 - np.eye(3))


def test_length_variance_grows_with_distance_squared():
    cfg = SimConfig.model_validate(
        {
            "schema": "colour_length",
            # long enough that no measurement is clipped at length 0
            "field": {"n_plants": 1, "n_rows": 1, "length_range": (0.45, 0.5)},
            "detector": {"clutter_rate": 0.0, "double_detection_p": 0.0},
        }
    )
    field = make_field(cfg, np.random.default_rng(0))
    det = Detector(field, cfg.detector)
    for r in (0.5, 2.0):
        ds = _plant_dets(_look(det, field, r))
        values = np.array([d.attributes["length"].value for d in ds])
        var = ds[0].attributes["length"].var
        assert var == pytest.approx((0.02 + 0.03 * r) ** 2)
        assert values.mean() == pytest.approx(field.length[0], abs=0.01)
        assert values.var() == pytest.approx(var, rel=0.1)


def test_false_detections_clutter_and_doubles():
    field, det, _ = _one_plant(clutter_rate=0.2, double_detection_p=0.3)
    frames = _look(det, field, 1.0)
    clutter = [d for f in frames for d in f if d.truth_id is None]
    assert len(clutter) / N == pytest.approx(0.2, abs=0.03)
    for d in clutter:
        r = np.hypot(*(d.xy - [0.3, 0.0]))
        assert r <= 2.5 + 0.6  # anywhere in view (plus depth noise)
    twice = np.mean([sum(d.truth_id is not None for d in f) == 2 for f in frames])
    assert twice == pytest.approx(0.3 * (0.95 - 0.2 * 1.0 / 2.5), abs=0.03)


def test_combined_label_and_range_bearing_output():
    field, det, _ = _one_plant(emit_label=True, geometry="range_bearing", clutter_rate=0.0)
    d = _plant_dets(_look(det, field, 1.0, n=5))[0]
    assert d.xy is None and d.range == pytest.approx(1.3, abs=0.3) and d.sigma_bearing > 0
    colour, size = d.label.split("_")
    assert colour in field.schema.discrete["colour"].values and size in ("small", "medium", "big")
    assert 0 < d.label_p < 1 and d.attributes == {}


def test_same_rng_same_frames():
    field, det, _ = _one_plant()
    a = _look(det, field, 1.0, n=20, seed=5)
    b = _look(det, field, 1.0, n=20, seed=5)
    assert [[(d.truth_id, d.xy.tolist()) for d in f] for f in a] == [
        [(d.truth_id, d.xy.tolist()) for d in f] for f in b
    ]
