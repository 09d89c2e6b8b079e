"""benchmarks/bench_scale.py's step ratio: the smallest survey runs beside the
larger one, so that both are timed on the machine of the same moment."""

import numpy as np

from benchmark_module import load_benchmark
from paths import SRC


def test_the_small_survey_runs_over_and_over_beside_the_large_one():
    b = load_benchmark("bench_scale")
    alone = b.measure(40, 2, SRC, {})
    large, beside = b.measure_beside(200, 40, 2, SRC, {})
    assert large["plants"] == 200 and len(large["steps_ms"]) == large["frames"]
    rounds, rest = divmod(beside.size, alone["frames"])
    assert rounds >= 1 and rest == 0  # whole surveys only: the one cut short is not counted
    assert b.step_ratios(np.array([2.0, 4.0]), np.array([1.0, 2.0])) == (2.0, 2.0)
