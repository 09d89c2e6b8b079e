"""The map as the messages a live node publishes, on the topics of the run's map.mcap:
the plants as ``visualization_msgs/MarkerArray`` on ``/agrislam/plants``, each robot's
optimised path as ``nav_msgs/Path`` on ``/agrislam/trajectory/<robot>``, and the interest
surface (sec. 2.7) as ``nav_msgs/OccupancyGrid`` on ``/agrislam/interest`` (h in [0, 1]
as 0-100: where to look next)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from agrislam.io.ros.messages import MARKER_ARRAY, PATH, MessageFactory
from agrislam.io.sinks.ros_map import PLANTS_TOPIC, plant_markers, trajectory_path
from agrislam.semantics.heuristic import InterestSurface
from agrislam.snapshot import MapSnapshot

OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
INTEREST_TOPIC = "/agrislam/interest"
TRAJECTORY_TOPIC = "/agrislam/trajectory/{robot}"


def interest_grid(
    surface: InterestSurface, make: MessageFactory, t: float, frame: str = "map"
) -> object:
    """The interest surface as an OccupancyGrid (row-major from (x0, y0), h as 0-100)."""
    ny, nx = surface.values.shape
    cells = np.rint(np.clip(surface.values, 0.0, 1.0) * 100.0).astype(np.int8).ravel()
    T = make.T
    info = T["nav_msgs/msg/MapMetaData"](
        map_load_time=make.time(t),
        resolution=float(surface.resolution),
        width=nx,
        height=ny,
        origin=make.pose((surface.x0, surface.y0, 0.0)),
    )
    return T[OCCUPANCY_GRID](header=make.header(t, frame), info=info, data=cells)


def map_messages(
    snapshot: MapSnapshot, make: MessageFactory, t: float, frame: str = "map", labels: bool = True
) -> Iterator[tuple[str, str, bytes]]:
    """(topic, type, CDR) of every message of one publication of the map."""
    markers = plant_markers(snapshot, make, t=t, frame=frame, labels=labels)
    yield PLANTS_TOPIC, MARKER_ARRAY, make.serialize(markers, MARKER_ARRAY)
    for robot, trajectory in snapshot.trajectories.items():
        path = trajectory_path(trajectory, make, frame)
        yield TRAJECTORY_TOPIC.format(robot=robot), PATH, make.serialize(path, PATH)
    if snapshot.interest_surface is not None:
        grid = interest_grid(snapshot.interest_surface, make, t, frame)
        yield INTEREST_TOPIC, OCCUPANCY_GRID, make.serialize(grid, OCCUPANCY_GRID)
