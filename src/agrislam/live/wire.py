"""rmw_zenoh's wire format, as its design document and rmw_zenoh_cpp lay it out:

- a topic's key expression: ``<domain_id>/<topic without its leading />/<DDS type
  name>/<RIHS01 type hash>``, e.g. ``0/r1/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_3cc9...``;
- the payload: the message's CDR with its 4-byte encapsulation header (as rosbags writes it);
- the attachment of each sample: the sequence number (int64), the source timestamp in ns
  (int64) and the publisher's 16-byte GID, laid out by Zenoh's serializer (little-endian
  integers; the GID as a byte sequence, its length a LEB128 varint);
- liveliness tokens under ``@ros2_lv``: one per node (``NN``), publisher (``MP``) and
  subscriber (``MS``), with names mangled (``/`` as ``%``) and the QoS as rmw_zenoh
  encodes it.

The plain mode keeps the topics and CDR payloads but none of the ROS conventions: the key
is the topic itself, the type travels in the sample's encoding."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Literal

from rosbags.typesys.store import Typestore

Scheme = Literal["ros", "plain"]
ADMIN_SPACE = "@ros2_lv"
GID_SIZE = 16
DEFAULT_QOS = "::,10:,:,:,,"  # reliable, volatile, keep last 10: the rmw defaults, left empty
PLAIN_ENCODING = "application/cdr"  # ;<type name> follows


def dds_type_name(msgtype: str) -> str:
    """``pkg/msg/Type`` as DDS names it (``pkg::msg::dds_::Type_``)."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_type_name(dds: str) -> str:
    """The inverse of `dds_type_name`."""
    pkg, kind, _, name = dds.split("::")
    return f"{pkg}/{kind}/{name.removesuffix('_')}"


def type_hash(store: Typestore, msgtype: str) -> str:
    """The RIHS01 hash (REP 2011) of a type's description, from the definitions in `store`."""
    return store.hash_rihs01(msgtype)


def mangle(name: str) -> str:
    """A name inside a liveliness token: ``/`` as ``%``, the empty or root name as ``%``."""
    return "%" if name in ("", "/") else name.replace("/", "%")


def topic_key(scheme: Scheme, domain: int, topic: str, msgtype: str, hashed: str) -> str:
    """The key expression samples of `topic` are put on."""
    if scheme == "plain":
        return topic.strip("/")
    return f"{domain}/{topic.strip('/')}/{dds_type_name(msgtype)}/{hashed}"


def topic_of_key(scheme: Scheme, key: str) -> tuple[str, str | None]:
    """(topic, type or None) of a sample's key expression."""
    if scheme == "plain":
        return "/" + key, None
    parts = key.split("/")
    if len(parts) < 4 or not parts[-1].startswith("RIHS01_"):
        raise ValueError(f"{key!r} is no rmw_zenoh topic key")
    return "/" + "/".join(parts[1:-2]), ros_type_name(parts[-2])


@dataclass(frozen=True, slots=True)
class Attachment:
    """What rmw_zenoh attaches to every sample."""

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def encode(self) -> bytes:
        if len(self.gid) != GID_SIZE:
            raise ValueError(f"a GID has {GID_SIZE} bytes, got {len(self.gid)}")
        head = struct.pack("<qq", self.sequence_number, self.source_timestamp_ns)
        return head + bytes([GID_SIZE]) + self.gid

    @classmethod
    def decode(cls, data: bytes) -> Attachment:
        if len(data) != 17 + GID_SIZE or data[16] != GID_SIZE:
            raise ValueError(f"not an rmw_zenoh attachment ({len(data)} bytes)")
        seq, stamp = struct.unpack_from("<qq", data)
        return cls(seq, stamp, bytes(data[17:]))


@dataclass(frozen=True, slots=True)
class NodeName:
    """Who a node is on the graph: its domain, Zenoh session id, number in the session,
    namespace and name."""

    domain: int
    zid: str
    node_id: int
    namespace: str
    name: str

    def token(self) -> str:
        """The node's liveliness token (``NN``)."""
        return self._head(self.node_id, "NN")

    def endpoint_token(
        self, entity_id: int, kind: Literal["MP", "MS"], topic: str, msgtype: str, hashed: str
    ) -> str:
        """The liveliness token of one of its publishers (``MP``) or subscribers (``MS``)."""
        return (
            f"{self._head(entity_id, kind)}/{mangle(topic)}/{dds_type_name(msgtype)}/"
            f"{hashed}/{DEFAULT_QOS}"
        )

    def _head(self, entity_id: int, kind: str) -> str:
        return (
            f"{ADMIN_SPACE}/{self.domain}/{self.zid}/{self.node_id}/{entity_id}/{kind}/%/"
            f"{mangle(self.namespace)}/{mangle(self.name)}"
        )


def endpoint_of_token(token: str) -> dict[str, str] | None:
    """The parts of a publisher's or subscriber's liveliness token (None for other tokens)."""
    parts = token.split("/")
    if len(parts) != 13 or parts[0] != ADMIN_SPACE or parts[5] not in ("MP", "MS"):
        return None
    return {
        "kind": parts[5],
        "node": parts[8].replace("%", "/"),
        "topic": parts[9].replace("%", "/"),
        "type": ros_type_name(parts[10]),
        "hash": parts[11],
    }
