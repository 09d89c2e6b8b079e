"""benchmarks/real_statistics.py measures what a simulated log was given: the depth model's
range scale, the bearing offset, the misreads, the odometry's clock offset and turn scale,
and the blind gaps, each within its sampling error."""

import numpy as np
import pytest

from agrislam.sim.arena import ArenaSimulator
from agrislam.sim.arena_config import ArenaConfig
from benchmark_module import load_benchmark
from quiet_arena import QUIET_ODOMETRY

EFFECTS = {
    "odometry": {
        **QUIET_ODOMETRY,  # the lag is found to the step on clean odometry
        "effects": {"clock_offset_s": 0.4, "turn_scale_spread": 0.1},
    },
    "camera": {
        "effects": {
            "range_scale": 1.05,
            "range_scale_spread": 0.0,
            "off_axis_depth": 1.0,
            "bearing_offset_spread": 0.0,
            "misread_rate": 0.01,
            "blind_per_minute": 0.0,
        }
    },
}


@pytest.fixture(scope="module")
def measured():
    b = load_benchmark("real_statistics")
    changes = {"seed": 2, "driving": {"duration_s": 400.0, "n_robots": 2}, **EFFECTS}
    records = list(ArenaSimulator(ArenaConfig.realistic(changes)).records())
    s = b.survey(records)
    return b, s, b.residuals(s)


def test_the_camera_statistics_find_the_depth_model_and_the_misreads(measured):
    b, _, res = measured
    stats = b.camera_statistics(res)
    good = np.abs(res.bearing_error) < b.MISREAD_RAD
    for scale, k in b.depth_model(res, good).values():
        assert scale == pytest.approx(1.05, abs=0.01) and k / scale == pytest.approx(1.0, abs=0.1)
    on_axis = float(stats["range err median, |b| 0-0.1 (m)"].split()[0])
    off_axis = float(stats["range err median, |b| >0.5 (m)"].split()[0])
    assert on_axis > 0.05 and off_axis < -0.1  # longer ahead, shorter at the edge
    share = float(stats["misread share (|bearing err| > 1 rad)"].split("%")[0]) / 100
    assert 0.003 < share < 0.012  # a misread of a landmark in a nearby direction is not seen


def test_the_odometry_clock_offset_is_found_with_its_sign(measured):
    b, s, _ = measured
    pairs = [(s.odometry[name], s.truth[name]) for name in s.truth]
    assert b.clock_offset(pairs) == pytest.approx(-0.4, abs=0.02)
    assert b.clock_offset(pairs[:1]) == pytest.approx(-0.4, abs=0.02)
    stats = b.odometry_statistics(s)
    assert stats["odometry clock lag, all robots (s)"] == "-0.40"
    # each robot turns by a scale of its own, drawn with a 10 % spread
    scales = [float(v) for v in stats["odometry turn scale per robot"].split()]
    assert np.std(scales) > 0.01


def test_gaps_count_the_stretches_without_a_sighting(measured):
    b, s, _ = measured
    s.frames = {name: np.array([10.0, 50.0, 55.0]) for name in s.odometry}
    stats = b.gap_statistics(s)
    assert stats["gaps > 30 s per robot"] == "2.0"  # 10 -> 50 and 55 -> the end at 400 s
    assert stats["longest gap per robot (s)"] == "345 345"
