"""fw's records and samples as Foxglove's well-known messages (issue 48), so Foxglove
shows a flight recording as a log and a 3D scene without knowing fw's own schemas.

Encoded by Foxglove's SDK (`foxglove.messages`, protobuf), not by hand. Imported only
where recording happens (the control process): every library a safety process maps
lengthens its crash detection, and none of them records.

* every record `fw log` prints -> `foxglove.Log` on `/fw/log`, with the same line
  (`framework/timeline.py`); refusals, faults and failed steps as warnings or errors;
* a `JointState` sample -> `foxglove.JointStates` (joints `a1`..`a7`);
* a `Pose` sample -> `foxglove.FrameTransforms`: the pose's frame (or `world`) as the
  parent, the recorded key as the child (`certus/cto`: the tool the Certus sees);
* an `Envelopes` sample -> `foxglove.SceneUpdate`: each person's capsule as a
  cylinder between two spheres, in the robot's base frame;
* any sample a topology's drawing function (`record:` `draw:`) turns into `Shapes`
  (frames, capsules, spheres in plain numbers: the function needs no Foxglove) ->
  `foxglove.FrameTransforms` on `/tf` and a `foxglove.SceneUpdate` on
  `/scene/<key>`: a procedure's goals and critical area, a robot's link capsules.

The frame a sample is in comes from the topology's `record:` entry (`frame:`) where
the sample does not say it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from framework.messages import Envelopes, JointState, Pose

LOG_TOPIC = "/fw/log"
BASE_FRAME = "base"
"""The frame envelopes are in (the robot's base, as the people detector gives them)."""

WARNING_WORDS = ("REFUSED", "unhandled", "FAILED", "refused", "error", "Exception", "lost")
"""A timeline line with one of these is a warning in Foxglove's log panel."""


@dataclass(frozen=True)
class Converted:
    """One Foxglove message: its schema's name, the schema (protobuf descriptors) and
    the encoded message."""

    schema_name: str
    schema: bytes
    data: bytes


def _stamp(seconds: float) -> Any:
    from foxglove.messages import Timestamp

    seconds = max(seconds, 0.0) if math.isfinite(seconds) else 0.0
    whole = int(seconds)
    return Timestamp(sec=whole, nsec=min(round((seconds - whole) * 1e9), 999_999_999))


def _converted(message: Any) -> Converted:
    schema = type(message).get_schema()
    return Converted(schema.name, bytes(schema.data), bytes(message.encode()))


def log(stamp: float, line: str, name: str = "fw") -> Converted:
    """A timeline line (as `fw log` prints it) as a Foxglove Log."""
    from foxglove.messages import Log, LogLevel

    level = LogLevel.Warning if any(w in line for w in WARNING_WORDS) else LogLevel.Info
    return _converted(Log(timestamp=_stamp(stamp), level=level, message=line, name=name))


def joint_states(sample: JointState, key: str, parent: str = "") -> Converted:
    """The arm's joints (a1..a7: KUKA's axis names) with velocity and effort if given."""
    from foxglove.messages import JointState as FoxJoint
    from foxglove.messages import JointStates

    def at(values: tuple[float, ...], i: int) -> float | None:
        return float(values[i]) if i < len(values) else None

    joints = [
        FoxJoint(
            name=f"a{i + 1}",
            position=float(q),
            velocity=at(sample.velocity, i),
            effort=at(sample.effort, i),
        )
        for i, q in enumerate(sample.position)
    ]
    return _converted(JointStates(timestamp=_stamp(sample.stamp), joints=joints))


def frame_transforms(sample: Pose, key: str, parent: str = "") -> Converted:
    """The pose as the transform from `parent` (else its own frame, else `world`) to a
    frame named `key`.
    fw's quaternions are (w, x, y, z); Foxglove's fields are named, so no reordering
    is left to chance."""
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Vector3

    w, x, y, z = (float(v) for v in sample.orientation)
    transform = FrameTransform(
        timestamp=_stamp(sample.stamp),
        parent_frame_id=parent or sample.frame or "world",
        child_frame_id=key,
        translation=Vector3(x=sample.position[0], y=sample.position[1], z=sample.position[2]),
        rotation=Quaternion(x=x, y=y, z=z, w=w),
    )
    return _converted(FrameTransforms(transforms=[transform]))


Link = tuple[str, str, tuple[float, float, float], tuple[float, float, float, float]]
"""(parent, child, position, quaternion (w, x, y, z)) of one link's frame in its parent."""
Point = tuple[float, float, float]
Rgba = tuple[float, float, float, float]


@dataclass(frozen=True)
class Shapes:
    """What a topology's drawing function (`record:` `draw: module:function`) makes of
    one sample, in plain numbers: frames (drawn as transforms, each in its parent),
    and capsules (segment a-b, radius) and spheres (centre, radius) in `frame`, one
    scene entity per recorded key, replaced whole at each sample."""

    frames: tuple[Link, ...] = ()
    capsules: tuple[tuple[Point, Point, float], ...] = ()
    spheres: tuple[tuple[Point, float], ...] = ()
    frame: str = BASE_FRAME
    color: Rgba = (0.2, 0.6, 1.0, 0.4)


def link_transforms(
    sample: JointState, links: Callable[[tuple[float, ...]], list[Link]]
) -> Converted:
    """A robot's links as transforms, each in the one before it, from its joints by
    `links` (the robot's own kinematics, named by the topology: framework/ knows no
    robot)."""
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Vector3

    transforms = [
        FrameTransform(
            timestamp=_stamp(sample.stamp),
            parent_frame_id=parent,
            child_frame_id=child,
            translation=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            rotation=Quaternion(w=float(q[0]), x=float(q[1]), y=float(q[2]), z=float(q[3])),
        )
        for parent, child, p, q in links(tuple(sample.position))
    ]
    return _converted(FrameTransforms(transforms=transforms))


def people(sample: Envelopes, key: str, parent: str = "") -> Converted:
    """Each person's capsules (segment a-b, radius) as a cylinder and two end spheres,
    one entity per recorded key, replaced whole at each sample."""
    from foxglove.messages import SceneUpdate

    capsules = [
        (tuple(sample.a[3 * i : 3 * i + 3]), tuple(sample.b[3 * i : 3 * i + 3]), radius)
        for i, radius in enumerate(sample.radius)
    ]
    entity = _entity(sample.stamp, parent or BASE_FRAME, key, capsules, (), PEOPLE_COLOR)
    return _converted(SceneUpdate(entities=[entity]))


PEOPLE_COLOR: Rgba = (1.0, 0.5, 0.1, 0.6)


def shapes(stamp: float, key: str, drawn: Shapes) -> list[tuple[str, Converted]]:
    """A drawing function's `Shapes` as Foxglove messages: (topic, message) for its
    frames (`/tf`) and its capsules and spheres (`/scene/<key>`), those it has."""
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, SceneUpdate, Vector3

    out = []
    if drawn.frames:
        transforms = [
            FrameTransform(
                timestamp=_stamp(stamp),
                parent_frame_id=parent,
                child_frame_id=child,
                translation=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                rotation=Quaternion(w=float(q[0]), x=float(q[1]), y=float(q[2]), z=float(q[3])),
            )
            for parent, child, p, q in drawn.frames
        ]
        out.append(("/tf", _converted(FrameTransforms(transforms=transforms))))
    if drawn.capsules or drawn.spheres:
        entity = _entity(stamp, drawn.frame, key, drawn.capsules, drawn.spheres, drawn.color)
        out.append((f"/scene/{key}", _converted(SceneUpdate(entities=[entity]))))
    return out


def _entity(
    stamp: float,
    frame: str,
    key: str,
    capsules: Any,
    spheres: Any,
    rgba: Rgba,
) -> Any:
    """One scene entity: each capsule as a cylinder between two spheres, and spheres."""
    from foxglove.messages import (
        Color,
        CylinderPrimitive,
        Quaternion,
        SceneEntity,
        SpherePrimitive,
        Vector3,
    )
    from foxglove.messages import Pose as FoxPose

    color = Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])

    def ball(centre: Any, radius: float) -> Any:
        return SpherePrimitive(
            pose=FoxPose(
                position=Vector3(x=float(centre[0]), y=float(centre[1]), z=float(centre[2]))
            ),
            size=Vector3(x=2 * radius, y=2 * radius, z=2 * radius),
            color=color,
        )

    cylinders, balls = [], [ball(c, float(r)) for c, r in spheres]
    for a, b, radius in capsules:
        radius = float(radius)
        balls += [ball(a, radius), ball(b, radius)]
        axis = [float(b[k]) - float(a[k]) for k in range(3)]
        length = math.sqrt(sum(v * v for v in axis))
        if length < 1e-9:
            continue
        middle = Vector3(
            x=(float(a[0]) + float(b[0])) / 2,
            y=(float(a[1]) + float(b[1])) / 2,
            z=(float(a[2]) + float(b[2])) / 2,
        )
        cylinders.append(
            CylinderPrimitive(
                pose=FoxPose(position=middle, orientation=_z_to(axis, length, Quaternion)),
                size=Vector3(x=2 * radius, y=2 * radius, z=length),
                bottom_scale=1.0,
                top_scale=1.0,
                color=color,
            )
        )
    return SceneEntity(
        timestamp=_stamp(stamp), frame_id=frame, id=key, cylinders=cylinders, spheres=balls
    )


