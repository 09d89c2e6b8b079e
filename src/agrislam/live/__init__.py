"""agrislam on a running robot: the map made while the robots drive, over Zenoh.

`wire`: rmw_zenoh's wire format (key expressions, attachment, liveliness tokens, type
hashes), so a ROS 2 system on rmw_zenoh sees agrislam as a node; `node`: a Zenoh session as
that node; `decoder`: messages into records as they come; `recording`: every message kept in
an MCAP file; `mapper`: the live map, bounded queue, map topics at a set rate; `replay`: a
recorded survey published on the same topics."""
