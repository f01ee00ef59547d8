"""What the robot side looks like in Foxglove: drawing functions a topology names in
its `record:` entries (`draw: module:function`, framework/scene.py), run by the flight
recorder in the control process, never in the robot's.

* `arm_capsules`: the arm's collision capsules (the ones speed and separation
  monitoring measures people against) from its joints;
* `goals`: each goal of the procedure where the navigator says it is now, as a
  frame `goal/<name>` in the robot's base, and the critical area around the target
  (the sphere in which the Supervisor slows the approach, eq. 3.11).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from components.domain.geometry import matrix_to_quat, pose_from_list
from components.domain.lwr4 import Kinematics
from framework.messages import EventMessage, JointState
from framework.scene import Shapes

ARM_COLOR = (0.6, 0.6, 0.65, 0.5)
CRITICAL_COLOR = (1.0, 0.2, 0.2, 0.25)
_kinematics: Kinematics | None = None


def arm_capsules(sample: JointState) -> Shapes:
    """The arm's collision capsules in its base frame for the sample's joints."""
    global _kinematics
    if _kinematics is None:  # Pinocchio's model: built once, on the first sample
        _kinematics = Kinematics()
    capsules = _kinematics.capsules(np.asarray(sample.position, dtype=float))
    return Shapes(
        capsules=tuple(
            (tuple(a.tolist()), tuple(b.tolist()), float(r))
            for a, b, r in zip(capsules.a, capsules.b, capsules.radius, strict=True)
        ),
        color=ARM_COLOR,
    )


def goals(sample: EventMessage) -> Shapes:
    """The navigator's goals (its `goals` output: base frame) as frames, and the
    critical area around the target where its report gives the radius."""
    payload: dict[str, Any] = sample.payload or {}
    frames = []
    for name, pose in sorted((payload.get("goals") or {}).items()):
        m = pose_from_list(pose)
        frames.append(("base", f"goal/{name}", tuple(m[:3, 3].tolist()), matrix_to_quat(m[:3, :3])))
    spheres = []
    target = (payload.get("goals") or {}).get("target")
    radius = payload.get("critical_radius")
    if target is not None and radius:
        spheres.append((tuple(float(v) for v in pose_from_list(target)[:3, 3]), float(radius)))
    return Shapes(frames=tuple(frames), spheres=tuple(spheres), color=CRITICAL_COLOR)
