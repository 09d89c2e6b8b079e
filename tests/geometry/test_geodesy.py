"""The map frame on the globe (geometry/geodesy.py): round trips, the yaw turn, covariances
turned with it, UTM zones."""

from __future__ import annotations

import numpy as np
import pytest

from agrislam.geometry.geodesy import MapFrame, utm_epsg
from agrislam.records import Anchor


def test_map_points_round_trip_through_wgs84() -> None:
    frame = MapFrame(Anchor(51.4488, 5.4905, 20.0, 30.0))
    xy = np.array([[0.0, 0.0], [120.0, -35.5], [-800.0, 950.0]])
    lla = frame.to_wgs84(xy, up=[0.0, 1.0, -2.0])
    back = frame.to_map(lla[:, 1], lla[:, 0], lla[:, 2])
    np.testing.assert_allclose(back[:, :2], xy, atol=1e-6)
    np.testing.assert_allclose(back[:, 2], [0.0, 1.0, -2.0], atol=1e-6)
    np.testing.assert_allclose(lla[0], [5.4905, 51.4488, 20.0], atol=1e-9)


def test_the_yaw_turns_east_into_the_map_frame() -> None:
    plain = MapFrame(Anchor(51.0, 5.0, 0.0, 0.0))
    turned = MapFrame(Anchor(51.0, 5.0, 0.0, 90.0))  # map x points north
    lon, lat, h = plain.to_wgs84(np.array([[10.0, 0.0]]))[0]  # 10 m east
    np.testing.assert_allclose(turned.to_map(lat, lon, h)[0, :2], [0.0, -10.0], atol=1e-6)
    cov = turned.enu_to_map(np.diag([1.0, 4.0]))  # sure east, unsure north
    np.testing.assert_allclose(cov, np.diag([4.0, 1.0]), atol=1e-12)


@pytest.mark.parametrize(
    ("lat", "lon", "epsg"),
    [(51.4488, 5.4905, 32631), (-33.87, 151.21, 32756), (0.0, -180.0, 32601), (10.0, 180.0, 32660)],
)
def test_utm_zone_of_the_anchor(lat: float, lon: float, epsg: int) -> None:
    assert utm_epsg(lat, lon) == epsg


def test_a_pole_is_no_anchor() -> None:
    with pytest.raises(ValueError, match="not a WGS84 position"):
        MapFrame(Anchor(90.0, 0.0))