def _z_to(axis: list[float], length: float, quaternion: Any) -> Any:
    """The rotation taking +z onto `axis` (a cylinder's axis is its z): about z x axis by
    the angle between them (atan2: exact also next to -z, where 1 + cos loses it)."""
    ux, uy, uz = (v / length for v in axis)
    across = math.hypot(ux, uy)  # |z x u|
    angle = math.atan2(across, uz)
    if across < 1e-12:  # along z (no turn) or against it (half a turn, about x)
        ex, ey = 1.0, 0.0
    else:
        ex, ey = -uy / across, ux / across
    half = math.sin(angle / 2)
    return quaternion(x=ex * half, y=ey * half, z=0.0, w=math.cos(angle / 2))


CONVERTERS: dict[type, Callable[[Any, str, str], Converted]] = {
    JointState: joint_states,
    Pose: frame_transforms,
    Envelopes: people,
}
"""Sample types Foxglove can draw, and how: (sample, recorded key, frame it is in)."""

TOPICS: dict[type, str] = {JointState: "/joint_states", Pose: "/tf", Envelopes: "/people"}
"""Where each kind goes: transforms share one topic (`/tf`) as Foxglove expects; the
others are per recorded key under these prefixes."""


def topic_for(kind: type, key: str) -> str:
    """The Foxglove topic a sample of `kind` recorded from `key` goes to."""
    return TOPICS[kind] if kind is Pose else f"{TOPICS[kind]}/{key}"
