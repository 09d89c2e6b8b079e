"""Outputs of a run (DESIGN.md "Outputs of a run"): each sink takes a `MapSnapshot` (or the
survey's records) and writes one file; none of them is imported by the core. Sinks never
import each other: what several read sits in the helpers `columns`, `readouts` and `scene`."""

from agrislam.io.sinks.csv import write_objects_csv, write_trajectory_csv
from agrislam.io.sinks.geojson import map_to_lonlat, write_geojson
from agrislam.io.sinks.report import write_attribute_maps, write_report
from agrislam.io.sinks.sqlite import load_map, save_map

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
