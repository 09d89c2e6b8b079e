"""A Zenoh session that is one ROS 2 node on rmw_zenoh's graph (or a plain Zenoh client):
it opens the session (a peer listening for others, or joined to a router or peer), declares
the node's liveliness token, and makes the publishers and subscribers of its topics."""

from __future__ import annotations

import itertools
import json
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh
from rosbags.typesys.store import Typestore

from agrislam.live.wire import (
    PLAIN_ENCODING,
    Attachment,
    NodeName,
    Scheme,
    topic_key,
    topic_of_key,
    type_hash,
)


def session_config(
    listen: str | None = None, connect: str | None = None, scouting: bool = False
) -> zenoh.Config:
    """A peer session: listening on `listen` (others connect to it), or joined to `connect`
    (rmw_zenoh's router is ``tcp/localhost:7447``). Multicast scouting is off unless asked
    for: a robot's network is no place to find strangers by accident."""
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("listen/endpoints", json.dumps([listen] if listen else []))
    if connect:
        config.insert_json5("connect/endpoints", json.dumps([connect]))
        config.insert_json5("connect/timeout_ms", "10000")
    config.insert_json5("scouting/multicast/enabled", json.dumps(scouting))
    return config


@dataclass(frozen=True, slots=True)
class Received:
    """One sample as it came: its topic and type, CDR payload, rmw_zenoh attachment (None in
    plain mode or when absent) and when it came (time.time_ns())."""

    topic: str
    msgtype: str
    payload: bytes
    attachment: Attachment | None
    received_ns: int


class TopicPublisher:
    """One topic's publisher: each put carries the payload and, on ROS's scheme, the
    attachment with the next sequence number and the publisher's GID."""

    def __init__(
        self, node: LiveNode, topic: str, msgtype: str, entity_id: int, block: bool = True
    ) -> None:
        self.node, self.topic, self.msgtype = node, topic, msgtype
        self.gid = os.urandom(16)
        self.sequence = itertools.count(1)
        hashed = type_hash(node.store, msgtype)
        self.key = topic_key(node.scheme, node.name.domain, topic, msgtype, hashed)
        self.publisher = node.session.declare_publisher(
            self.key,
            encoding=zenoh.Encoding(f"{PLAIN_ENCODING};{msgtype}"),
            congestion_control=zenoh.CongestionControl.BLOCK
            if block
            else zenoh.CongestionControl.DROP,
            reliability=zenoh.Reliability.RELIABLE,
        )
        self.token = node.token_of(entity_id, "MP", topic, msgtype, hashed)

    def put(self, payload: bytes, stamp_ns: int | None = None) -> None:
        attachment = None
        if self.node.scheme == "ros":
            stamp = time.time_ns() if stamp_ns is None else stamp_ns
            attachment = Attachment(next(self.sequence), stamp, self.gid).encode()
        self.publisher.put(payload, attachment=attachment)

    @property
    def matched(self) -> bool:
        """Whether a subscriber of this key is known."""
        return bool(self.publisher.matching_status.matching)


class LiveNode:
    """The node on an open Zenoh session. `store` holds the definitions of every type it
    sends or takes (their hashes are computed from them). Close it to leave the graph."""

    def __init__(
        self,
        session: zenoh.Session,
        store: Typestore,
        name: str = "agrislam",
        namespace: str = "/",
        domain: int = 0,
        scheme: Scheme = "ros",
    ) -> None:
        self.session, self.store, self.scheme = session, store, scheme
        self.name = NodeName(domain, str(session.zid()), 0, namespace, name)
        self.entities = itertools.count(1)
        self.tokens: list[Any] = []
        self.subscribers: list[Any] = []
        self.publishers: dict[str, TopicPublisher] = {}
        self.lock = threading.Lock()
        if scheme == "ros":
            self.tokens.append(session.liveliness().declare_token(self.name.token()))

    @classmethod
    def open(
        cls, store: Typestore, listen: str | None = None, connect: str | None = None, **kw: Any
    ) -> LiveNode:
        return cls(zenoh.open(session_config(listen, connect)), store, **kw)

    def token_of(self, entity_id: int, kind: Any, topic: str, msgtype: str, hashed: str) -> Any:
        if self.scheme != "ros":
            return None
        key = self.name.endpoint_token(entity_id, kind, topic, msgtype, hashed)
        token = self.session.liveliness().declare_token(key)
        self.tokens.append(token)
        return token

    def publisher(self, topic: str, msgtype: str, block: bool = True) -> TopicPublisher:
        """The publisher of `topic` (made on first use). `block`: a put waits while the
        network is congested (a replay, whose every message counts), else it is dropped (a
        map that the next one replaces: a slow subscriber never holds up the mapper)."""
        with self.lock:
            pub = self.publishers.get(topic)
            if pub is None:
                pub = TopicPublisher(self, topic, msgtype, next(self.entities), block)
                self.publishers[topic] = pub
            elif pub.msgtype != msgtype:
                raise ValueError(f"{topic} carries {pub.msgtype}, not {msgtype}")
            return pub

    def subscribe(
        self, msgtype: str, on_sample: Callable[[Received], None], topic: str = "**"
    ) -> None:
        """Take every sample of `msgtype` on `topic` (a key expression pattern over topic
        names: ``**`` for all of them). On ROS's scheme a named topic also gets its
        subscriber's token; a pattern cannot (rmw_zenoh tokens name one topic)."""
        hashed = type_hash(self.store, msgtype)
        key = topic_key(self.scheme, self.name.domain, topic, msgtype, hashed)
        scheme = self.scheme

        def handler(sample: zenoh.Sample) -> None:
            name, found = topic_of_key(scheme, str(sample.key_expr))
            if scheme == "plain":
                found = str(sample.encoding).partition(";")[2] or None
                if found != msgtype:
                    return
            raw = sample.attachment
            attachment = None
            if raw is not None and scheme == "ros":
                try:
                    attachment = Attachment.decode(raw.to_bytes())
                except ValueError:
                    attachment = None
            on_sample(
                Received(name, msgtype, sample.payload.to_bytes(), attachment, time.time_ns())
            )

        # on the network thread, as samples come: Zenoh's default (a thread per subscriber)
        # would lose the order between topics, which the map needs
        direct = zenoh.handlers.Callback(handler, indirect=False)
        self.subscribers.append(self.session.declare_subscriber(key, direct))
        if "*" not in topic:
            self.subscribe_token(topic, msgtype)

    def subscribe_token(self, topic: str, msgtype: str) -> None:
        """The liveliness token of a subscriber of `topic` (one found through a pattern)."""
        self.token_of(next(self.entities), "MS", topic, msgtype, type_hash(self.store, msgtype))

    def wait_matched(self, timeout: float) -> bool:
        """Whether every publisher has a subscriber within `timeout` s."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if all(p.matched for p in self.publishers.values()):
                return True
            time.sleep(0.01)
        return False

    def close(self) -> None:
        for sub in self.subscribers:
            sub.undeclare()
        for token in self.tokens:
            token.undeclare()
        for pub in self.publishers.values():
            pub.publisher.undeclare()
        self.subscribers, self.tokens = [], []
        self.session.close()
