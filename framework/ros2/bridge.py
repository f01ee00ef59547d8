"""The components a topology's `ros2:` section becomes (framework/ros2/section.py):
one per bridged topic, in the bridge process.

* `*ToRos` (an entry of `publish:`) reads an fw output on its input `sample` (event
  activity: each sample, in its own thread) and publishes it on its ROS topic.
* `*FromRos` (an entry of `subscribe:`) receives its ROS topic in a Zenoh thread and,
  while running, writes each message that passes the checks on its output `sample`,
  which the topology connects like any other output. A message that does not pass is
  refused (`fw/refused/<component>`, kept by the flight recorder) with the reason.

One class per fw message type, because a port's type is fixed where it is declared.
rosbags (CDR) is imported on first use and the ROS session opened in `configure`, so
only the bridge process maps them: the topology loader imports this module in every
process.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, ClassVar

from framework.component import Component, In, Out, State, operation
from framework.messages import JointState, Pose, Scalar
from framework.ports import ReadStatus
from framework.properties import prop
from framework.ros2 import convert, rmw
from framework.ros2.link import DEFAULT_ROUTER, RosLink
from framework.ros2.rmw import DEFAULT_QOS, SENSOR_QOS

QOS = {"reliable": DEFAULT_QOS, "sensor": SENSOR_QOS}
"""The QoS profiles a bridge entry may name (`qos:`), as rmw_zenoh's token strings."""


class RosBridge(Component):
    """What both directions share: the ROS topic, its type, the link and the counts."""

    ROS_TYPE: ClassVar[str] = ""
    declare: Callable[[], Any]
    """Declare this entry's publisher or subscription on the ROS session (each direction
    defines it; called by `configure`)."""

    topic = prop(str, "", required=True, doc="the absolute ROS 2 topic name (/joint_states)")
    domain = prop(int, 0, min=0, max=232, doc="the ROS domain id (ROS_DOMAIN_ID)")
    router = prop(str, DEFAULT_ROUTER, doc="the ROS network's Zenoh router (rmw_zenohd)")
    node = prop(str, "fw", doc="the ROS node name fw's bridge appears as")
    qos = prop(str, "reliable", choices=sorted(QOS), doc="the QoS profile ROS tools see")
    names = prop(list, [], doc="JointState: the joint names, in fw's order")
    frame = prop(str, "", doc="frame_id where a sample or message names none")
    stamp = prop(
        str,
        "header",
        choices=["header", "arrival"],
        doc="a received message's time: its header's (never after its arrival), or arrival",
    )
    zenoh = prop(dict, {}, doc="extra Zenoh settings for the ROS session (TLS to the router)")

    def __init__(self, name: str):
        super().__init__(name)
        self._link: Any = None
        self._entity: Any = None
        self._lock = threading.Lock()
        self.counts = {"bridged": 0, "refused": 0}
        self._work: deque[float] = deque(maxlen=1000)  # s per sample crossed, the last 1000
        self.last_refusal = ""

    def configure_hook(self) -> bool:
        rmw.check_topic(self.topic)
        self._conversion = convert.conversion(self.ROS_TYPE)
        self._options = convert.Options(tuple(self.names), self.frame, self.stamp)
        self.type_hash = convert.type_hash(self.ROS_TYPE)
        self.key = rmw.topic_key(self.domain, self.topic, self.ROS_TYPE, self.type_hash)
        self._link = RosLink.acquire(self.router, self.domain, self.node, self.zenoh)
        try:
            self._entity = self.declare()
        except Exception:  # released, then raised on: configure says why it failed
            self._link.release()
            self._link = None
            raise
        return True

    def cleanup_hook(self) -> None:
        if self._entity is not None:
            self._entity.close()
            self._entity = None
        if self._link is not None:
            self._link.release()
            self._link = None

    def _refused(self, port: str, reason: str) -> None:
        self.counts["refused"] += 1
        self.last_refusal = reason
        self.refuse(port, reason)

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """The topic, its key on the ROS network, its router and whether it is linked,
        how many samples crossed or were refused (with the last reason), and the time
        the last 1000 took to cross (checks, conversion, encoding and sending; p50, p99)."""
        return {
            "topic": self.topic,
            "type": self.ROS_TYPE,
            "key": getattr(self, "key", ""),
            "router": self.router,
            "router_connected": self._link is not None and self._link.connected(),
            **self.counts,
            "last_refusal": self.last_refusal,
            **_work_us(self._work),
        }


