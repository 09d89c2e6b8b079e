"""map.geojson: WGS84 placement checked against published numbers and an independent ECEF
conversion, yaw, RFC 7946 structure."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from agrislam.io.sinks import geojson
from agrislam.io.sinks.geojson import (
    geojson_dict,
    map_to_lonlat,
    position_sigma,
    write_geojson,
)
from agrislam.records import Anchor

A, E2 = 6_378_137.0, 0.006_694_379_990_14  # WGS84 semi-major axis and e^2 (NIMA TR8350.2)


def radii_of_curvature(lat_deg: float) -> tuple[float, float]:
    """Meridian and prime-vertical radii of WGS84 (to turn degrees into metres here)."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    w = math.sqrt(1.0 - E2 * s2)
    return A * (1.0 - E2) / w**3, A / w


def enu_to_geodetic(east: float, north: float, anchor: Anchor) -> tuple[float, float]:
    """Independent reference: the tangent-plane point -> ECEF -> geodetic (iterated)."""
    lat, lon = math.radians(anchor.lat), math.radians(anchor.lon)
    n = A / math.sqrt(1.0 - E2 * math.sin(lat) ** 2)
    origin = np.array(
        [
            (n + anchor.h) * math.cos(lat) * math.cos(lon),
            (n + anchor.h) * math.cos(lat) * math.sin(lon),
            (n * (1.0 - E2) + anchor.h) * math.sin(lat),
        ]
    )
    e_axis = np.array([-math.sin(lon), math.cos(lon), 0.0])
    n_axis = np.array(
        [-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)]
    )
    x, y, z = origin + east * e_axis + north * n_axis
    p = math.hypot(x, y)
    phi = math.atan2(z, p * (1.0 - E2))
    for _ in range(10):
        n_phi = A / math.sqrt(1.0 - E2 * math.sin(phi) ** 2)
        h = p / math.cos(phi) - n_phi
        phi = math.atan2(z, p * (1.0 - E2 * n_phi / (n_phi + h)))
    return math.degrees(math.atan2(y, x)), math.degrees(phi)


@pytest.mark.parametrize(("east", "north"), [(60.0, 0.0), (0.0, 60.0), (-45.0, 35.0)])
def test_offsets_from_the_anchor_land_within_millimetres(east, north):
    anchor = Anchor(lat=51.4488, lon=5.4905, h=20.0, yaw_deg=0.0)
    lon, lat = map_to_lonlat(np.array([[east, north]]), anchor)[0]
    ref_lon, ref_lat = enu_to_geodetic(east, north, anchor)
    m, n = radii_of_curvature(anchor.lat)
    d_north = math.radians(lat - ref_lat) * m
    d_east = math.radians(lon - ref_lon) * n * math.cos(math.radians(anchor.lat))
    assert abs(d_north) < 2e-3 and abs(d_east) < 2e-3, (d_east, d_north)


def test_one_metre_north_on_the_equator_by_hand():
    north, east = map_to_lonlat(np.array([[0.0, 1.0], [1.0, 0.0]]), Anchor(lat=0.0, lon=10.0))
    # 1 m of latitude at the equator: 180 / (pi * a (1 - e^2)) deg; of longitude 180 / (pi a)
    assert north[0] == 10.0
    assert north[1] == pytest.approx(1.0 / 6_335_439.327 * 180.0 / math.pi, rel=1e-9)
    assert east[0] == pytest.approx(10.0 + 180.0 / (math.pi * A), rel=1e-12)
    assert east[1] == 0.0


def test_yaw_turns_the_map_x_axis_from_east_towards_north():
    plain, turned = Anchor(lat=51.0, lon=5.0), Anchor(lat=51.0, lon=5.0, yaw_deg=90.0)
    # with the x axis pointing north, map (10, 0) is 10 m north and map (0, 10) is 10 m west
    np.testing.assert_allclose(
        map_to_lonlat(np.array([[10.0, 0.0], [0.0, 10.0]]), turned),
        map_to_lonlat(np.array([[0.0, 10.0], [-10.0, 0.0]]), plain),
        rtol=0,
        atol=1e-12,
    )
    yawed = Anchor(lat=51.0, lon=5.0, yaw_deg=30.0)
    expected = map_to_lonlat(np.array([[10.0 * math.cos(math.pi / 6), 5.0]]), plain)
    np.testing.assert_allclose(map_to_lonlat(np.array([[10.0, 0.0]]), yawed), expected, atol=1e-12)


