"""A topology's `ros2:` section, written out as what fw already knows: one bridge
component per topic (framework/ros2/bridge.py) in the bridge's process, and the
connections that feed them. After this, the loader checks them as it checks any
component and connection (types, unknown ports, rates), the process gets its
certificate from `fw keys` and its access rules from the topology, and a lost bridge
process stops the robot like any other. Every written-out entry keeps the place of
the `ros2:` entry it came from, so a finding about it names that file and line.

    ros2:
      publish:   [{from: robot.joints, topic: /joint_states, type: sensor_msgs/msg/JointState}]
      subscribe: [{topic: /tracker/pose, type: geometry_msgs/msg/PoseStamped, to: navigator.cto}]

becomes `ros2_out_joint_states` (a `JointStateToRos` reading robot.joints) and
`ros2_in_tracker_pose` (a `PoseFromRos` whose output `sample` feeds navigator.cto).
"""

from __future__ import annotations

from typing import Any

from framework.errors import Finding
from framework.ros2.bridge import FROM_ROS, TO_ROS
from framework.ros2.link import DEFAULT_ROUTER
from framework.yamlio import Document

DEFAULT_PROCESS = "ros2"


def component_name(direction: str, topic: str) -> str:
    """The default name of a topic's bridge component: `ros2_out_joint_states`."""
    return f"ros2_{direction}_{topic.strip('/').replace('/', '_')}"


def output_key(topic: str) -> str:
    """Where a subscribed topic's samples go on fw's bus: `ros2/tracker/pose`."""
    return f"ros2/{topic.strip('/')}"


def expand(doc: Document) -> list[Finding]:
    """Write `doc`'s `ros2:` section out into its components, processes and
    connections (in place; the schema has checked the section's shape). The findings
    are what cannot be written out (a name taken twice)."""
    data = doc.data
    section = data.get("ros2")
    if not section:
        return []
    findings: list[Finding] = []
    process = section.get("process", DEFAULT_PROCESS)
    common = {
        "router": section.get("router", DEFAULT_ROUTER),
        "domain": section.get("domain", 0),
        "node": section.get("node", f"fw_{data.get('topology', 'fw')}"),
    }
    if section.get("zenoh"):
        common["zenoh"] = section["zenoh"]
    components = data.setdefault("components", {})
    processes = data.get("processes")
    if processes and process not in processes:
        processes[process] = {"on_loss": "restart"}  # a bridge holds no state of its own
        _alias(doc, ("processes", process), ("ros2",))
    connections = data.setdefault("connections", [])

    def add(where: tuple[Any, ...], name: str, spec: dict[str, Any]) -> bool:
        if name in components:
            findings.append(
                Finding(
                    "error",
                    "ros2-name",
                    f"the bridge of {spec['properties']['topic']} would be component "
                    f"{name!r}, which the topology already has",
                    doc.location(where),
                    "give the entry a `name:` of its own",
                )
            )
            return False
        components[name] = spec
        _alias(doc, ("components", name), where)
        return True

    def connect(where: tuple[Any, ...], connection: dict[str, Any]) -> None:
        _alias(doc, ("connections", len(connections)), where)
        connections.append(connection)

    def spec(entry: dict[str, Any], cls: type, **more: Any) -> dict[str, Any]:
        return {
            "class": f"{cls.__module__}:{cls.__name__}",
            "process": process,
            "properties": {**common, **_options(entry)},
            "initial": "running",
            **more,
        }

    for i, entry in enumerate(section.get("publish") or []):
        where = ("ros2", "publish", i)
        name = entry.get("name") or component_name("out", entry["topic"])
        if add(where, name, spec(entry, TO_ROS[entry["type"]], activity={"event": ["sample"]})):
            connection = {"port": f"{name}.sample", "from": entry["from"]}
            if "rate" in entry:
                connection["rate"] = entry["rate"]
            connect(where, connection)
    for i, entry in enumerate(section.get("subscribe") or []):
        where = ("ros2", "subscribe", i)
        name = entry.get("name") or component_name("in", entry["topic"])
        outputs = {"sample": output_key(entry["topic"])}
        if add(where, name, spec(entry, FROM_ROS[entry["type"]], outputs=outputs)):
            targets = entry.get("to") or []
            for port in [targets] if isinstance(targets, str) else targets:
                connect(where, {"port": port, "from": f"{name}.sample"})
    return findings


def _options(entry: dict[str, Any]) -> dict[str, Any]:
    wanted = ("topic", "names", "frame", "stamp", "qos")
    return {k: entry[k] for k in wanted if k in entry}


def _alias(doc: Document, path: tuple[Any, ...], where: tuple[Any, ...]) -> None:
    """Give the written-out value at `path` the place and the path of the entry it
    came from."""
    probe = where
    while probe and probe not in doc.marks:
        probe = probe[:-1]
    if probe in doc.marks:
        doc.marks[path] = doc.marks[probe]
        if probe in doc.origins:
            doc.origins[path] = doc.origins[probe]
    doc.written[path] = where
