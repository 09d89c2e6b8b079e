"""Mapping on the robot (`agrislam live`, `agrislam replay`): what a user sets (how often the
map goes out, how many messages may wait, the ROS domain, the topics' naming) and, in
`advanced.live`, the node's name and the map's frame."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from agrislam.config.limits import StrictModel as _Strict


class LiveSection(_Strict):
    """The live node."""

    publish_rate: float = Field(
        20.0, gt=0.0, description="Hz, at most: the map, paths and interest grid go out"
    )
    queue_size: int = Field(
        32,
        ge=1,
        description="detection frames waiting for the mapper at most (the lag it may run "
        "behind: 32 frames at 10 Hz is 3.2 s); past it the oldest is dropped and counted",
    )
    domain_id: int = Field(0, ge=0, le=232, description="ROS_DOMAIN_ID of the graph")
    namespaces: Literal["ros", "plain"] = Field(
        "ros",
        description="ros: rmw_zenoh's key expressions, attachments and liveliness tokens (a "
        "ROS 2 node); plain: the same topics as bare Zenoh keys, for fleets without ROS",
    )
    robots: list[str] | None = Field(
        None, description="robot namespaces to map; none: every robot that publishes"
    )


class AdvancedLive(_Strict):
    """The node's identity on the graph and the frame of what it publishes."""

    node_name: str = Field("agrislam", pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")
    map_frame: str = "map"
    marker_labels: bool = Field(True, description="a text marker per plant in the live map")
    replay_wait_s: float = Field(
        10.0, ge=0.0, description="s a replay waits for a subscriber before it publishes"
    )