def _work_us(work: deque[float]) -> dict[str, float]:
    ordered = sorted(work) or [0.0]

    def at(q: float) -> float:
        return 1e6 * ordered[min(len(ordered) - 1, int(q * len(ordered)))]

    return {"work_p50_us": at(0.5), "work_p99_us": at(0.99)}


class _ToRos(RosBridge):
    """Publishes each sample of its input `sample` on the ROS topic (event activity)."""

    def declare(self) -> Any:
        return self._link.publisher(
            self.topic, self.ROS_TYPE, self.type_hash, self.key, QOS[self.qos]
        )

    def update_hook(self) -> None:
        while True:
            status, sample = self.sample.read()
            if status is not ReadStatus.NEW:
                return
            stamp = self.local_stamp("sample", sample.stamp)
            if stamp is None:  # the writer's host clock is not measured yet
                stamp = time.time()
            try:
                message = self._conversion.to_ros(sample, stamp, self._options)
            except convert.Refused as exc:  # the sample has no ROS form (an unseen tool): not sent
                self.last_refusal = str(exc)
                continue
            began = time.perf_counter()
            self._entity.put(convert.serialize(message, self.ROS_TYPE), int(stamp * 1e9))
            self.counts["bridged"] += 1
            self._work.append(time.perf_counter() - began)


class _FromRos(RosBridge):
    """Writes each checked message of the ROS topic on its output `sample`."""

    def declare(self) -> Any:
        return self._link.subscribe(
            self.topic, self.ROS_TYPE, self.type_hash, self.key, QOS[self.qos], self._on_ros
        )

    def _on_ros(self, zsample: Any) -> None:
        """A message from ROS (a Zenoh thread): dropped unless running, refused unless it
        carries rmw_zenoh's attachment and passes the conversion's checks."""
        if self.state is not State.RUNNING:
            return
        arrival, began = time.time(), time.perf_counter()
        with self._lock:
            try:
                if zsample.attachment is None:
                    raise convert.Refused("no rmw_zenoh attachment (ROS nodes drop such samples)")
                rmw.Attachment.decode(zsample.attachment.to_bytes())
                message = convert.deserialize(zsample.payload.to_bytes(), self.ROS_TYPE)
                value = self._conversion.from_ros(message, arrival, self._options)
            except (convert.Refused, rmw.RmwError) as exc:
                self._refused("sample", f"{self.topic}: {exc}")
                return
            self.sample.write(value)
            self.counts["bridged"] += 1
            self._work.append(time.perf_counter() - began)


class JointStateToRos(_ToRos):
    """fw JointState -> sensor_msgs/msg/JointState."""

    ROS_TYPE = "sensor_msgs/msg/JointState"
    sample = In(JointState, doc="the joints to publish", policy={"type": "buffer", "size": 16})


class PoseToRos(_ToRos):
    """fw Pose -> geometry_msgs/msg/PoseStamped (an invalid pose, an unseen tool, is not
    sent: ROS has no invalid pose)."""

    ROS_TYPE = "geometry_msgs/msg/PoseStamped"
    sample = In(Pose, doc="the pose to publish", policy={"type": "buffer", "size": 16})


class ScalarToRos(_ToRos):
    """fw Scalar -> std_msgs/msg/Float64 (its value; Float64 has no stamp)."""

    ROS_TYPE = "std_msgs/msg/Float64"
    sample = In(Scalar, doc="the number to publish", policy={"type": "buffer", "size": 16})


class JointStateFromRos(_FromRos):
    """sensor_msgs/msg/JointState -> fw JointState, in the order of `names`."""

    ROS_TYPE = "sensor_msgs/msg/JointState"
    sample = Out(JointState, doc="the joints a ROS node published")


class PoseFromRos(_FromRos):
    """geometry_msgs/msg/PoseStamped -> fw Pose (valid, normalised)."""

    ROS_TYPE = "geometry_msgs/msg/PoseStamped"
    sample = Out(Pose, doc="the pose a ROS node published")


class ScalarFromRos(_FromRos):
    """std_msgs/msg/Float64 -> fw Scalar, stamped on arrival."""

    ROS_TYPE = "std_msgs/msg/Float64"
    sample = Out(Scalar, doc="the number a ROS node published")


TO_ROS: dict[str, type[RosBridge]] = {
    c.ROS_TYPE: c for c in (JointStateToRos, PoseToRos, ScalarToRos)
}
FROM_ROS: dict[str, type[RosBridge]] = {
    c.ROS_TYPE: c for c in (JointStateFromRos, PoseFromRos, ScalarFromRos)
}
