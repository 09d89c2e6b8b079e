"""The map frame on the globe (spec/log-format.md "meta": anchor): WGS84 to and from the map
frame, a local east-north-up frame at the anchor turned `yaw_deg` from east towards north,
and the anchor's UTM zone. PROJ does the geodesy; nothing is hand-written but the yaw turn."""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np
import pyproj

from agrislam.records import Anchor


def check_anchor(anchor: Anchor) -> None:
    """A ValueError unless the anchor is a WGS84 position off the poles."""
    if not (-90.0 < anchor.lat < 90.0 and -180.0 <= anchor.lon <= 180.0):
        raise ValueError(f"anchor lat/lon ({anchor.lat}, {anchor.lon}) is not a WGS84 position")


def utm_epsg(lat: float, lon: float) -> int:
    """EPSG code of the WGS84 UTM zone holding (lat, lon): 326zz north, 327zz south."""
    zone = min(int((lon + 180.0) // 6.0) + 1, 60)
    return (32600 if lat >= 0.0 else 32700) + zone


class MapFrame:
    """The map frame of an anchor: `to_map` and `to_wgs84` between (lat, lon, h) and
    map (x, y, up); `enu_to_map` turns east-north vectors and covariances."""

    def __init__(self, anchor: Anchor) -> None:
        check_anchor(anchor)
        self.anchor = anchor
        yaw = math.radians(anchor.yaw_deg)
        # map x axis yaw_deg north of east: map = R(-yaw) enu
        self._rot = np.array([[math.cos(yaw), math.sin(yaw)], [-math.sin(yaw), math.cos(yaw)]])
        topocentric = (
            "+proj=pipeline +step +proj=cart +ellps=WGS84 "
            f"+step +proj=topocentric +ellps=WGS84 +lat_0={anchor.lat!r} +lon_0={anchor.lon!r} "
            f"+h_0={anchor.h!r}"
        )
        self._enu = pyproj.Transformer.from_pipeline(topocentric)

    def to_map(self, lat: np.ndarray, lon: np.ndarray, h: np.ndarray) -> np.ndarray:
        """(k, 3) map x, y and height above the anchor's tangent plane, m."""
        lat, lon, h = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (lat, lon, h)))
        east, north, up = self._enu.transform(lon, lat, h)
        xy = np.column_stack([np.ravel(east), np.ravel(north)]) @ self._rot.T
        return np.column_stack([xy, np.ravel(up)])

    def to_wgs84(self, xy: np.ndarray, up: np.ndarray | float = 0.0) -> np.ndarray:
        """(k, 3) longitude, latitude (deg) and ellipsoidal height of map points."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        enu = xy @ self._rot  # R^T map
        up = np.broadcast_to(np.asarray(up, dtype=float), (len(xy),))
        lon, lat, h = self._enu.transform(enu[:, 0], enu[:, 1], up, direction="INVERSE")
        return np.column_stack([lon, lat, h])

    def enu_to_map(self, cov_en: np.ndarray) -> np.ndarray:
        """(..., 2, 2) east-north covariances in the map frame."""
        return self._rot @ cov_en @ self._rot.T

    @cached_property
    def utm_epsg(self) -> int:
        return utm_epsg(self.anchor.lat, self.anchor.lon)

    @cached_property
    def _utm(self) -> pyproj.Transformer:
        return pyproj.Transformer.from_crs(4326, self.utm_epsg, always_xy=True)

    def to_utm(self, xy: np.ndarray) -> np.ndarray:
        """(k, 2) easting, northing in the anchor's UTM zone (EPSG `utm_epsg`)."""
        lonlat = self.to_wgs84(xy)
        e, n = self._utm.transform(lonlat[:, 0], lonlat[:, 1])
        return np.column_stack([e, n])
