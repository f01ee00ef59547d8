"""`fw bench ros2`: the SEEG deployment seen from ROS 2 (topologies/seeg_ros2.yaml)
by zenoh-ros2-sdk, an rmw_zenoh peer written apart from fw, through a real Zenoh
router in this process (what rmw_zenohd is on a ROS machine).

What it measures, in one run:
* the rate at which a ROS node receives /joint_states (declared 100 Hz) while the
  robot waits braked, and whether each message holds the robot's joints: every
  message is matched by its stamp to a sample of robot/joints read on fw's bus;
* the latency of a PoseStamped from a ROS node's `publish` to its arrival on fw's bus
  (the bench's own session, as the navigator's process would read it): ROS node ->
  router -> the bridge process -> fw's bus;
* beside it, the same run's two hops it is made of when nothing is bridged: a ROS
  node to a ROS node through the router, and fw's own hop between two processes.
"""

from __future__ import annotations

import itertools
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from fw_bench.files import seeg_file
from fw_bench.report import Row, stats

POSE = "geometry_msgs/msg/PoseStamped"
JOINTS = "sensor_msgs/msg/JointState"


def _registry() -> None:
    from zenoh_ros2_sdk.message_registry import get_registry

    get_registry(str(seeg_file("tests", "data", "ros2_msgs")))


def _overlay(folder: Path, router_port: int) -> Path:
    """seeg_ros2.yaml with the bench's router and a pose topic fw subscribes to."""
    path = folder / "seeg_ros2_bench.yaml"
    path.write_text(
        f"extends: {seeg_file('topologies', 'seeg_ros2.yaml')}\n"
        "topology: seeg_ros2_bench\n"
        "ros2:\n"
        f"  router: tcp/127.0.0.1:{router_port}\n"
        "  subscribe:\n"
        "    - {topic: /bench/pose, type: geometry_msgs/msg/PoseStamped}\n"
    )
    return path


