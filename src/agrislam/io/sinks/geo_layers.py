"""The map as GIS layers: plants, tracks and rows as geometries in WGS84 or the anchor's UTM
zone with their attribute columns, and the weeds a prescription treats. A helper of the
GeoPackage, shapefile and ISOXML sinks, not a sink: it writes nothing."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyogrio.raw
import shapely

from agrislam.config import OutputsConfig
from agrislam.geometry.geodesy import MapFrame
from agrislam.io.sinks.columns import TRAJECTORY_SOURCES, object_columns
from agrislam.io.sinks.readouts import discrete_columns
from agrislam.snapshot import MapSnapshot

CRS = ("wgs84", "utm")


@dataclass(frozen=True, slots=True)
class Layer:
    """Geometries (WKB) with their columns (name -> array), in EPSG `epsg`."""

    name: str
    geometry: np.ndarray
    columns: dict[str, np.ndarray]
    geometry_type: str
    epsg: int


def write_layer(path: Path, layer: Layer, name: str, driver: str, append: bool) -> None:
    """One layer of geometries and columns into a GDAL vector file."""
    names = list(layer.columns)
    pyogrio.raw.write(
        path,
        layer.geometry,
        [layer.columns[n] for n in names],
        names,
        layer=name,
        driver=driver,
        geometry_type=layer.geometry_type,
        crs=f"EPSG:{layer.epsg}",
        append=append,
    )


def map_frame(snapshot: MapSnapshot) -> MapFrame:
    """The snapshot's map frame on the globe; a ValueError if the map has no anchor."""
    if snapshot.anchor is None:
        raise ValueError(
            "the map has no anchor (meta.anchor or a GNSS fix), so it cannot be placed on "
            "the globe; write objects.csv instead or add an anchor"
        )
    return MapFrame(snapshot.anchor)


def place(frame: MapFrame, xy: np.ndarray, crs: str) -> np.ndarray:
    """(k, 2) map points as lon/lat (EPSG 4326) or UTM easting/northing (epsg_of)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return frame.to_utm(xy) if crs == "utm" else frame.to_wgs84(xy)[:, :2]


def plants(snapshot: MapSnapshot, frame: MapFrame, crs: str) -> Layer:
    """Every plant as a point with the columns of objects.csv (map x, y kept)."""
    columns = object_columns(snapshot)
    coords = place(frame, np.column_stack([columns["x"], columns["y"]]), crs)
    points = shapely.to_wkb(shapely.points(coords))
    return Layer("plants", points, columns, "Point", epsg_of(frame, crs))


def tracks(snapshot: MapSnapshot, frame: MapFrame, crs: str) -> Layer:
    """Each robot's optimised and dead-reckoned trajectory as a line."""
    lines, robot, source, t0, t1 = [], [], [], [], []
    for name, trajectories in zip(
        TRAJECTORY_SOURCES, (snapshot.trajectories, snapshot.dead_reckoning), strict=True
    ):
        for traj in trajectories.values():
            poses = np.asarray(traj.poses, dtype=float).reshape(-1, 3)
            if len(poses) < 2:
                continue
            lines.append(shapely.linestrings(place(frame, poses[:, :2], crs)))
            robot.append(traj.robot)
            source.append(name)
            t0.append(float(traj.t[0]))
            t1.append(float(traj.t[-1]))
    columns = {
        "robot": np.array(robot, dtype=object),
        "source": np.array(source, dtype=object),
        "t_start": np.array(t0),
        "t_end": np.array(t1),
    }
    return Layer(
        "tracks", shapely.to_wkb(np.array(lines)), columns, "LineString", epsg_of(frame, crs)
    )


def rows(snapshot: MapSnapshot, frame: MapFrame, crs: str) -> Layer:
    """Each fitted row (sec. 2.6.2) as a line across the extent of the plants."""
    lines, numbers = [], []
    fitted, xy = snapshot.rows, np.asarray(snapshot.objects.xy, dtype=float).reshape(-1, 2)
    if fitted is not None and len(xy):
        along = np.array([np.cos(fitted.angle), np.sin(fitted.angle)])
        normal = np.array([-along[1], along[0]])
        s = xy @ along
        for k, offset in enumerate(np.asarray(fitted.offsets, dtype=float).tolist()):
            ends = offset * normal + np.outer([s.min(), s.max()], along)
            lines.append(shapely.linestrings(place(frame, ends, crs)))
            numbers.append(k)
    geometry = shapely.to_wkb(np.array(lines, dtype=object)) if lines else np.empty(0, object)
    return Layer(
        "rows",
        geometry,
        {"row": np.array(numbers, dtype=np.int64)},
        "LineString",
        epsg_of(frame, crs),
    )


def epsg_of(frame: MapFrame, crs: str) -> int:
    return frame.utm_epsg if crs == "utm" else 4326


@dataclass(frozen=True, slots=True)
class Weeds:
    """The plants a prescription treats: ids, map xy, the probability each is a weed."""

    ids: np.ndarray
    xy: np.ndarray
    p: np.ndarray


def weeds(snapshot: MapSnapshot, cfg: OutputsConfig) -> Weeds:
    """Plants whose `weed_attribute` is `weed_value` with p >= `weed_min_p`; a ValueError
    naming the schema when it has no such attribute or value."""
    found = discrete_columns(snapshot).get(cfg.weed_attribute)
    if found is None or cfg.weed_value not in found[0]:
        raise ValueError(
            f"the map's schema has no attribute {cfg.weed_attribute!r} with value "
            f"{cfg.weed_value!r} (outputs.weed_attribute / weed_value): no weeds to treat"
        )
    values, belief = found
    p = belief[:, list(values).index(cfg.weed_value)]
    chosen = p >= cfg.weed_min_p
    xy = np.asarray(snapshot.objects.xy, dtype=float).reshape(-1, 2)[chosen]
    return Weeds(np.asarray(snapshot.objects.ids)[chosen], xy, p[chosen])
