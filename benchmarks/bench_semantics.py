"""Benchmark of the semantic belief engine at field scale.

    python benchmarks/bench_semantics.py [--objects 100000] [--frames 300] [--repeats 15]

Prints, as medians over repeats:
  1. one frame of 20 detections' updates (3 attributes each) on a 100,000-object table
     (target < 1 ms), with and without growth time models;
  2. h for every object and the interest surface over the field (target < 50 ms);
and the same work done the straightforward way (one Python dict per object, per-object
loops, a per-object stencil for the surface) so the ratio means something.

The field: 100,000 plants are one hectare of sugar beet, 200 rows 0.5 m apart with a plant
every 0.2 m (positions jittered by 2 cm), i.e. about 1e6 surface cells at 0.1 m.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import numpy as np

from agrislam.config import SECONDS_PER_DAY, FieldSchema, SemanticsConfig
from agrislam.records import ContinuousMeasurement, DiscreteMeasurement
from agrislam.semantics import BeliefTable, interest_surface

DETECTIONS_PER_FRAME = 20
FRAME_DT_S = 0.1

GROWING = {
    "attributes": {
        "type": {"kind": "discrete", "values": ["crop", "weed"]},
        "size": {
            "kind": "discrete",
            "values": ["small", "medium", "big"],
            "time_model": {"rate_per_day": 0.04, "l_max": 0.6, "process_noise": 0.01},
        },
        "length": {
            "kind": "continuous",
            "min": 0.0,
            "max": 0.6,
            "time_model": {"rate_per_day": 0.04, "l_max": 0.6, "variance_per_day": 1e-5},
        },
    }
}


def median_ms(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def field_positions(n: int, rng: np.random.Generator) -> np.ndarray:
    per_row = 500
    rows = math.ceil(n / per_row)
    along = np.tile(np.arange(per_row) * 0.2, rows)[:n]
    across = np.repeat(np.arange(rows) * 0.5, per_row)[:n]
    return np.column_stack([along, across]) + rng.normal(0.0, 0.02, (n, 2))


def random_measurements(schema: FieldSchema, k: int, rng: np.random.Generator) -> list[dict]:
    """What a detector reports for k detections: every attribute of the schema."""
    out = []
    for _ in range(k):
        m = {}
        for name, spec in schema.discrete.items():
            value = spec.values[rng.integers(spec.n_values)]
            m[name] = DiscreteMeasurement(value, float(rng.uniform(0.3, 0.99)))
        for name, spec in schema.continuous.items():
            m[name] = ContinuousMeasurement(float(rng.uniform(spec.min, spec.max)), 1e-3)
        out.append(m)
    return out


def populated_table(schema: FieldSchema, n: int, rng: np.random.Generator) -> BeliefTable:
    """n objects, each measured 1-3 times over the first days of the survey."""
    table = BeliefTable(schema, SemanticsConfig())
    table.add(n, t=0.0)
    t = 0.0
    for _ in range(3):
        ids = rng.permutation(n)[: int(0.8 * n)]
        t += SECONDS_PER_DAY
        table.update(ids, random_measurements(schema, len(ids), rng), t)
    return table


# ----------------------------------------------------- the straightforward way (baseline)


def naive_table(table: BeliefTable) -> list[dict]:
    """The same beliefs as one Python dict per object."""
    discrete = table.discrete_beliefs()
    continuous = table.continuous_beliefs()
    schema = table.schema
    objects = []
    for i in range(len(table)):
        obj: dict = {"n_meas": int(table.n_meas[i]), "t": float(table.belief_time[i])}
        for name, p in discrete.items():
            obj[name] = dict(zip(schema.discrete[name].values, p[i].tolist(), strict=True))
        for name, (mean, var) in continuous.items():
            obj[name] = (float(mean[i]), float(var[i]))
        objects.append(obj)
    return objects


def naive_update(objects: list[dict], ids, measurements, schema: FieldSchema, t: float) -> None:
    """Bayes / Kalman per object and attribute in plain Python (no time model)."""
    for i, m in zip(ids, measurements, strict=True):
        obj = objects[i]
        for name, meas in m.items():
            if name in schema.discrete:
                belief = obj[name]
                n = len(belief)
                if meas.p < 1.0 / n:
                    continue
                post = {
                    v: q * (meas.p if v == meas.value else (1 - meas.p) / (n - 1))
                    for v, q in belief.items()
                }
                total = sum(post.values())
                obj[name] = {v: max(q / total, 1e-9) for v, q in post.items()}
            else:
                mean, var = obj[name]
                gain = var / (var + meas.var)
                obj[name] = (mean + gain * (meas.value - mean), var * meas.var / (var + meas.var))
        obj["n_meas"] += 1
        obj["t"] = t


def naive_interest(objects: list[dict], schema: FieldSchema, config: SemanticsConfig) -> list:
    h = []
    for obj in objects:
        terms = []
        for name in schema.discrete:
            belief = obj[name].values()
            terms.append(1 + sum(q * math.log(q) for q in belief if q > 0) / math.log(len(belief)))
        for name, spec in schema.continuous.items():
            _, var = obj[name]
            h_n = 0.5 * math.log(2 * math.pi * math.e * var / (spec.max - spec.min) ** 2)
            sig = 1 / (1 + math.exp(-config.heuristic_alpha * (h_n - config.heuristic_beta)))
            terms.append(1 - sig)
        n = obj["n_meas"]
        h.append(1 - n / (n + 1) * (sum(terms) / len(terms) if terms else 1.0))
    return h


def naive_surface(xy: np.ndarray, h: list, config: SemanticsConfig) -> np.ndarray:
    """Per object, add its Gaussian stencil (radius 3 sigma) to the grid."""
    res, sigma = config.surface_resolution, config.surface_sigma
    margin = 3 * sigma
    x0, y0 = xy[:, 0].min() - margin, xy[:, 1].min() - margin
    nx = int(np.ceil((xy[:, 0].max() + margin - x0) / res))
    ny = int(np.ceil((xy[:, 1].max() + margin - y0) / res))
    weight, knowledge = np.zeros((ny, nx)), np.zeros((ny, nx))
    r = int(np.ceil(3 * sigma / res))
    for (x, y), hk in zip(xy, h, strict=True):
        j, i = round((x - x0) / res - 0.5), round((y - y0) / res - 0.5)
        i0, i1, j0, j1 = max(i - r, 0), min(i + r + 1, ny), max(j - r, 0), min(j + r + 1, nx)
        cy = y0 + (np.arange(i0, i1) + 0.5) * res
        cx = x0 + (np.arange(j0, j1) + 0.5) * res
        w = np.exp(-((cy[:, None] - y) ** 2 + (cx[None, :] - x) ** 2) / (2 * sigma**2))
        weight[i0:i1, j0:j1] += w
        knowledge[i0:i1, j0:j1] += w * (1 - hk)
    return 1 - knowledge / np.maximum(weight, 1.0)


# ------------------------------------------------------------------------------- main


def bench_schema(label: str, schema: FieldSchema, args: argparse.Namespace) -> None:
    rng = np.random.default_rng(0)
    n = args.objects
    table = populated_table(schema, n, rng)
    config = table.config
    xy = field_positions(n, rng)
    t0 = float(table.belief_time.max())
    frames = [
        (
            rng.choice(n, DETECTIONS_PER_FRAME, replace=False),
            random_measurements(schema, DETECTIONS_PER_FRAME, rng),
            t0 + SECONDS_PER_DAY + k * FRAME_DT_S,  # a new survey a day later
        )
        for k in range(args.frames)
    ]
    objects = naive_table(table)

    times = []
    for ids, measurements, t in frames:
        start = time.perf_counter()
        table.update(ids, measurements, t)
        times.append(time.perf_counter() - start)
    update_ms = 1e3 * float(np.median(times))
    update_p95 = 1e3 * float(np.percentile(times, 95))
    naive_times = []
    for ids, measurements, t in frames:
        start = time.perf_counter()
        naive_update(objects, ids, measurements, schema, t)
        naive_times.append(time.perf_counter() - start)
    naive_update_ms = 1e3 * float(np.median(naive_times))

    t_now = frames[-1][2]
    h_ms = median_ms(lambda: table.interest(t=t_now), args.repeats)
    h = table.interest(t=t_now)
    surface_ms = median_ms(lambda: interest_surface(xy, h, config), args.repeats)
    surface = interest_surface(xy, h, config)
    both_ms = median_ms(lambda: interest_surface(xy, table.interest(t=t_now), config), args.repeats)
    naive_h_ms = median_ms(lambda: naive_interest(objects, schema, config), 1)
    naive_h = naive_interest(objects, schema, config)
    naive_surface_ms = median_ms(lambda: naive_surface(xy, naive_h, config), 1)

    attrs = ", ".join(
        f"{k}{'+growth' if v.time_model else ''}" for k, v in schema.attributes.items()
    )
    print(f"\n{label}: {n:,} objects; attributes {attrs}")
    print(
        f"  update, one frame of {DETECTIONS_PER_FRAME} detections: "
        f"{update_ms:.3f} ms median, {update_p95:.3f} ms p95 (target < 1 ms) "
        f"[{'ok' if update_ms < 1.0 else 'MISSED'}]   per-object dicts: {naive_update_ms:.3f} ms"
    )
    print(
        f"  h for all objects at t: {h_ms:.1f} ms;  surface {surface.values.shape[1]} x "
        f"{surface.values.shape[0]} cells of {surface.resolution} m: {surface_ms:.1f} ms"
    )
    print(
        f"  h + surface: {both_ms:.1f} ms median (target < 50 ms) "
        f"[{'ok' if both_ms < 50.0 else 'MISSED'}]   per-object loops: "
        f"{naive_h_ms + naive_surface_ms:.0f} ms (h {naive_h_ms:.0f} + surface "
        f"{naive_surface_ms:.0f}), {(naive_h_ms + naive_surface_ms) / both_ms:.0f}x slower"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", type=int, default=100_000)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    bench_schema("crops and weeds (paper Table 2)", FieldSchema.preset("crops_weeds"), args)
    bench_schema(
        "growing: type, size and length with App. B time models",
        FieldSchema.model_validate(GROWING),
        args,
    )


if __name__ == "__main__":
    main()