def test_feature_collection_structure(sample_snapshot, tmp_path):
    path = write_geojson(sample_snapshot, tmp_path / "map.geojson")
    doc = json.loads(path.read_text(encoding="utf-8"))
    assert doc["type"] == "FeatureCollection" and "crs" not in doc
    points = [f for f in doc["features"] if f["geometry"]["type"] == "Point"]
    lines = [f for f in doc["features"] if f["geometry"]["type"] == "LineString"]
    objects = sample_snapshot.objects
    assert len(points) == len(objects) and len(lines) == 4
    assert [f["id"] for f in points] == objects.ids.tolist()
    first = points[0]
    lon, lat = first["geometry"]["coordinates"]  # RFC 7946: longitude first
    assert 5.49 < lon < 5.491 and 51.448 < lat < 51.449
    expected = map_to_lonlat(objects.xy[:1], sample_snapshot.anchor)[0]
    assert (lon, lat) == (round(expected[0], 8), round(expected[1], 8))
    props = first["properties"]
    colour = objects.discrete["colour"][0]
    assert props["kind"] == "object" and props["n_meas"] == int(objects.n_meas[0])
    assert props["colour_p"] == pytest.approx(colour.max())
    assert props["colour"] == sample_snapshot.schema.discrete["colour"].values[colour.argmax()]
    assert props["length"] == pytest.approx(objects.continuous["length"][0][0])
    assert {"size", "size_p", "interest", "sigma_m", "length_var"} <= set(props)
    assert "colour_blue" not in props  # full distributions live in objects.csv
    kinds = {(f["properties"]["robot"], f["properties"]["source"]) for f in lines}
    assert kinds == {(r, s) for r in ("spot", "husky") for s in ("optimised", "dead_reckoning")}
    spot = next(f for f in lines if f["properties"]["robot"] == "spot")
    assert len(spot["geometry"]["coordinates"]) == len(sample_snapshot.trajectories["spot"].t)


def test_no_anchor_is_a_clear_error(sample_snapshot, tmp_path):
    with pytest.raises(ValueError, match="no anchor"):
        write_geojson(dataclasses.replace(sample_snapshot, anchor=None), tmp_path / "m.geojson")


def test_nan_becomes_null_so_the_file_stays_json(sample_snapshot, tmp_path):
    interest = sample_snapshot.objects.interest.copy()
    interest[0] = np.nan
    snap = dataclasses.replace(
        sample_snapshot, objects=dataclasses.replace(sample_snapshot.objects, interest=interest)
    )
    text = write_geojson(snap, tmp_path / "m.geojson").read_text(encoding="utf-8")
    assert "NaN" not in text
    assert json.loads(text)["features"][0]["properties"]["interest"] is None


def test_position_sigma_is_the_largest_axis():
    cov = np.array([[[0.04, 0.0], [0.0, 0.01]], [[2e-4, 1e-4], [1e-4, 2e-4]]])
    # eigenvalues of the second: 2e-4 +- 1e-4
    np.testing.assert_allclose(position_sigma(cov), [0.2, math.sqrt(3e-4)], rtol=1e-12)


def test_written_feature_by_feature_is_the_whole_collection(sample_snapshot, tmp_path, monkeypatch):
    """The file is written feature by feature, the objects' values a chunk at a time (no
    list of 100,000 features): the same text as the whole collection dumped at once, also
    when a chunk boundary falls inside the objects."""
    monkeypatch.setattr(geojson, "CHUNK", 7)  # 30 objects: 5 chunks, the last partial
    text = write_geojson(sample_snapshot, tmp_path / "m.geojson").read_text(encoding="utf-8")
    whole = json.dumps(geojson_dict(sample_snapshot), allow_nan=False, separators=(",", ":"))
    assert text == whole + "\n"
    ids = [f.get("id") for f in json.loads(text)["features"]]
    assert ids[: len(sample_snapshot.objects)] == sample_snapshot.objects.ids.tolist()
    assert not (tmp_path / "none.geojson").exists()
    with pytest.raises(ValueError, match="no anchor"):  # before the file is opened
        write_geojson(dataclasses.replace(sample_snapshot, anchor=None), tmp_path / "none.geojson")
    assert not (tmp_path / "none.geojson").exists()
