"""`map.geojson` (RFC 7946): the plants as WGS84 points and the trajectories as lines, for
QGIS, farm-management software or a web map. PROJ turns the map frame's metres (east-north
at the anchor, turned `yaw_deg`) into degrees (geometry/geodesy.py)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from agrislam.geometry.geodesy import MapFrame, check_anchor
from agrislam.io.sinks.columns import object_columns
from agrislam.records import Anchor
from agrislam.snapshot import MapSnapshot

DEGREE_DECIMALS = 8  # 1e-8 deg: 1.1 mm of latitude
TRAJECTORY_SOURCES = {"optimised": "trajectories", "dead_reckoning": "dead_reckoning"}


def map_to_lonlat(xy: np.ndarray, anchor: Anchor) -> np.ndarray:
    """(k, 2) map-frame metres -> (k, 2) WGS84 longitude, latitude in degrees (PROJ's
    topocentric frame at the anchor, geometry/geodesy.py)."""
    return MapFrame(anchor).to_wgs84(xy)[:, :2]


CHUNK = 4096  # objects turned into JSON values at a time: no list per column of the map


def geojson_dict(snapshot: MapSnapshot) -> dict[str, Any]:
    """The FeatureCollection: one Point per object, one LineString per robot trajectory."""
    return {"type": "FeatureCollection", "features": list(features(snapshot))}


def features(snapshot: MapSnapshot) -> Iterator[dict[str, Any]]:
    """The FeatureCollection's features one by one: the objects' Points (their values
    converted a chunk of objects at a time), then each trajectory's LineString. A map
    without a (valid) anchor is a ValueError here, before the first feature."""
    anchor = snapshot.anchor
    if anchor is None:
        raise ValueError(
            "the map has no anchor (meta.anchor: WGS84 lat/lon of the map origin), so it "
            "cannot be placed on the globe; write objects.csv instead or add an anchor"
        )
    check_anchor(anchor)
    return _features(snapshot, anchor)


def _features(snapshot: MapSnapshot, anchor: Anchor) -> Iterator[dict[str, Any]]:
    columns = object_columns(snapshot, distributions=False)
    lonlat = np.round(
        map_to_lonlat(np.column_stack([columns["x"], columns["y"]]), anchor), DEGREE_DECIMALS
    )
    properties = {
        name: col
        for name, col in columns.items()
        if name not in ("x", "y", "cov_xx", "cov_xy", "cov_yy")
    }
    properties["sigma_m"] = position_sigma(snapshot.objects.cov)
    names = list(properties)
    for start in range(0, len(lonlat), CHUNK):
        part = slice(start, start + CHUNK)
        values = [_json_values(properties[name][part]) for name in names]
        for coords, props in zip(lonlat[part].tolist(), zip(*values, strict=True), strict=True):
            yield {
                "type": "Feature",
                "id": props[0],
                "geometry": {"type": "Point", "coordinates": coords},
                "properties": {"kind": "object", **dict(zip(names, props, strict=True))},
            }
    for source, attr in TRAJECTORY_SOURCES.items():
        for traj in getattr(snapshot, attr).values():
            poses = np.asarray(traj.poses, dtype=float).reshape(-1, 3)
            if len(poses) < 2:  # RFC 7946 3.1.4: a LineString has two or more positions
                continue
            line = np.round(map_to_lonlat(poses[:, :2], anchor), DEGREE_DECIMALS)
            yield {
                "type": "Feature",
                "geometry": {"type": "LineString", "coordinates": line.tolist()},
                "properties": {
                    "kind": "trajectory",
                    "robot": traj.robot,
                    "source": source,
                    "t_start": float(traj.t[0]),
                    "t_end": float(traj.t[-1]),
                },
            }


def write_geojson(snapshot: MapSnapshot, path: str | Path) -> Path:
    """Write `map.geojson` (RFC 7946, WGS84 lon/lat) feature by feature: the same text
    as `json.dumps(geojson_dict(snapshot))`, without the whole collection in memory; the
    snapshot must have an anchor."""
    path, stream = Path(path), features(snapshot)
    with path.open("w", encoding="utf-8") as out:
        out.write('{"type":"FeatureCollection","features":[')
        for n, feature in enumerate(stream):
            out.write(
                ("," if n else "") + json.dumps(feature, allow_nan=False, separators=(",", ":"))
            )
        out.write("]}\n")
    return path


def position_sigma(cov: np.ndarray) -> np.ndarray:
    """Standard deviation along the least certain direction: sqrt of the largest eigenvalue
    of each 2x2 position covariance, m."""
    cov = np.asarray(cov, dtype=float).reshape(-1, 2, 2)
    a, b, d = cov[:, 0, 0], 0.5 * (cov[:, 0, 1] + cov[:, 1, 0]), cov[:, 1, 1]
    return np.sqrt(0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b**2))


def _json_values(column: np.ndarray) -> list[Any]:
    """Plain JSON values; NaN and infinities (not JSON) become null."""
    values = column.tolist()
    if column.dtype.kind == "f" and not np.all(np.isfinite(column)):
        bad = ~np.isfinite(column)
        values = [None if b else v for v, b in zip(values, bad.tolist(), strict=True)]
    return values
