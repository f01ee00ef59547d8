"""Spec: a deployment with a `ros2:` section talks to ROS 2 nodes through a real Zenoh
router, both ways, as zenoh-ros2-sdk (an rmw_zenoh peer written apart from fw) sees
it: fw's outputs arrive on their topics, ROS topics arrive on fw's bus, the bridge
appears in the ROS graph, and what a ROS node sends wrong is refused and counted,
never passed on."""

import contextlib
import itertools
import math
import shutil
import time
from typing import Any

import pytest
import zenoh

from framework.bus import BusConfig, free_port
from framework.deployer import Deployment
from framework.messages import Pose
from framework.remote import RemoteComponent
from framework.ros2 import convert, rmw
from framework.ros2.router import open_router
from tests.conftest import REPO, drained, join_deployment, private_topology, reader_port, wait_until
from tests.support.ros2 import pose_stamped, ros_time, sdk_registry, sdk_type_hash

TOY = REPO / "tests" / "data" / "toy"
POSE = "geometry_msgs/msg/PoseStamped"


def toy_bridged(folder, router_port: int):
    shutil.copy(TOY / "toy_chart.yaml", folder / "toy_chart.yaml")
    path = folder / "toy.yaml"
    path.write_text(
        (TOY / "toy.yaml").read_text() + f"ros2:\n  router: tcp/127.0.0.1:{router_port}\n"
        "  publish:\n    - {from: t1.out, topic: /fw/count, type: std_msgs/msg/Float64}\n"
        "    - {from: ros2_in_ros_joints.sample, topic: /fw/joints, type: sensor_msgs/msg/JointState,"
        " names: [a, b, c]}\n"
        "    - {from: ros2_in_ros_pose.sample, topic: /fw/pose, type: geometry_msgs/msg/PoseStamped}\n"
        "    - {from: ros2_in_ros_number.sample, topic: /fw/number, type: std_msgs/msg/Float64}\n"
        "  subscribe:\n    - {topic: /ros/pose, type: geometry_msgs/msg/PoseStamped}\n"
        "    - {topic: /ros/joints, type: sensor_msgs/msg/JointState, names: [a, b, c]}\n"
        "    - {topic: /ros/number, type: std_msgs/msg/Float64}\n"
    )
    return path


@pytest.fixture(scope="module")
def ros(tmp_path_factory):
    """A router, the toy deployment bridged to it, and an operator session on fw's bus."""
    folder = tmp_path_factory.mktemp("ros2")
    port = free_port()
    router = open_router(f"tcp/127.0.0.1:{port}")
    bus = BusConfig(namespace=f"t_ros2_{free_port()}", hub_port=free_port())
    deployment = Deployment(private_topology(toy_bridged(folder, port), bus), folder / "run")
    deployment.start()
    operator = join_deployment(deployment.topology.bus)
    sdk_registry()
    try:
        yield port, deployment, operator
    finally:
        operator.close()
        deployment.stop()
        router.close()


def client(port: int):
    """A plain Zenoh client of the router, as a node that ignores rmw_zenoh's rules."""
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
    return zenoh.open(config)


def test_a_ros_node_reads_an_fw_output_on_its_topic(ros):
    from zenoh_ros2_sdk import ROS2Subscriber

    port, _, _ = ros
    got: list[float] = []
    sub = ROS2Subscriber(
        topic="/fw/count",
        msg_type="std_msgs/msg/Float64",
        callback=lambda m: got.append(m.data),
        router_port=port,
    )
    try:
        assert wait_until(lambda: len(got) >= 5, timeout=10), "the counter's values arrive"
        assert all(b == a + 1.0 for a, b in itertools.pairwise(got)), got
    finally:
        sub.close()


