"""Spec: what the robot side looks like in Foxglove (components/robot/drawing.py): the
arm's collision capsules are the ones speed and separation monitoring measures, and
the navigator's goals are frames in the base with the critical area around the target."""

import numpy as np
import pytest

from components.domain.geometry import pose_list
from components.domain.lwr4 import Kinematics
from components.robot import drawing
from framework.messages import EventMessage, JointState


def test_the_arms_capsules_are_its_separation_capsules():
    q = (0.3, -0.5, 0.2, 1.1, -0.4, 0.7, 0.1)
    drawn = drawing.arm_capsules(JointState(1.0, q))
    model = Kinematics().capsules(np.array(q))
    assert len(drawn.capsules) == len(model.radius) > 0
    for (a, b, r), ma, mb, mr in zip(drawn.capsules, model.a, model.b, model.radius, strict=True):
        assert a == pytest.approx(tuple(ma)) and b == pytest.approx(tuple(mb)) and r == mr
    assert drawn.frame == "base"


def goals(payload):
    return drawing.goals(EventMessage(2.0, "goals", "navigator", payload))


def test_each_goal_is_a_frame_and_the_critical_area_is_around_the_target():
    target, home = np.eye(4), np.eye(4)
    target[:3, 3], home[:3, 3] = (0.6, 0.1, 0.2), (0.3, 0.0, 0.5)
    drawn = goals(
        {"goals": {"target": pose_list(target), "home": pose_list(home)}, "critical_radius": 0.05}
    )
    assert [(parent, child) for parent, child, _, _ in drawn.frames] == [
        ("base", "goal/home"),
        ("base", "goal/target"),
    ]
    assert drawn.frames[1][2] == pytest.approx((0.6, 0.1, 0.2))
    ((centre, radius),) = drawn.spheres
    assert centre == pytest.approx((0.6, 0.1, 0.2)) and radius == 0.05


def test_no_target_or_no_radius_draws_no_critical_area():
    home = pose_list(np.eye(4))
    assert goals({"goals": {"home": home}, "critical_radius": 0.05}).spheres == ()
    assert goals({"goals": {"target": home}}).spheres == ()
    assert goals({}).frames == ()
