"""`map.gpkg` (OGC GeoPackage, through pyogrio/GDAL): the plants, tracks and rows as layers
with their attributes as columns, in WGS84 (`plants`, `tracks`, `rows`) and in the UTM
zone of the anchor (`plants_utm`, ...), for QGIS, ArcGIS and farm-management software."""

from __future__ import annotations

from pathlib import Path

from agrislam.io.sinks.geo_layers import CRS, map_frame, plants, rows, tracks, write_layer
from agrislam.snapshot import MapSnapshot


def write_geopackage(snapshot: MapSnapshot, path: str | Path) -> Path:
    """Write every layer in both reference systems; the snapshot must have an anchor."""
    path, frame = Path(path), map_frame(snapshot)
    first = True
    for crs in CRS:
        for make in (plants, tracks, rows):
            layer = make(snapshot, frame, crs)
            name = layer.name if crs == "wgs84" else f"{layer.name}_{crs}"
            write_layer(path, layer, name, "GPKG", append=not first)
            first = False
    return path
