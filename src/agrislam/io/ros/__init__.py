"""ROS messages without a ROS installation (rosbags): the definitions, type stores and
message builders that the bag source reads with and the bag sinks write with. It imports
neither sources nor sinks; both import it."""
