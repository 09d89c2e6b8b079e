"""report.png: a real PNG whose pixels follow the data, and robustness to missing parts."""

from __future__ import annotations

import dataclasses
import struct
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import to_rgba
from matplotlib.image import imread

from agrislam.config import COLOURS, FieldSchema
from agrislam.io.sinks import report
from agrislam.io.sinks.readouts import value_colours
from agrislam.io.sinks.report import (
    MAX_STEP_BINS,
    _headline,
    _marker_size,
    write_attribute_maps,
    write_report,
)
from agrislam.snapshot import MapSnapshot, ObjectMap

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
LOW_DPI = 50  # enough to check pixels, twice as fast to draw


def png_size(path: Path) -> tuple[int, int]:
    """Width and height from the IHDR chunk."""
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def one_colour(snapshot: MapSnapshot, colour: str) -> MapSnapshot:
    """Every plant certainly `colour`, and nothing else to draw in colour."""
    belief = np.full((len(snapshot.objects), len(COLOURS)), 1e-9)
    belief[:, COLOURS.index(colour)] = 1.0
    schema = FieldSchema.model_validate(
        {"attributes": {"colour": {"kind": "discrete", "values": COLOURS}}}
    )
    objects = dataclasses.replace(snapshot.objects, discrete={"colour": belief}, continuous={})
    return dataclasses.replace(snapshot, schema=schema, objects=objects)


def count_near(path: Path, rgb: tuple[float, float, float], tol: float = 0.12) -> int:
    image = imread(path)[..., :3]
    return int(np.sum(np.all(np.abs(image - np.asarray(rgb)) < tol, axis=-1)))


def test_report_is_a_sizeable_png(sample_snapshot, tmp_path):
    truth = {r: dataclasses.replace(t) for r, t in sample_snapshot.trajectories.items()}
    metrics = {"plants": {"mapped": 30, "missed": 0}, "size_accuracy": 0.967, "name": "demo"}
    path = write_report(sample_snapshot, tmp_path / "report.png", metrics=metrics, truth=truth)
    width, height = png_size(path)
    assert width >= 1200 and height >= 700
    assert path.stat().st_size > 50_000


def test_report_pixels_follow_the_data(sample_snapshot, tmp_path):
    yellow = write_report(one_colour(sample_snapshot, "yellow"), tmp_path / "y.png", dpi=LOW_DPI)
    blue = write_report(one_colour(sample_snapshot, "blue"), tmp_path / "b.png", dpi=LOW_DPI)
    # the colour attribute is drawn in the plants' actual colours
    assert count_near(yellow, (1.0, 1.0, 0.0)) > 250
    assert count_near(blue, (1.0, 1.0, 0.0)) < 30
    assert count_near(blue, (0.0, 0.0, 1.0)) > 250


@pytest.mark.parametrize(
    "parts",
    [
        {"schema": False, "anchor": False, "rows": False, "surface": False},
        # a long strip of a field (one column of panels), more steps than plotted points
        {"n_rows": 4, "per_row": 100, "n_steps": 1500, "surface": False},
    ],
)
def test_report_copes_with_missing_parts(snapshot_factory, parts, tmp_path):
    path = write_report(snapshot_factory(**parts), tmp_path / "report.png", dpi=LOW_DPI)
    assert png_size(path)[0] > 300


def test_report_of_an_empty_map_without_timings(sample_snapshot, tmp_path):
    empty = ObjectMap(
        ids=np.zeros(0, dtype=int),
        xy=np.zeros((0, 2)),
        cov=np.zeros((0, 2, 2)),
        n_meas=np.zeros(0, dtype=int),
        interest=np.zeros(0),
        row=np.zeros(0, dtype=int),
    )
    snap = MapSnapshot(schema=None, objects=empty, trajectories={}, dead_reckoning={})
    assert png_size(write_report(snap, tmp_path / "empty.png", dpi=LOW_DPI))[0] > 300
    snap = dataclasses.replace(sample_snapshot, objects=empty, interest_surface=None)
    assert png_size(write_report(snap, tmp_path / "no_plants.png", dpi=LOW_DPI))[0] > 300


def test_step_times_of_unequal_length_are_rejected(sample_snapshot, tmp_path):
    times = dict(sample_snapshot.step_times, maintain=np.zeros(3))
    with pytest.raises(ValueError, match="step_times: stages have different numbers of steps"):
        write_report(dataclasses.replace(sample_snapshot, step_times=times), tmp_path / "r.png")


def test_attribute_maps_one_panel_each(sample_snapshot, snapshot_factory, tmp_path):
    three = write_attribute_maps(sample_snapshot, tmp_path / "attributes.png", dpi=LOW_DPI)
    plain = snapshot_factory(schema=False)
    none = write_attribute_maps(plain, tmp_path / "plain.png", dpi=LOW_DPI)
    assert png_size(three)[0] > png_size(none)[0]  # three panels side by side against one


