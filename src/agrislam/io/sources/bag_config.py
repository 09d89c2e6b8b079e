"""How to read a ROS bag: which topics mean what (named here or found by type), how the
odometry covariance is meant, the form of the records, and the RGB-D front end's settings.
The ``bag:`` section of a run's config file."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from agrislam.io.perception.config import PerceptionConfig
from agrislam.io.ros.conventions import META_TOPIC, TRUTH_TOPIC
from agrislam.io.ros.messages import Layout


class BagSourceConfig(BaseModel):
    """Which topics of a bag mean what, and how to read them."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    robot: str = Field("r1", description="robot of topics without a robot namespace")
    odometry_topics: list[str] | None = Field(None, description="default: every nav_msgs/Odometry")
    detection_topics: list[str] | None = Field(
        None, description="Detection3DArray / Detection2DArray topics; default: all of them"
    )
    depth_topics: list[str] | None = Field(
        None, description="default: Images with 'depth' in the name"
    )
    camera_info_topics: list[str] | None = Field(None, description="default: every CameraInfo")
    gnss_topics: list[str] | None = Field(None, description="default: every NavSatFix")
    instance_topics: list[str] | None = Field(
        None,
        description="instance images (pixel k = detection k-1); default: 'instance' in the name",
    )
    rgb_topics: list[str] | None = Field(
        None, description="colour images for the green filter; default: 'color'/'rgb' in the name"
    )
    meta_topic: str = META_TOPIC
    truth_topic: str = TRUTH_TOPIC
    base_frame: str | None = Field(
        None, description="robot base frame; default: the odometry child_frame_id, else base_link"
    )
    camera_to_base: tuple[float, float, float, float, float, float, float] | None = Field(
        None, description="x y z qx qy qz qw of frames tf does not connect to the base"
    )
    odom_covariance: Literal["increment", "absolute", "ignore"] = Field(
        "increment",
        description="the x/y/yaw block of an Odometry's pose covariance: that of the motion "
        "since the previous message ('increment', drivers with a fixed covariance), of the "
        "pose itself, differenced between messages ('absolute', as an EKF publishes), or not "
        "read ('ignore')",
    )
    odometry_form: Literal["pose", "delta"] = Field(
        "pose", description="odometry records as odometry-frame poses or as increments"
    )
    detection_geometry: Literal["xy", "range_bearing"] = Field(
        "xy", description="detections as position + covariance or as range and bearing"
    )
    class_names: dict[str, str] = Field(
        default_factory=dict, description="numeric class id -> class name"
    )
    split_labels: bool = Field(True, description="split combined labels with the label map")
    sync_tolerance: float = Field(0.02, ge=0.0, description="s between detections and depth")
    vision_msgs_layout: Layout = Field(
        "humble", description="layout for bags that carry no message definitions"
    )
    perception: PerceptionConfig | None = Field(
        None, description="RGB-D front end; default: from the run's sensor settings"
    )
