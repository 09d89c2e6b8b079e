"""Outputs of a run (DESIGN.md "Outputs of a run"): each sink takes a `MapSnapshot` and
writes one file; none of them is imported by the core."""

from agrislam.sinks.csv import write_objects_csv, write_trajectory_csv
from agrislam.sinks.geojson import map_to_lonlat, write_geojson
from agrislam.sinks.report import write_attribute_maps, write_report
from agrislam.sinks.sqlite import load_map, save_map

__all__ = [
    "load_map",
    "map_to_lonlat",
    "save_map",
    "write_attribute_maps",
    "write_geojson",
    "write_objects_csv",
    "write_report",
    "write_trajectory_csv",
]
