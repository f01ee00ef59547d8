"""The ROS side of a bridge process: one Zenoh session on the ROS network, apart from
fw's bus.

Why a session of its own: fw's bus admits only sessions holding the deployment's
certificates (mTLS) and lives in the deployment's namespace; ROS nodes hold neither.
So the bridge process has two sessions, and only its bridge components (the entries
of the topology's `ros2:` section) copy samples from one to the other: a ROS node sees
only the outputs exposed to it and can write only the inputs declared, each checked
(framework/ros2/convert.py) before it reaches fw's bus, where the process's access
rules apply as to any other.

The ROS session joins the ROS network as rmw_zenoh's nodes do, through its router
(rmw_zenohd; default `tcp/127.0.0.1:7447`), but listens on no port: it learns the
nodes from the router and connects to each itself (gossip, `to_peer: always`), so its
samples take one hop to a node, not two through the router, and it opens nothing a
stranger could connect to. Measured (`fw bench ros2`): a ROS pose reached fw's bus in
0.52 ms p50 as a client of the router, 0.36 ms as such a peer.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from framework.errors import FwError
from framework.ros2.rmw import CDR_ENCODING, GID_SIZE, Attachment, EntityKind, Node

DEFAULT_ROUTER = "tcp/127.0.0.1:7447"
"""Where rmw_zenoh's router listens by default (`ros2 run rmw_zenoh_cpp rmw_zenohd`)."""
ROUTER_WAIT = 2.0
"""How long configuring a bridge waits for the router before it says none answers (it
goes on: the router may start after fw, and fw's own functions never wait on ROS)."""
log = logging.getLogger("fw.ros2")


class RosLinkError(FwError):
    """The ROS network cannot be reached, or a setting for it is wrong."""


def ros_config(router: str, extra: dict[str, Any] | None = None) -> zenoh.Config:
    """The ROS session's Zenoh configuration: a peer that connects to `router` and to
    the nodes it learns of there, with no listening port and no multicast scouting;
    `extra` (the section's `zenoh:`) may add TLS to the router."""
    settings: dict[str, Any] = {
        "mode": "peer",
        "connect/endpoints": [router],
        "listen/endpoints": [],
        "scouting/multicast/enabled": False,
        "scouting/gossip/enabled": True,
        "scouting/gossip/autoconnect": {"router": [], "peer": ["router", "peer"]},
        "scouting/gossip/autoconnect_strategy": {
            "peer": {"to_router": "always", "to_peer": "always"}
        },
        "connect/retry": {"period_init_ms": 250, "period_max_ms": 1000},
        **(extra or {}),
    }
    config = zenoh.Config()
    for key, value in settings.items():
        try:
            config.insert_json5(key, json.dumps(value))
        except Exception as exc:  # zenoh raises its own error type
            raise RosLinkError(
                f"invalid Zenoh setting for the ROS side {key}={value!r}: {exc}"
            ) from None
    return config


@dataclass
class RosEndpoint:
    """One topic on the ROS side: its Zenoh publisher or subscriber, its liveliness
    token, and, for a publisher, its GID and sequence counter (`put` is called from one
    thread, the bridge component's)."""

    key: str
    entity: Any
    token: Any
    gid: bytes = field(default_factory=lambda: os.urandom(GID_SIZE))
    sequence: int = 0

    def put(self, payload: bytes, source_ns: int) -> None:
        """Send one CDR sample with its attachment (rmw_zenoh drops samples without)."""
        self.sequence += 1
        attachment = Attachment(self.sequence, source_ns, self.gid).encode()
        self.entity.put(payload, encoding=CDR_ENCODING, attachment=attachment)

    def close(self) -> None:
        """Undeclare the token (the topic leaves `ros2 topic list`), then the entity."""
        for declared in (self.token, self.entity):
            with contextlib.suppress(Exception):  # already closed with its session
                declared.undeclare()


class RosLink:
    """One process's session on the ROS network and the node it declares there, shared
    by the process's bridge components (`acquire`/`release`, counted)."""

    _open: dict[tuple[str, int, str], RosLink] = {}
    _lock = threading.Lock()

    def __init__(self, router: str, domain: int, node: str, extra: dict[str, Any] | None):
        try:
            self.session = zenoh.open(ros_config(router, extra))
        except RosLinkError:
            raise
        except Exception as exc:  # zenoh raises its own error type
            raise RosLinkError(
                f"cannot open a session for the ROS network at {router} "
                f"({str(exc).split(' at /')[0].strip()})"
            ) from None
        self.router = router
        deadline = time.monotonic() + ROUTER_WAIT
        while not self.connected() and time.monotonic() < deadline:
            time.sleep(0.05)
        if not self.connected():
            log.warning(
                "no ROS 2 router answers at %s yet: ROS nodes see nothing of fw until one "
                "runs there (`ros2 run rmw_zenoh_cpp rmw_zenohd`, or `fw ros2 router`)",
                router,
            )
        self.node = Node(domain, str(self.session.info.zid()), node)
        self._node_token = self.session.liveliness().declare_token(self.node.token())
        self._entities = 0
        self.users = 0

    def connected(self) -> bool:
        """True while the session is linked to the ROS network's router."""
        return bool(list(self.session.info.routers_zid()))

    @classmethod
    def acquire(
        cls, router: str, domain: int, node: str, extra: dict[str, Any] | None = None
    ) -> RosLink:
        """The process's link for (router, domain, node), opened on first use."""
        with cls._lock:
            link = cls._open.get((router, domain, node))
            if link is None:
                link = cls._open[(router, domain, node)] = RosLink(router, domain, node, extra)
            link.users += 1
            return link

    def release(self) -> None:
        """One user fewer; the last one closes the session (the node leaves the graph)."""
        with RosLink._lock:
            self.users -= 1
            if self.users > 0:
                return
            RosLink._open.pop((self.router, self.node.domain, self.node.name), None)
        with contextlib.suppress(Exception):  # closing twice, or at interpreter exit
            self._node_token.undeclare()
            self.session.close()

    def _entity_id(self) -> int:
        with RosLink._lock:
            self._entities += 1
            return self._entities

    def publisher(
        self, topic: str, ros_type: str, type_hash: str, key: str, qos: str
    ) -> RosEndpoint:
        """Declare a publisher on `key` and its `MP` token."""
        token = self.node.endpoint_token(
            EntityKind.PUBLISHER, self._entity_id(), topic, ros_type, type_hash, qos
        )
        publisher = self.session.declare_publisher(
            key, encoding=CDR_ENCODING, congestion_control=zenoh.CongestionControl.DROP
        )
        return RosEndpoint(key, publisher, self.session.liveliness().declare_token(token))

    def subscribe(
        self,
        topic: str,
        ros_type: str,
        type_hash: str,
        key: str,
        qos: str,
        callback: Callable[[Any], None],
    ) -> RosEndpoint:
        """Declare a subscriber on `key` (`callback` runs in a Zenoh thread) and its
        `MS` token."""
        token = self.node.endpoint_token(
            EntityKind.SUBSCRIPTION, self._entity_id(), topic, ros_type, type_hash, qos
        )
        subscriber = self.session.declare_subscriber(key, callback)
        return RosEndpoint(key, subscriber, self.session.liveliness().declare_token(token))
