"""benchmarks/bench_arena.py's scoring: the mean row a change is judged on."""

import numpy as np

from agrislam.records import Detection, Detections, TruthObject, TruthPose
from benchmark_module import load_benchmark


def test_the_mean_row_averages_each_figure_and_is_judged_like_a_seed():
    b = load_benchmark("bench_arena")

    def score(mapped, spurious, purity, first, last, attribute=None):
        return b.Score(
            mapped,
            17,
            spurious,
            2,
            purity,
            0.96,
            0.05,
            0.06,
            1.5,
            (2.0, first),
            (3.0, last),
            60.0,
            900.0,
            attribute,
            {"heading": 4.0},
        )

    mean = b.mean_score([score(17, 1, 0.96, 4.0, 5.0), score(16, 2, 0.94, 4.0, 7.0, 0.9)])
    assert (mean.mapped, mean.spurious, mean.purity) == (16.5, 1.5, 0.95)
    assert mean.first_ms == (2.0, 4.0) and mean.last_ms == (3.0, 6.0)
    assert mean.attribute is None and mean.noise is None  # not every seed has them
    assert mean.failures() == ["mapped"]  # p95 6.0 = 1.5 x 4.0 still passes
    row = b.cells("agrislam", "mean of 2", mean)
    assert row[1:5] == ["mean of 2", "16.5 / 17", "1.5", "2"]


def test_the_association_ceiling_gives_each_frame_its_likeliest_landmarks_one_to_one():
    """The ceiling knows the true pose and landmarks: a detection on its landmark counts
    right, one measured on the other landmark wrong, and two in one frame nearest the same
    landmark share the two out (the one nearer keeps it). Clutter is not counted."""
    b = load_benchmark("bench_arena")
    a, other = np.array([2.0, 0.0]), np.array([2.0, 0.4])  # 0.2 rad apart at 2 m

    def seen(xy, truth, nudge=0.0):
        return Detection(
            range=float(np.hypot(*xy)),
            bearing=float(np.arctan2(xy[1], xy[0])) + nudge,
            sigma_range=0.1,
            sigma_bearing=0.01,
            truth_id=truth,
        )

    records = [
        TruthObject("a", a),
        TruthObject("b", other),
        TruthPose(0.0, "r", np.zeros(3)),
        Detections(0.0, "r", (seen(a, "a"), seen(a, None, 0.05))),
        Detections(1.0, "r", (seen(a, "a"), seen(a, "b", 0.03))),  # b's nearer a than b
        Detections(2.0, "r", (seen(other, "a"),)),  # a confused with b
        Detections(3.0, "r", (seen(other, "b"),)),
    ]
    assert b.association_ceiling(records) == (0.8, 0.8)  # each nearest alone: 0.6, 0.6


def test_the_minute_table_gives_each_minutes_p95_and_its_dearest_stages():
    b = load_benchmark("bench_arena")
    t = np.arange(0.0, 180.0, 0.5)  # three minutes of steps, the last one slow in "optimise"
    optimise = np.where(t >= 120.0, 0.010, 0.001)
    times = {"associate": np.full(len(t), 0.002), "optimise": optimise, "place": np.zeros(len(t))}
    lines = b.minute_stages((t + 1000.0).tolist(), times, sum(times.values()), top=2)
    assert len(lines) == 3
    assert lines[0] == "minute 0: p95 3.0 ms (associate 2.0, optimise 1.0)"
    assert lines[2] == "minute 2: p95 12.0 ms (optimise 10.0, associate 2.0)"
