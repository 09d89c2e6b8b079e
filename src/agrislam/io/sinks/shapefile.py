"""`prescription_shp.zip`: the weeds as a spot-spraying prescription in a zipped ESRI
shapefile (points in WGS84 with the rate in l/ha), the way farm-management software
imports one."""

from __future__ import annotations

import tempfile
import zipfile
from pathlib import Path

import numpy as np
import shapely

from agrislam.config import OutputsConfig
from agrislam.io.sinks.geo_layers import Layer, map_frame, place, weeds, write_layer
from agrislam.snapshot import MapSnapshot

LAYER = "prescription"


def write_shapefile(snapshot: MapSnapshot, path: str | Path, cfg: OutputsConfig) -> Path:
    """Write the zip (prescription.shp, .shx, .dbf, .prj, .cpg); needs an anchor and a
    schema that tells weeds (outputs.weed_attribute)."""
    path, frame = Path(path), map_frame(snapshot)
    treated = weeds(snapshot, cfg)
    coords = place(frame, treated.xy, "wgs84")
    columns = {
        "ID": np.asarray(treated.ids, dtype=np.int64),
        "P_WEED": treated.p,
        "RATE": np.full(len(treated.ids), cfg.rate_l_ha),
    }
    layer = Layer(LAYER, shapely.to_wkb(shapely.points(coords)), columns, "Point", 4326)
    with tempfile.TemporaryDirectory() as tmp:
        write_layer(Path(tmp) / f"{LAYER}.shp", layer, LAYER, "ESRI Shapefile", append=False)
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
            for part in sorted(Path(tmp).iterdir()):
                archive.write(part, part.name)
    return path