def test_a_ros_pose_reaches_fws_bus_checked_and_stamped(ros):
    from zenoh_ros2_sdk import ROS2Publisher

    port, _, operator = ros
    port_in = reader_port(operator, "ros2/ros/pose", Pose)
    pub = ROS2Publisher(topic="/ros/pose", msg_type=POSE, router_port=port)
    try:
        store = pub.session_mgr.store
        seen: list = []

        def arrived():
            pub.publish(**pose_stamped(store, (0.1, 0.2, 0.3), (0.0, 0.0, 0.0, 1.0)))
            seen.extend(drained(port_in))
            return bool(seen)

        assert wait_until(arrived, timeout=10, interval=0.1)
        pose = seen[-1]
        assert pose.position == (0.1, 0.2, 0.3) and pose.orientation == (1.0, 0.0, 0.0, 0.0)
        assert pose.valid and pose.frame == "map" and pose.stamp <= time.time()
    finally:
        pub.close()


def test_the_bridge_is_a_node_with_its_publisher_and_subscription_in_the_ros_graph(ros):
    port, _, _ = ros
    session = client(port)
    try:
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**")]
    finally:
        session.close()
    assert any(t.endswith("/NN/%/%/fw_toy") for t in tokens), tokens
    float64 = f"std_msgs::msg::dds_::Float64_/{sdk_type_hash('std_msgs/msg/Float64')}"
    assert any(f"/MP/%/%/fw_toy/%fw%count/{float64}/" in t for t in tokens), tokens
    pose = f"geometry_msgs::msg::dds_::PoseStamped_/{sdk_type_hash(POSE)}"
    assert any(f"/MS/%/%/fw_toy/%ros%pose/{pose}/" in t for t in tokens), tokens


def test_what_a_ros_node_sends_wrong_is_refused_counted_and_never_passed_on(ros):
    port, deployment, operator = ros
    bridge = RemoteComponent(deployment.hub, "ros2_in_ros_pose")
    port_in = reader_port(operator, "ros2/ros/pose", Pose)
    before = bridge.call("report")["refused"]
    key = rmw.topic_key(0, "/ros/pose", POSE, convert.type_hash(POSE))
    c = convert.conversion(POSE)
    good = c.to_ros(
        Pose((1.0, 0, 0), (1, 0, 0, 0), time.time(), valid=True), time.time(), convert.Options()
    )
    nan = c.to_ros(
        Pose((1.0, 0, 0), (1, 0, 0, 0), time.time(), valid=True), time.time(), convert.Options()
    )
    nan.pose.position.y = math.nan
    attachment = rmw.Attachment(1, time.time_ns(), b"\x07" * 16).encode()
    session = client(port)
    try:
        publisher = session.declare_publisher(key)
        time.sleep(0.5)  # the router learns of the bridge's subscriber
        drained(port_in)  # the last pose of an earlier spec, which fw's bus keeps
        publisher.put(convert.serialize(good, POSE))  # no attachment
        publisher.put(b"\x00\x01\x00\x00garbage", attachment=attachment)
        publisher.put(convert.serialize(nan, POSE), attachment=attachment)
        assert wait_until(lambda: bridge.call("report")["refused"] - before == 3, timeout=10), (
            bridge.call("report")
        )
        time.sleep(0.3)
        assert drained(port_in) == [], "nothing refused reached fw's bus"
        publisher.put(convert.serialize(good, POSE), attachment=attachment)
        assert wait_until(lambda: drained(port_in) != [], timeout=10), "a good one still passes"
    finally:
        session.close()
    assert "not finite" in bridge.call("report")["last_refusal"]


def test_without_the_ros_router_fw_runs_and_the_bridge_says_it_is_not_linked(tmp_path):
    """fw's own functions never wait on ROS: the deployment comes up, the bridge reports
    its router unlinked and its process log says where it looked; a router that starts
    later is linked by itself."""
    port = free_port()  # nothing listens there
    bus = BusConfig(namespace=f"t_ros2_none_{free_port()}", hub_port=free_port())
    deployment = Deployment(private_topology(toy_bridged(tmp_path, port), bus), tmp_path / "run")
    deployment.start()
    try:
        report = RemoteComponent(deployment.hub, "ros2_out_fw_count").call("report")
        assert report["router"] == f"tcp/127.0.0.1:{port}" and not report["router_connected"]
        log = next(p for p in deployment.processes if p.name == "ros2").tail(20)
        assert f"no ROS 2 router answers at tcp/127.0.0.1:{port}" in log, log
        router = open_router(f"tcp/127.0.0.1:{port}")  # ROS starts after fw
        try:
            bridge = RemoteComponent(deployment.hub, "ros2_out_fw_count")
            assert wait_until(lambda: bridge.call("report")["router_connected"], timeout=10)
        finally:
            router.close()
    finally:
        deployment.stop()


