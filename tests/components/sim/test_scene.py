"""Spec: the simulated OR places the trackers and cameras where they can see the work."""

import numpy as np

from components.sim.arm import SimulatedArm
from components.sim.scene import Scene


def test_trackers_and_cameras_stand_above_the_floor_and_face_the_target():
    arm = SimulatedArm()
    model, data = arm.model, arm.data
    target = np.array(Scene().target)
    for name in ("certus", "vicra", "kinect_0", "kinect_1"):
        body = model.body(name).id
        position = data.xpos[body]
        axis = data.xmat[body].reshape(3, 3)[:, 2]  # each sensor looks along its z
        to_target = (target - position) / np.linalg.norm(target - position)
        assert position[2] > model.geom("floor").pos[2] + 1.0, name
        assert axis @ to_target > np.cos(np.radians(35)), f"{name} looks away from the target"
