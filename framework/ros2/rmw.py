"""What ROS 2's Zenoh middleware (rmw_zenoh) expects on the wire, written from its
documented design (../shared/FACTS.md, "ROS 2 over Zenoh"): the data key of a topic,
the liveliness tokens that make a node and its endpoints appear in `ros2 node list` and
`ros2 topic list`, the attachment every sample must carry, and the QoS string of a
token. Pure functions and one small dataclass: no session, no I/O.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from enum import StrEnum

from framework.errors import FwError

ADMIN_SPACE = "@ros2_lv"
"""Where rmw_zenoh declares its liveliness tokens (the ROS graph)."""
CDR_ENCODING = "application/cdr"
GID_SIZE = 16
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
DEFAULT_QOS = "::,10:,:,:,,"
"""rmw_zenoh's QoS string for the default profile: reliable, volatile, keep last 10,
no deadline, lifespan or liveliness lease (an empty field is the default)."""
SENSOR_QOS = "2::,5:,:,:,,"
"""The sensor-data profile: best effort, keep last 5 (what `ros2 topic echo` matches
for joint states and poses without asking for reliability)."""

_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/msg/([A-Z][A-Za-z0-9]*)$")
_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class RmwError(FwError):
    """A ROS name, type or attachment that rmw_zenoh would not accept."""


class EntityKind(StrEnum):
    """The kind letters of a liveliness token."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"


def check_topic(name: str) -> str:
    """`name` if it is a valid absolute ROS 2 topic name (`/a/b_c`: tokens of letters,
    digits and `_`, none starting with a digit, no empty token), else `RmwError` saying
    what is wrong. Relative names are not taken: fw's node has no namespace to
    resolve them against, so a topic is always written as ROS tools print it."""
    if not name.startswith("/"):
        raise RmwError(f"ROS topic {name!r} must be absolute (start with '/')")
    tokens = name[1:].split("/")
    for token in tokens:
        if not _TOKEN.match(token):
            raise RmwError(
                f"ROS topic {name!r}: {token!r} is not a name token "
                "(letters, digits and '_', not starting with a digit, no '//' or trailing '/')"
            )
    return name


def check_type(ros_type: str) -> tuple[str, str]:
    """(package, message) of a `pkg/msg/Name` type, else `RmwError`."""
    match = _TYPE.match(ros_type)
    if match is None:
        raise RmwError(f"ROS type {ros_type!r} is not of the form package/msg/Name")
    return match.group(1), match.group(2)


def dds_type(ros_type: str) -> str:
    """The type name in keys and tokens: `sensor_msgs/msg/JointState` ->
    `sensor_msgs::msg::dds_::JointState_`."""
    package, name = check_type(ros_type)
    return f"{package}::msg::dds_::{name}_"


def mangle(name: str) -> str:
    """A name inside one chunk of a token: every '/' written '%' ('%' alone for an empty
    or root name)."""
    if not name or name == "/":
        return "%"
    return name.replace("/", "%")


def topic_key(domain: int, topic: str, ros_type: str, type_hash: str) -> str:
    """The data key of a topic: `<domain>/<topic without its outer '/'>/<dds type>/<hash>`."""
    return f"{domain}/{check_topic(topic).strip('/')}/{dds_type(ros_type)}/{type_hash}"


@dataclass(frozen=True)
class Node:
    """A ROS node as the graph sees it: fw's bridge is one node per process."""

    domain: int
    zid: str
    """The Zenoh session id of the session that declares it."""
    name: str
    namespace: str = "/"
    node_id: int = 0
    enclave: str = ""

    def token(self) -> str:
        """The node's liveliness token (`ros2 node list` shows it while it lives)."""
        return (
            f"{ADMIN_SPACE}/{self.domain}/{self.zid}/{self.node_id}/{self.node_id}/"
            f"{EntityKind.NODE}/{mangle(self.enclave)}/{mangle(self.namespace)}/{self.name}"
        )

    def endpoint_token(
        self,
        kind: EntityKind,
        entity_id: int,
        topic: str,
        ros_type: str,
        type_hash: str,
        qos: str = DEFAULT_QOS,
    ) -> str:
        """A publisher's or subscription's liveliness token (`ros2 topic list -v`)."""
        return (
            f"{ADMIN_SPACE}/{self.domain}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
            f"{mangle(self.enclave)}/{mangle(self.namespace)}/{self.name}/"
            f"{mangle(check_topic(topic))}/{dds_type(ros_type)}/{type_hash}/{qos}"
        )


@dataclass(frozen=True)
class Attachment:
    """What rmw_zenoh requires beside every sample (a sample without one is dropped):
    the publisher's sequence number (from 1), the source time (ns since the epoch) and
    the publisher's 16-byte GID."""

    sequence: int
    source_ns: int
    gid: bytes

    _LAYOUT = struct.Struct("<qqB")

    def encode(self) -> bytes:
        """The 33 bytes: int64 sequence, int64 source time, 0x10, the GID."""
        if len(self.gid) != GID_SIZE:
            raise RmwError(f"a GID is {GID_SIZE} bytes, not {len(self.gid)}")
        return self._LAYOUT.pack(self.sequence, self.source_ns, GID_SIZE) + self.gid

    @classmethod
    def decode(cls, data: bytes) -> Attachment:
        """The attachment in `data`, else `RmwError` (too short, or a GID length that
        does not fit what follows)."""
        if len(data) < cls._LAYOUT.size:
            raise RmwError(f"attachment of {len(data)} bytes (rmw_zenoh sends {ATTACHMENT_SIZE})")
        sequence, source_ns, size = cls._LAYOUT.unpack_from(data)
        gid = bytes(data[cls._LAYOUT.size : cls._LAYOUT.size + size])
        if len(gid) != size:
            raise RmwError(f"attachment says a {size}-byte GID, {len(gid)} bytes follow")
        return cls(sequence, source_ns, gid)
