"""`taskdata.zip`: an ISO 11783-10 (ISOXML v4) TaskData with the weeds as a treatment
prescription that ISOBUS terminals read, written with the `isoxml` library.

One task over a partfield (the plants' hull): a grid of type 1 in WGS84 whose cells of
`outputs.cell_m` hold treatment zone 1 (spray `outputs.rate_l_ha`) where a weed lies and
zone 0 (no spray) elsewhere; zone 0 also serves outside the field and when position is
lost. The grid's first cell is its south-west corner; rows run north, columns east."""

from __future__ import annotations

from decimal import Decimal
from pathlib import Path

import isoxml.models.base.v4 as iso
import numpy as np
import shapely
from isoxml.converter.np_grid import from_numpy_array_to_type_1
from isoxml.converter.shapely_geom import ShapelyConverterV4
from isoxml.models.ddi_entities import DDEntity
from isoxml.util.isoxml_io import isoxml_to_zip

from agrislam import __version__
from agrislam.config import OutputsConfig
from agrislam.geometry.geodesy import MapFrame
from agrislam.io.sinks.geo_layers import map_frame, place, weeds
from agrislam.records import Anchor
from agrislam.snapshot import MapSnapshot

RATE_DDI = 1  # Setpoint Volume Per Area Application Rate, mm^3/m^2
MM3_PER_M2_PER_L_HA = 100.0  # 1 l/ha = 1e6 mm^3 / 1e4 m^2
DEGREE_DIGITS = 9  # ISOXML positions: decimal degrees, 9 digits


def cell_degrees(anchor: Anchor, cell_m: float) -> tuple[float, float]:
    """The size in degrees (north, east) of a cell of `cell_m` metres at the anchor."""
    north_up = MapFrame(Anchor(anchor.lat, anchor.lon, anchor.h, 0.0))
    lon_lat = north_up.to_wgs84(np.array([[0.0, cell_m], [cell_m, 0.0]]))
    return float(lon_lat[0, 1] - anchor.lat), float(lon_lat[1, 0] - anchor.lon)


def treatment_grid(
    lonlat: np.ndarray, d_north: float, d_east: float
) -> tuple[np.ndarray, float, float]:
    """(rows, columns) uint8 zone codes with 1 in every cell holding a point, and the grid's
    south-west corner (lat, lon), half a cell beyond the southernmost, westernmost point."""
    south = round(float(lonlat[:, 1].min()) - d_north / 2, DEGREE_DIGITS)
    west = round(float(lonlat[:, 0].min()) - d_east / 2, DEGREE_DIGITS)
    row = np.floor((lonlat[:, 1] - south) / d_north).astype(int)
    col = np.floor((lonlat[:, 0] - west) / d_east).astype(int)
    zones = np.zeros((row.max() + 1, col.max() + 1), dtype=np.uint8)
    zones[row, col] = 1
    return zones, south, west


def zone(code: int, name: str, value: int) -> iso.TreatmentZone:
    rate = iso.ProcessDataVariable(
        process_data_ddi=bytes(DDEntity.from_id(RATE_DDI)), process_data_value=value
    )
    return iso.TreatmentZone(code=code, designator=name, process_data_variables=[rate])


def write_isoxml(snapshot: MapSnapshot, path: str | Path, cfg: OutputsConfig) -> Path:
    """Write the TaskData zip; needs an anchor and weeds in the schema (geo_layers.weeds)."""
    path, frame = Path(path), map_frame(snapshot)
    treated = weeds(snapshot, cfg)
    if not len(treated.ids):
        raise ValueError("no plant is a weed with p >= outputs.weed_min_p: nothing to treat")
    lonlat = place(frame, treated.xy, "wgs84")
    d_north, d_east = cell_degrees(frame.anchor, cfg.cell_m)
    zones, south, west = treatment_grid(lonlat, d_north, d_east)
    # the field: the plants' convex hull and a cell around it, measured in the map frame
    hull = shapely.convex_hull(shapely.multipoints(snapshot.objects.xy))
    hull = hull.buffer(cfg.cell_m, join_style="mitre")
    outline = shapely.Polygon(place(frame, shapely.get_coordinates(hull), "wgs84"))
    boundary = ShapelyConverterV4().to_iso_polygon(outline, iso.PolygonType.PartfieldBoundary)
    customer = iso.Customer(id="CTR1", last_name="agrislam")
    farm = iso.Farm(id="FRM1", designator="agrislam", customer_id_ref=customer.id)
    field = iso.Partfield(
        id="PFD1",
        designator="surveyed field",
        area=round(hull.area),
        customer_id_ref=customer.id,
        farm_id_ref=farm.id,
        polygons=[boundary],
    )
    resolution = DDEntity.from_id(RATE_DDI).bit_resolution
    rate = round(cfg.rate_l_ha * MM3_PER_M2_PER_L_HA / resolution)
    rows, columns = zones.shape
    grid = iso.Grid(
        minimum_north_position=Decimal(f"{south:.{DEGREE_DIGITS}f}"),
        minimum_east_position=Decimal(f"{west:.{DEGREE_DIGITS}f}"),
        cell_north_size=d_north,
        cell_east_size=d_east,
        maximum_column=columns,
        maximum_row=rows,
        filename="GRD00001",
        type=iso.GridType.GridType1,
    )
    task = iso.Task(
        id="TSK1",
        designator="weed treatment",
        status=iso.TaskStatus.Planned,
        customer_id_ref=customer.id,
        farm_id_ref=farm.id,
        partfield_id_ref=field.id,
        treatment_zones=[zone(0, "no weed", 0), zone(1, "weed", rate)],
        grids=[grid],
        default_treatment_zone_code=0,
        position_lost_treatment_zone_code=0,
        out_of_field_treatment_zone_code=0,
    )
    task_data = iso.Iso11783TaskData(
        management_software_manufacturer="agrislam",
        management_software_version=__version__,
        data_transfer_origin=iso.Iso11783TaskDataDataTransferOrigin.FMIS,
        customers=[customer],
        farms=[farm],
        partfields=[field],
        tasks=[task],
    )
    with open(path, "wb") as f:
        isoxml_to_zip(f, task_data, {grid.filename: from_numpy_array_to_type_1(zones, grid)})
    return path
