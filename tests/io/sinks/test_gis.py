"""The farm's GIS formats, each read back: the GeoPackage and the shapefile with
pyogrio (every plant within 1 mm), the ISOXML TaskData with the isoxml library (its
treated grid cells are exactly the weeds' cells)."""

from __future__ import annotations

import dataclasses
import zipfile

import numpy as np
import pyogrio
import pyogrio.raw
import pytest
import shapely
from isoxml.converter.np_grid import to_numpy_array
from isoxml.util.isoxml_io import isoxml_from_path

from agrislam.config import COLOURS, OutputsConfig
from agrislam.geometry.geodesy import MapFrame
from agrislam.io.sinks.geopackage import write_geopackage
from agrislam.io.sinks.isoxml import MM3_PER_M2_PER_L_HA, write_isoxml
from agrislam.io.sinks.shapefile import write_shapefile

# "weeds" of the sample map: plants most likely of the first colour
WEEDS = OutputsConfig(weed_attribute="colour", weed_value=COLOURS[0], weed_min_p=0.3)


def read_points(path, layer: str | None = None) -> tuple[np.ndarray, dict]:
    meta, _, geometry, fields = pyogrio.raw.read(path, layer=layer)
    coords = shapely.get_coordinates(shapely.from_wkb(geometry))
    return coords, dict(zip(meta["fields"], fields, strict=True)) | {"crs": meta["crs"]}


def map_xy(snapshot, lonlat: np.ndarray) -> np.ndarray:
    return MapFrame(snapshot.anchor).to_map(lonlat[:, 1], lonlat[:, 0], snapshot.anchor.h)[:, :2]


def test_geopackage_layers_read_back_within_a_millimetre(sample_snapshot, tmp_path) -> None:
    path = write_geopackage(sample_snapshot, tmp_path / "map.gpkg")
    layers = {name for name, _ in pyogrio.list_layers(path)}
    assert layers == {"plants", "tracks", "rows", "plants_utm", "tracks_utm", "rows_utm"}
    lonlat, fields = read_points(path, "plants")
    assert fields["crs"] == "EPSG:4326"
    objects = sample_snapshot.objects
    np.testing.assert_array_equal(fields["id"], objects.ids)
    error = np.linalg.norm(map_xy(sample_snapshot, lonlat) - objects.xy, axis=1)
    assert error.max() < 1e-3
    np.testing.assert_allclose(fields["colour_p"], objects.discrete["colour"].max(axis=1))
    utm, fields = read_points(path, "plants_utm")
    frame = MapFrame(sample_snapshot.anchor)
    assert fields["crs"] == f"EPSG:{frame.utm_epsg}" == "EPSG:32631"
    assert np.linalg.norm(utm - frame.to_utm(objects.xy), axis=1).max() < 1e-3
    _, _, lines, track_fields = pyogrio.raw.read(path, layer="tracks")
    assert len(lines) == 4
    assert sorted(zip(*track_fields[:2], strict=True)) == sorted(
        (r, s) for r in ("spot", "husky") for s in ("optimised", "dead_reckoning")
    )
    _, _, rows, _ = pyogrio.raw.read(path, layer="rows")
    assert len(rows) == len(sample_snapshot.rows.offsets)


def test_shapefile_prescription_reads_back_from_the_zip(sample_snapshot, tmp_path) -> None:
    path = write_shapefile(sample_snapshot, tmp_path / "prescription_shp.zip", WEEDS)
    names = set(zipfile.ZipFile(path).namelist())
    assert {"prescription.shp", "prescription.shx", "prescription.dbf", "prescription.prj"} <= names
    lonlat, fields = read_points(f"/vsizip/{path}/prescription.shp")
    colour = sample_snapshot.objects.discrete["colour"]
    weeds = colour[:, 0] >= WEEDS.weed_min_p
    assert weeds.any() and not weeds.all()
    np.testing.assert_array_equal(fields["ID"], sample_snapshot.objects.ids[weeds])
    error = np.linalg.norm(
        map_xy(sample_snapshot, lonlat) - sample_snapshot.objects.xy[weeds], axis=1
    )
    assert error.max() < 1e-3
    np.testing.assert_allclose(fields["RATE"], WEEDS.rate_l_ha)


def test_isoxml_grid_cells_are_the_weeds(sample_snapshot, tmp_path) -> None:
    path = write_isoxml(sample_snapshot, tmp_path / "taskdata.zip", WEEDS)
    zipfile.ZipFile(path).extractall(tmp_path / "stick")  # a terminal's USB stick: TASKDATA/
    task_data, refs = isoxml_from_path(tmp_path / "stick" / "TASKDATA")
    (task,) = task_data.tasks
    (grid,) = task.grids
    zones = to_numpy_array(refs[grid.filename], grid)
    rates = {z.code: z.process_data_variables[0].process_data_value for z in task.treatment_zones}
    assert rates == {0: 0, 1: round(WEEDS.rate_l_ha * MM3_PER_M2_PER_L_HA / 0.01)}
    assert task.default_treatment_zone_code == task.out_of_field_treatment_zone_code == 0
    # every weed falls in a treated cell, and every treated cell holds a weed
    colour = sample_snapshot.objects.discrete["colour"]
    weeds = sample_snapshot.objects.xy[colour[:, 0] >= WEEDS.weed_min_p]
    lonlat = MapFrame(sample_snapshot.anchor).to_wgs84(weeds)[:, :2]
    row = np.floor((lonlat[:, 1] - float(grid.minimum_north_position)) / grid.cell_north_size)
    col = np.floor((lonlat[:, 0] - float(grid.minimum_east_position)) / grid.cell_east_size)
    cells = {(int(r), int(c)) for r, c in zip(row, col, strict=True)}
    treated = {tuple(rc) for rc in np.argwhere(zones == 1).tolist()}
    assert treated == cells
    # a cell is about outputs.cell_m on the ground
    assert grid.cell_north_size * 111_250 == pytest.approx(WEEDS.cell_m, rel=0.01)
    (field,) = task_data.partfields
    assert field.area > 0 and task.partfield_id_ref == field.id


def test_a_schema_without_weeds_is_a_clear_error(sample_snapshot, tmp_path) -> None:
    with pytest.raises(ValueError, match="no attribute 'type' with value 'weed'"):
        write_shapefile(sample_snapshot, tmp_path / "p.zip", OutputsConfig())
    with pytest.raises(ValueError, match="no anchor"):
        write_geopackage(dataclasses.replace(sample_snapshot, anchor=None), tmp_path / "m.gpkg")