def test_value_colours(sample_snapshot):
    np.testing.assert_allclose(
        value_colours("colour", COLOURS, sample_snapshot)[[0, 6]],
        [to_rgba("blue"), to_rgba("yellow")],
    )
    health = value_colours("health", ["healthy", "diseased"], sample_snapshot)
    np.testing.assert_allclose(health, [to_rgba("tab:green"), to_rgba("tab:red")])
    sizes = value_colours("size", ["small", "medium", "big"], sample_snapshot)
    brightness = sizes[:, :3].sum(axis=1)
    assert np.all(np.diff(brightness) < 0)  # small light, big dark
    types = value_colours("type", ["A", "B"], sample_snapshot)
    np.testing.assert_allclose(types, [to_rgba("tab:blue"), to_rgba("tab:orange")])


def test_headline_reads_the_evaluation_metrics():
    metrics = {
        "objects": {
            "n_truth": 400,
            "mapped": 398,
            "duplicates": 2,
            "false_objects": 1,
            "position_rms": 0.04321,
        },
        "attributes": {
            "colour": {"accuracy": 0.9975, "n": 398},
            "size": {"accuracy": 0.96},
            "length": {"rms": 0.0412, "bias": 0.01},
        },
        "trajectory": {
            "optimised": {"rms_position": 0.0812},
            "dead_reckoning": {"rms_position": 0.5034},
        },
        "association": {"purity": 0.991, "completeness": 0.982},
        "timings": {"associate": {"p50_s": 0.01}},
    }
    assert _headline(metrics) == [
        "mapped 398/400 plants (99.5%)   ·   2 duplicates, 1 false   ·   position RMS 0.043 m",
        "association purity 99.1%, completeness 98.2%",
        "colour 99.8% right   ·   size 96.0% right   ·   length RMS 0.0412",
        "trajectory RMS 0.081 m (dead reckoning 0.503 m)",
    ]


def test_headline_of_other_metrics_lists_their_scalars():
    lines = _headline({"run": {"steps": 120, "p95_ms": 30.25}, "note": [1, 2], "seed": 3, "a": 1})
    assert lines == ["run.steps: 120   ·   run.p95_ms: 30.2   ·   seed: 3   ·   a: 1"]


@pytest.mark.slow
def test_report_of_100k_plants_and_10k_steps(snapshot_factory, tmp_path):
    big = snapshot_factory(n_rows=100, per_row=1000, n_steps=10_000)
    assert png_size(write_report(big, tmp_path / "report.png"))[0] > 1000


def test_a_larger_field_adds_no_artists_and_its_plants_are_rasterised(
    snapshot_factory, tmp_path, monkeypatch
):
    """What keeps a whole field's report quick to draw (the timing is in
    benchmarks/bench_outputs.py): each panel's plants are one rasterised collection, so ten
    times the plants and thirty times the steps draw the same artists, and the step times
    are binned to at most MAX_STEP_BINS points."""
    figures = []
    monkeypatch.setattr(report, "_save", lambda fig, path, dpi: figures.append(fig) or path)

    def artists(snapshot: MapSnapshot) -> list[Counter]:
        write_report(snapshot, tmp_path / "report.png")
        return [Counter(type(a).__name__ for a in ax.get_children()) for ax in figures[-1].axes]

    small = artists(snapshot_factory(n_rows=4, per_row=300, n_steps=100))
    large = artists(snapshot_factory(n_rows=40, per_row=300, n_steps=3000))
    assert large == small
    plants = [c for ax in figures[-1].axes for c in ax.collections if len(c.get_offsets()) > 1]
    assert len(plants) == 5 and all(len(c.get_offsets()) == 12_000 for c in plants)
    assert all(c.get_rasterized() for c in plants)
    *_, steps = figures[-1].axes
    assert all(len(c.get_paths()[0].vertices) <= 2 * MAX_STEP_BINS + 4 for c in steps.collections)


def test_a_few_trees_over_a_park_are_drawn_larger_than_a_dense_field():
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6))
    try:
        park = _marker_size(ax, (-90.0, 190.0, -40.0, 240.0), n=114)  # Victoria Park
        field = _marker_size(ax, (-1.0, 19.0, -1.0, 10.0), n=400)  # the default field
        huge = _marker_size(ax, (0.0, 450.0, 0.0, 40.0), n=10_000)
    finally:
        plt.close(fig)
    assert park >= 20.0  # a dot of 5 pt and more: its colour can be read
    assert 2.0 <= huge < park
    assert field >= 8.0


def test_a_large_interest_surface_is_drawn_as_block_means():
    from agrislam.io.sinks.report import coarsened

    values = np.arange(7 * 10, dtype=np.float32).reshape(7, 10)
    same, block = coarsened(values, most=10)
    assert block == 1 and same is values
    means, block = coarsened(values, most=4)
    assert block == 3 and means.shape == (3, 4)  # 7 x 10 cells padded to 9 x 12
    assert means[0, 0] == values[:3, :3].mean()
    assert means[2, 3] == values[6, 9]  # the corner block holds the edge value only
    assert means.dtype == np.float32