def echoed_by_fw(port: int, into: str, out: str, ros_type: str, message: dict) -> Any:
    """Publish `message` on ROS topic `into` until fw, which reads it and publishes it
    again on `out` (through the bridge process and fw's bus), sends it back; what came."""
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber

    echoed: list = []
    sub = ROS2Subscriber(topic=out, msg_type=ros_type, callback=echoed.append, router_port=port)
    pub = ROS2Publisher(topic=into, msg_type=ros_type, router_port=port)
    try:

        def send():
            pub.publish(**message)
            return bool(echoed)

        assert wait_until(send, timeout=10, interval=0.1), f"nothing came back on {out}"
    finally:
        pub.close()
        sub.close()
    return echoed[-1]


def sdk_store() -> Any:
    """The SDK's own type store (its messages are built from the .msg files)."""
    from zenoh_ros2_sdk.session import ZenohSession

    return ZenohSession.get_instance().store


def test_joints_cross_both_ways_by_name_through_fws_bus(ros):
    """A ROS node's joints, in an order of its own, enter fw in fw's order and go back
    out to ROS under fw's names."""
    import numpy as np

    port, _, _ = ros
    store = sdk_store()
    header = store.types["std_msgs/msg/Header"](stamp=ros_time(store, time.time()), frame_id="")
    message = echoed_by_fw(
        port,
        "/ros/joints",
        "/fw/joints",
        "sensor_msgs/msg/JointState",
        {
            "header": header,
            "name": ["c", "a", "b"],
            "position": np.array([3.0, 1.0, 2.0]),
            "velocity": np.array([], dtype=float),
            "effort": np.array([], dtype=float),
        },
    )
    assert list(message.name) == ["a", "b", "c"]
    assert list(message.position) == [1.0, 2.0, 3.0]


def test_a_pose_crosses_both_ways_with_its_stamp_and_frame(ros):
    port, _, _ = ros
    store = sdk_store()
    stamp = time.time() - 0.25
    sent = pose_stamped(store, (0.5, -0.25, 2.0), (0.0, 0.6, 0.0, 0.8), stamp=stamp, frame="cam")
    message = echoed_by_fw(port, "/ros/pose", "/fw/pose", POSE, sent)
    p, q = message.pose.position, message.pose.orientation
    assert (p.x, p.y, p.z) == (0.5, -0.25, 2.0)
    assert (q.x, q.y, q.z, q.w) == pytest.approx((0.0, 0.6, 0.0, 0.8), abs=1e-12)
    assert message.header.frame_id == "cam"
    back = message.header.stamp.sec + message.header.stamp.nanosec * 1e-9
    assert back == pytest.approx(stamp, abs=1e-6), "the header's stamp, not the arrival's"


def test_a_float64_crosses_both_ways(ros):
    port, _, _ = ros
    message = echoed_by_fw(port, "/ros/number", "/fw/number", "std_msgs/msg/Float64", {"data": 2.5})
    assert message.data == 2.5


def listening_ports(pid: int) -> set[int]:
    """The TCP ports process `pid` listens on (its socket inodes in /proc/net/tcp)."""
    import os

    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        with contextlib.suppress(OSError):
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    ports = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as rows:
            for row in list(rows)[1:]:
                fields = row.split()
                if fields[3] == "0A" and fields[9] in inodes:  # LISTEN
                    ports.add(int(fields[1].rsplit(":", 1)[1], 16))
    return ports


def test_the_bridge_listens_on_no_port_of_the_ros_network(ros):
    """Its only listening port is the one every fw process has (fw's bus: mutual TLS);
    the ROS side connects out, to the router and to the nodes it learns of there."""
    _, deployment, _ = ros
    counts = {p.name: len(listening_ports(p.popen.pid)) for p in deployment.processes}
    assert counts["ros2"] == counts["trackers"] == 1, counts
