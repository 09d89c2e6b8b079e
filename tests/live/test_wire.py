"""rmw_zenoh's wire format as agrislam writes it, checked against what others publish: the
type hashes ROS 2 (Jazzy, Kilted) generates for the types agrislam sends and takes, the
attachment as Zenoh's own serializer lays it out, the key expressions and liveliness
tokens of rmw_zenoh's design."""

import pytest
import zenoh.ext

from agrislam.io.ros.messages import typestore
from agrislam.live.wire import (
    Attachment,
    NodeName,
    dds_type_name,
    endpoint_of_token,
    mangle,
    ros_type_name,
    topic_key,
    topic_of_key,
    type_hash,
)

# RIHS01 hashes as ROS 2 publishes them (`ros2 topic info -v` on Jazzy/Kilted, and the
# generated code of rmw_zenoh-compatible clients); vision_msgs 4.x for the detections
PUBLISHED = {
    "std_msgs/msg/String": "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "nav_msgs/msg/Odometry": "3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "nav_msgs/msg/Path": "1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b",
    "nav_msgs/msg/OccupancyGrid": (
        "8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7"
    ),
    "visualization_msgs/msg/MarkerArray": (
        "86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf"
    ),
    "sensor_msgs/msg/NavSatFix": "62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404",
    "sensor_msgs/msg/Image": "d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
    "vision_msgs/msg/Detection3DArray": (
        "793f5eab9595ac1c0da07873cc859db42eae51f0ee76056db8562515d830e018"
    ),
}


@pytest.mark.parametrize("msgtype", sorted(PUBLISHED))
def test_type_hashes_from_the_registered_definitions_are_the_published_ones(msgtype):
    assert type_hash(typestore("humble"), msgtype) == f"RIHS01_{PUBLISHED[msgtype]}"


def test_a_changed_definition_changes_its_hash():
    store = typestore("humble")
    other = typestore("foxy")  # vision_msgs 2.x/3.x: another Detection3D
    assert type_hash(store, "vision_msgs/msg/Detection3DArray") != type_hash(
        other, "vision_msgs/msg/Detection3DArray"
    )


def test_the_attachment_is_laid_out_as_zenohs_serializer_lays_out_rmw_zenohs_fields():
    gid = bytes(range(16))
    ours = Attachment(7, 1_700_000_000_123_456_789, gid).encode()
    theirs = zenoh.ext.z_serialize(
        (zenoh.ext.Int64(7), zenoh.ext.Int64(1_700_000_000_123_456_789), gid)
    ).to_bytes()
    assert ours == theirs and len(ours) == 33
    assert Attachment.decode(theirs) == Attachment(7, 1_700_000_000_123_456_789, gid)
    with pytest.raises(ValueError):
        Attachment.decode(theirs[:-1])
    with pytest.raises(ValueError):
        Attachment(1, 2, b"short").encode()


def test_key_expressions_of_ros_and_plain_topics():
    hashed = "RIHS01_" + PUBLISHED["nav_msgs/msg/Odometry"]
    key = topic_key("ros", 3, "/r1/odom", "nav_msgs/msg/Odometry", hashed)
    assert key == f"3/r1/odom/nav_msgs::msg::dds_::Odometry_/{hashed}"
    assert topic_of_key("ros", key) == ("/r1/odom", "nav_msgs/msg/Odometry")
    assert topic_key("plain", 3, "/r1/odom", "nav_msgs/msg/Odometry", hashed) == "r1/odom"
    assert topic_of_key("plain", "r1/odom") == ("/r1/odom", None)
    with pytest.raises(ValueError):
        topic_of_key("ros", "r1/odom")
    assert ros_type_name(dds_type_name("vision_msgs/msg/Detection3DArray")) == (
        "vision_msgs/msg/Detection3DArray"
    )


def test_liveliness_tokens_name_node_publisher_and_subscriber_as_rmw_zenoh_does():
    node = NodeName(0, "aabbcc", 0, "/", "agrislam")
    assert node.token() == "@ros2_lv/0/aabbcc/0/0/NN/%/%/agrislam"
    hashed = "RIHS01_" + PUBLISHED["nav_msgs/msg/Path"]
    token = node.endpoint_token(4, "MP", "/agrislam/trajectory/r1", "nav_msgs/msg/Path", hashed)
    assert token == (
        "@ros2_lv/0/aabbcc/0/4/MP/%/%/agrislam/%agrislam%trajectory%r1/"
        f"nav_msgs::msg::dds_::Path_/{hashed}/::,10:,:,:,,"
    )
    assert endpoint_of_token(token) == {
        "kind": "MP",
        "node": "agrislam",
        "topic": "/agrislam/trajectory/r1",
        "type": "nav_msgs/msg/Path",
        "hash": hashed,
    }
    assert endpoint_of_token(node.token()) is None
    assert mangle("/") == "%" and mangle("/ns/a") == "%ns%a"
