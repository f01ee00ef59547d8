"""`fw ros2`: what a topology bridges to ROS 2, and a router for ROS nodes where
rmw_zenohd does not run (docs/ros2.md)."""

from __future__ import annotations

import argparse
from typing import Any

EPILOG = """examples:
  fw ros2 topics topologies/seeg_ros2.yaml     the topics, types, keys and type hashes
  fw ros2 router                              a router on tcp/127.0.0.1:7447 (rmw_zenohd's port)
  fw ros2 router --listen tcp/127.0.0.1:7500

A ROS 2 machine with rmw_zenoh runs its own router (ros2 run rmw_zenoh_cpp rmw_zenohd);
fw's bridge connects to it (the topology's ros2: router:) and, through it, to each ROS
node, listening on no port itself. docs/ros2.md."""


def add_commands(sub: Any) -> None:
    """Register `fw ros2 topics` and `fw ros2 router`."""
    p = sub.add_parser(
        "ros2",
        help="ROS 2 topics of a topology; a Zenoh router for ROS nodes",
        description="fw publishes outputs to ROS 2 and reads ROS 2 topics over rmw_zenoh, "
        "as a topology's ros2: section says, without ROS installed.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    what = p.add_subparsers(dest="ros2_command", metavar="WHAT", required=True)
    topics = what.add_parser("topics", help="the topics a topology bridges, with keys and hashes")
    topics.add_argument("topology", metavar="TOPOLOGY", help="a topology YAML")
    topics.set_defaults(func=cmd_topics)
    router = what.add_parser("router", help="run a Zenoh router for ROS 2 nodes (no ROS needed)")
    router.add_argument(
        "--listen",
        default="tcp/127.0.0.1:7447",
        metavar="ENDPOINT",
        help="where it listens (default tcp/127.0.0.1:7447, loopback only)",
    )
    router.set_defaults(func=cmd_router)


def cmd_topics(args: argparse.Namespace) -> int:
    """Print each bridged topic: direction, fw side, ROS type, data key."""
    from framework.ros2 import convert, rmw
    from framework.ros2.bridge import RosBridge
    from framework.topology import load_topology

    topo = load_topology(args.topology)
    rows = []
    for name, spec in topo.components.items():
        if spec.info is None or not issubclass(spec.info.cls, RosBridge):
            continue
        cls = spec.info.cls
        props = spec.properties
        ros_type = cls.ROS_TYPE
        key = rmw.topic_key(
            props.get("domain", 0), props["topic"], ros_type, convert.type_hash(ros_type)
        )
        if "sample" in spec.info.outputs:
            fw_side = f"{name}.sample -> {spec.output_key('sample')}"
            direction = "from ROS"
        else:
            readers = [s for s in topo.connections if s.component == name]
            fw_side = f"{readers[0].key} -> {name}.sample" if readers else name
            direction = "to ROS"
        rows.append((direction, props["topic"], ros_type, fw_side, key, spec.process))
    if not rows:
        print(f"{args.topology}: no ros2: section, nothing is bridged")
        return 0
    for direction, topic, ros_type, fw_side, key, process in rows:
        print(
            f"{direction:8} {topic}  {ros_type}\n         fw: {fw_side} (process {process})\n"
            f"         key: {key}"
        )
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    """Run the router until Ctrl-C."""
    from framework.ros2.router import run_router

    return run_router(args.listen)
