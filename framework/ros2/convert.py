"""fw samples to ROS 2 messages and back: which pairs exist, their CDR bytes, and the
REP-2011 type hashes rmw_zenoh puts in its keys.

Messages, CDR and hashes come from `rosbags` (its ROS 2 Jazzy type store), not from a
serializer of fw's own: it is a well-kept pure-Python library that reads and writes
real ROS bags, so its bytes are the ones ROS nodes read. It is imported on first use,
in the bridge's process only (a safety process never maps it).

What crosses is checked like any sample fw reads: a ROS message that is not finite,
has a quaternion that is not a rotation, lacks a joint fw was told to expect, or says
nothing of its time is refused with the reason (`Refused`), never passed on. Stamps
are wall-clock seconds on both sides (ROS time and fw's sample stamps); a stamp from a
ROS host is never taken as later than the sample's arrival, so a clock running ahead
there cannot make data look fresher than it is (a clock behind makes it look older,
which only errs on the safe side).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from typing import Any

from framework.errors import FwError
from framework.messages import JointState, Pose, Scalar, type_name


class Refused(FwError):
    """A sample or message that must not cross the bridge, and why."""


@dataclass(frozen=True)
class Options:
    """What a bridge entry of the topology says beyond its topic and type."""

    names: tuple[str, ...] = ()
    """Joint names, in fw's order (JointState): published as the message's names;
    a received message must name them all (in any order: ROS does not fix one)."""
    frame: str = ""
    """frame_id for a Pose whose sample names none; a received pose's frame if its
    header names none."""
    stamp: str = "header"
    """'header': a received message is as old as its header says (never younger than
    its arrival); 'arrival': stamped on arrival, for ROS publishers that do not stamp."""


@dataclass(frozen=True)
class Conversion:
    """One ROS type and the fw message type it carries, both ways."""

    ros_type: str
    fw_type: type
    to_ros: Callable[[Any, float, Options], Any] = field(repr=False)
    """(fw sample, its stamp on this host's wall clock, options) -> ROS message."""
    from_ros: Callable[[Any, float, Options], Any] = field(repr=False)
    """(ROS message, its arrival on this host's wall clock, options) -> fw sample."""


@cache
def typestore() -> Any:
    """rosbags' type store for ROS 2 Jazzy (loaded once per process)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


@cache
def type_hash(ros_type: str) -> str:
    """The `RIHS01_<sha256>` type hash of `ros_type` (REP 2011), as rmw_zenoh keys it."""
    return str(typestore().hash_rihs01(ros_type))


def serialize(message: Any, ros_type: str) -> bytes:
    """CDR bytes of `message`, with the 4-byte little-endian encapsulation header."""
    return bytes(typestore().serialize_cdr(message, ros_type))


def deserialize(data: bytes, ros_type: str) -> Any:
    """The ROS message in CDR `data`; `Refused` for bytes that are not one (rosbags
    checks the encapsulation header and every length)."""
    try:
        return typestore().deserialize_cdr(data, ros_type)
    except Exception as exc:  # rosbags raises whatever its reader met: all mean bad bytes
        raise Refused(f"not a {ros_type}: {type(exc).__name__}: {exc}") from None


def _time(seconds: float) -> Any:
    store = typestore()
    sec = math.floor(seconds)
    nanosec = min(999_999_999, max(0, round((seconds - sec) * 1e9)))
    return store.types["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=int(nanosec))


def _header(seconds: float, frame: str) -> Any:
    return typestore().types["std_msgs/msg/Header"](stamp=_time(seconds), frame_id=frame)


def _stamp(header: Any, arrival: float, options: Options) -> float:
    if options.stamp == "arrival":
        return arrival
    said = header.stamp.sec + header.stamp.nanosec * 1e-9
    if said <= 0:
        raise Refused("header.stamp is 0 (not stamped): say `stamp: arrival` to stamp it here")
    return min(said, arrival)


def _finite(label: str, values: Any) -> tuple[float, ...]:
    numbers = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in numbers):
        raise Refused(f"{label} is not finite: {numbers}")
    return numbers


def _array(values: tuple[float, ...]) -> Any:
    import numpy as np

    return np.array(values, dtype=np.float64)


def _joints_to_ros(sample: JointState, stamp: float, options: Options) -> Any:
    count = len(sample.position)
    names = list(options.names) or [f"joint_{i + 1}" for i in range(count)]
    if len(names) != count:
        raise Refused(f"{count} joints, and the topology names {len(names)}")
    return typestore().types["sensor_msgs/msg/JointState"](
        header=_header(stamp, options.frame),
        name=names,
        position=_array(sample.position),
        velocity=_array(sample.velocity),
        effort=_array(sample.effort),
    )


def _joints_from_ros(message: Any, arrival: float, options: Options) -> JointState:
    names = list(message.name)
    position = _finite("position", message.position)
    columns = {"velocity": message.velocity, "effort": message.effort}
    for label, values in columns.items():
        if len(values) not in (0, len(position)):
            raise Refused(f"{len(values)} {label} values for {len(position)} positions")
    if len(names) != len(position):
        raise Refused(f"{len(names)} names for {len(position)} positions")
    order = list(range(len(position)))
    if options.names:
        missing = [n for n in options.names if n not in names]
        if missing:
            raise Refused(f"joints {missing} missing (it names {names})")
        order = [names.index(n) for n in options.names]

    def pick(values: Any, label: str) -> tuple[float, ...]:
        numbers = _finite(label, values)
        return tuple(numbers[i] for i in order) if numbers else ()

    return JointState(
        stamp=_stamp(message.header, arrival, options),
        position=tuple(position[i] for i in order),
        velocity=pick(columns["velocity"], "velocity"),
        effort=pick(columns["effort"], "effort"),
    )


def _pose_to_ros(sample: Pose, stamp: float, options: Options) -> Any:
    if not sample.valid:
        raise Refused("not valid (the tool is not seen): ROS has no invalid pose, none is sent")
    store = typestore()
    w, x, y, z = sample.orientation
    pose = store.types["geometry_msgs/msg/Pose"](
        position=store.types["geometry_msgs/msg/Point"](*sample.position),
        orientation=store.types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
    )
    return store.types["geometry_msgs/msg/PoseStamped"](
        header=_header(stamp, sample.frame or options.frame), pose=pose
    )


QUATERNION_SLACK = 1e-3
"""How far from 1 a received quaternion's norm may be (float32 round trips) before it
is refused as not a rotation; within it, it is normalised."""


def _pose_from_ros(message: Any, arrival: float, options: Options) -> Pose:
    p, q = message.pose.position, message.pose.orientation
    position = _finite("position", (p.x, p.y, p.z))
    x, y, z, w = _finite("orientation", (q.x, q.y, q.z, q.w))
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if abs(norm - 1.0) > QUATERNION_SLACK:
        raise Refused(f"orientation is not a rotation (|q| = {norm:.6g})")
    return Pose(
        position=position,  # type: ignore[arg-type]
        orientation=(w / norm, x / norm, y / norm, z / norm),
        stamp=_stamp(message.header, arrival, options),
        valid=True,
        frame=message.header.frame_id or options.frame,
        tool="ros2",
    )


def _scalar_to_ros(sample: Scalar, stamp: float, options: Options) -> Any:
    return typestore().types["std_msgs/msg/Float64"](data=float(sample.value))


def _scalar_from_ros(message: Any, arrival: float, options: Options) -> Scalar:
    (value,) = _finite("data", (message.data,))
    return Scalar(stamp=arrival, value=value)  # Float64 has no header: stamped on arrival


CONVERSIONS: dict[str, Conversion] = {
    c.ros_type: c
    for c in (
        Conversion("sensor_msgs/msg/JointState", JointState, _joints_to_ros, _joints_from_ros),
        Conversion("geometry_msgs/msg/PoseStamped", Pose, _pose_to_ros, _pose_from_ros),
        Conversion("std_msgs/msg/Float64", Scalar, _scalar_to_ros, _scalar_from_ros),
    )
}
"""The ROS types a topology may bridge, by name."""


def conversion(ros_type: str) -> Conversion:
    """The conversion for `ros_type`, else `FwError` listing the ones there are."""
    found = CONVERSIONS.get(ros_type)
    if found is None:
        known = ", ".join(f"{c.ros_type} ({type_name(c.fw_type)})" for c in CONVERSIONS.values())
        raise FwError(f"fw cannot bridge ROS type {ros_type!r} (it bridges: {known})")
    return found
