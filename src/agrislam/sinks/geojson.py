"""`map.geojson` (RFC 7946): the plants as WGS84 points and the trajectories as lines, for
QGIS, farm-management software or a web map.

The map frame is a local east-north frame at the anchor, its x axis turned `yaw_deg`
from east towards north (spec/log-format.md "meta"). Map metres become degrees with
the meridian and prime-vertical radii of curvature of the WGS84 ellipsoid at the
anchor: a local tangent plane, good to well under a millimetre over a 100 m field.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from agrislam.records import Anchor
from agrislam.sinks.columns import object_columns
from agrislam.snapshot import MapSnapshot

WGS84_A = 6_378_137.0  # semi-major axis, m
WGS84_F = 1.0 / 298.257_223_563  # flattening
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared
DEGREE_DECIMALS = 8  # 1e-8 deg: 1.1 mm of latitude
TRAJECTORY_SOURCES = {"optimised": "trajectories", "dead_reckoning": "dead_reckoning"}


def radii_of_curvature(lat_deg: float) -> tuple[float, float]:
    """Meridian radius M and prime-vertical radius N of WGS84 at a geodetic latitude, m."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    w = math.sqrt(1.0 - WGS84_E2 * s2)
    return WGS84_A * (1.0 - WGS84_E2) / w**3, WGS84_A / w


def map_to_lonlat(xy: np.ndarray, anchor: Anchor) -> np.ndarray:
    """(k, 2) map-frame metres -> (k, 2) WGS84 longitude, latitude in degrees."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    yaw = math.radians(anchor.yaw_deg)
    c, s = math.cos(yaw), math.sin(yaw)
    east = c * xy[:, 0] - s * xy[:, 1]  # the map x axis points yaw_deg north of east
    north = s * xy[:, 0] + c * xy[:, 1]
    m, n = radii_of_curvature(anchor.lat)
    lat = anchor.lat + np.degrees(north / (m + anchor.h))
    lon = anchor.lon + np.degrees(east / ((n + anchor.h) * math.cos(math.radians(anchor.lat))))
    return np.column_stack([lon, lat])


def geojson_dict(snapshot: MapSnapshot) -> dict[str, Any]:
    """The FeatureCollection: one Point per object, one LineString per robot trajectory."""
    anchor = snapshot.anchor
    if anchor is None:
        raise ValueError(
            "the map has no anchor (meta.anchor: WGS84 lat/lon of the map origin), so it "
            "cannot be placed on the globe; write objects.csv instead or add an anchor"
        )
    if not (-90.0 < anchor.lat < 90.0 and -180.0 <= anchor.lon <= 180.0):
        raise ValueError(f"anchor lat/lon ({anchor.lat}, {anchor.lon}) is not a WGS84 position")
    columns = object_columns(snapshot, distributions=False)
    lonlat = np.round(
        map_to_lonlat(np.column_stack([columns["x"], columns["y"]]), anchor), DEGREE_DECIMALS
    )
    properties = {
        name: _json_values(col)
        for name, col in columns.items()
        if name not in ("x", "y", "cov_xx", "cov_xy", "cov_yy")
    }
    properties["sigma_m"] = _json_values(position_sigma(snapshot.objects.cov))
    names = list(properties)
    features = [
        {
            "type": "Feature",
            "id": props[0],
            "geometry": {"type": "Point", "coordinates": coords},
            "properties": {"kind": "object", **dict(zip(names, props, strict=True))},
        }
        for coords, props in zip(
            lonlat.tolist(), zip(*properties.values(), strict=True), strict=True
        )
    ]
    for source, attr in TRAJECTORY_SOURCES.items():
        for traj in getattr(snapshot, attr).values():
            poses = np.asarray(traj.poses, dtype=float).reshape(-1, 3)
            if len(poses) < 2:  # RFC 7946 3.1.4: a LineString has two or more positions
                continue
            line = np.round(map_to_lonlat(poses[:, :2], anchor), DEGREE_DECIMALS)
            features.append(
                {
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
            )
    return {"type": "FeatureCollection", "features": features}


def write_geojson(snapshot: MapSnapshot, path: str | Path) -> Path:
    """Write `map.geojson` (RFC 7946, WGS84 lon/lat); the snapshot must have an anchor."""
    path = Path(path)
    text = json.dumps(geojson_dict(snapshot), allow_nan=False, separators=(",", ":"))
    path.write_text(text + "\n", encoding="utf-8")
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