def _pose_kwargs(store: Any, x: float) -> dict[str, Any]:
    now = time.time()
    sec = int(now)
    header = store.types["std_msgs/msg/Header"](
        stamp=store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int((now - sec) * 1e9)),
        frame_id="bench",
    )
    pose = store.types["geometry_msgs/msg/Pose"](
        position=store.types["geometry_msgs/msg/Point"](x=x, y=0.0, z=0.0),
        orientation=store.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    return {"header": header, "pose": pose}


def echo(router_port: int) -> None:
    """A ROS node that publishes on /bench/pong each pose it receives on /bench/ping
    (`python -m fw_bench.ros2 PORT`: the far end of `ros_to_ros_hop`)."""
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber

    _registry()
    pub = ROS2Publisher(topic="/bench/pong", msg_type=POSE, router_port=router_port)
    ROS2Subscriber(
        topic="/bench/ping",
        msg_type=POSE,
        callback=lambda m: pub.publish(header=m.header, pose=m.pose),
        router_port=router_port,
    )
    print("ready", flush=True)
    sys.stdin.read()  # until the bench closes the pipe


def ros_to_ros_hop(router_port: int, count: int) -> list[float]:
    """One-way latencies (s) between two ROS nodes of two processes (zenoh-ros2-sdk
    peers of the router, as rmw_zenoh's nodes are): half of each round trip to an echo."""
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber

    child = subprocess.Popen(
        [sys.executable, "-m", "fw_bench.ros2", str(router_port)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    answered = threading.Event()
    sub = ROS2Subscriber(
        topic="/bench/pong",
        msg_type=POSE,
        callback=lambda m: answered.set(),
        router_port=router_port,
    )
    pub = ROS2Publisher(topic="/bench/ping", msg_type=POSE, router_port=router_port)
    store = pub.session_mgr.store
    hops = []
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        time.sleep(1.0)  # discovery
        for k in range(count + 20):
            answered.clear()
            sent = time.perf_counter()
            pub.publish(**_pose_kwargs(store, float(k)))
            if answered.wait(2.0) and k >= 20:
                hops.append((time.perf_counter() - sent) / 2)
    finally:
        pub.close()
        sub.close()
        child.kill()
        child.wait()
    return hops


def run(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Deploy seeg_ros2 beside a router and measure (see the module docstring)."""
    from framework.bus import free_port
    from framework.messages import JointState, Pose, decode
    from framework.ros2.router import open_router
    from fw_bench.baseline import zenoh_hop
    from fw_bench.seeg_run import SeegRun

    _registry()
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber

    port = free_port()
    router = open_router(f"tcp/127.0.0.1:{port}")
    folder = Path(tempfile.mkdtemp(prefix="fw-bench-ros2-"))
    seconds = 3.0 if quick else 10.0
    count = 100 if quick else 500
    try:
        run_ = SeegRun(
            topology_file=_overlay(folder, port), secure=context.get("bus", "mtls") == "mtls"
        )
        run_.start()
        try:
            hub = run_.deployment.hub
            fw_joints: dict[float, tuple[float, ...]] = {}
            lock = threading.Lock()

            def on_fw(sample: Any) -> None:
                joints, _, _ = decode(bytes(sample.payload.to_bytes()), JointState)
                with lock:
                    fw_joints[round(joints.stamp, 6)] = joints.position

            fw_sub = hub.subscribe("robot/joints/at_100hz", on_fw, history=False)
            ros_joints: list[tuple[float, float, list[str], tuple[float, ...]]] = []

            def on_ros(message: Any) -> None:
                stamp = message.header.stamp.sec + message.header.stamp.nanosec * 1e-9
                ros_joints.append(
                    (time.monotonic(), stamp, list(message.name), tuple(message.position))
                )

            sub = ROS2Subscriber(
                topic="/joint_states", msg_type=JOINTS, callback=on_ros, router_port=port
            )
            time.sleep(1.0)
            ros_joints.clear()
            time.sleep(seconds)
            sub.close()
            fw_sub.undeclare()
            received = list(ros_joints)
            rate = len(received) / seconds
            intervals = [(b[0] - a[0]) * 1e3 for a, b in itertools.pairwise(received)]
            with lock:
                known = dict(fw_joints)
            matched = [
                r
                for r in received
                if round(r[1], 6) in known
                and max(abs(x - y) for x, y in zip(r[3], known[round(r[1], 6)], strict=True)) < 1e-9
            ]
            names = received[0][2] if received else []

            arrivals: dict[float, float] = {}
            got = threading.Event()

            def on_pose(sample: Any) -> None:
                pose, _, _ = decode(bytes(sample.payload.to_bytes()), Pose)
                arrivals[pose.position[0]] = time.perf_counter()
                got.set()

            pose_sub = hub.subscribe("ros2/bench/pose", on_pose, history=False)
            pub = ROS2Publisher(topic="/bench/pose", msg_type=POSE, router_port=port)
            store = pub.session_mgr.store
            time.sleep(1.0)
            latencies = []
            for k in range(count + 20):
                got.clear()
                sent = time.perf_counter()
                pub.publish(**_pose_kwargs(store, float(k)))
                if got.wait(2.0) and k >= 20 and float(k) in arrivals:
                    latencies.append(arrivals[float(k)] - sent)
            pub.close()
            pose_sub.undeclare()
            from framework.remote import RemoteComponent

            work = RemoteComponent(hub, "ros2_in_bench_pose").call("report")
            ros_hops = ros_to_ros_hop(port, count)
            fw_hops = zenoh_hop(count, secure=context.get("bus", "mtls") == "mtls")
        finally:
            run_.stop()
    finally:
        router.close()
    lat = stats([x * 1e3 for x in latencies])
    ros_hop = stats([x * 1e3 for x in ros_hops])
    fw_hop = stats([x * 1e3 for x in fw_hops])
    context.setdefault("series", {})["ros2"] = {
        "joint_state_intervals_ms": intervals,
        "pose_latency_ms": [x * 1e3 for x in latencies],
    }
    print(
        f"ros2: /joint_states names {names}; {len(matched)} of {len(received)} messages "
        "hold the robot's joints of their stamp",
        flush=True,
    )
    return [
        Row(
            "ros2",
            "/joint_states rate seen by a ROS node (declared 100 Hz)",
            rate,
            unit="Hz",
            target=95.0,
            at_least=True,
            n=len(received),
        ),
        Row(
            "ros2",
            "/joint_states interval p50",
            statistics.median(intervals) if intervals else 0.0,
            n=len(intervals),
        ),
        Row(
            "ros2",
            "/joint_states interval p99",
            stats(intervals)["p99"] if intervals else 0.0,
            n=len(intervals),
        ),
        Row(
            "ros2",
            "/joint_states messages holding the robot's joints of their stamp",
            100.0 * len(matched) / max(1, len(received)),
            unit="%",
            target=100.0,
            at_least=True,
            n=len(received),
        ),
        Row(
            "ros2",
            "ROS pose -> fw's bus p50",
            lat["p50"],
            n=len(latencies),
            target=ros_hop["p50"] + fw_hop["p50"],
        ),
        Row("ros2", "ROS pose -> fw's bus p99", lat["p99"], n=len(latencies)),
        Row(
            "ros2",
            "the bridge's work per pose p50 (checks, conversion, sending)",
            work["work_p50_us"],
            unit="us",
        ),
        Row("ros2", "the bridge's work per pose p99", work["work_p99_us"], unit="us"),
        Row("ros2", "ROS node -> ROS node of another process p50", ros_hop["p50"], n=len(ros_hops)),
        Row("ros2", "fw's hop between two processes p50", fw_hop["p50"], n=len(fw_hops)),
    ]


if __name__ == "__main__":
    echo(int(sys.argv[1]))
