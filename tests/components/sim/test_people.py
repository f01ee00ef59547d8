"""Spec: scripted people walk at their speed, lean over the table, and are seen by the
simulated cameras through the shared ground truth."""

import math

import numpy as np

from components.domain.skeleton import JOINTS
from components.sim.people import Person


def test_a_person_walks_the_waypoints_at_walking_speed_and_faces_the_way():
    p = Person(np.array([0.0, 0.0]))
    p.waypoints = [np.array([1.0, 0.0]), np.array([1.0, 1.0])]
    p.advance(0.5)
    assert np.allclose(p.position, [0.5, 0.0]) and math.isclose(p.facing, 0.0)
    p.advance(1.0)
    assert np.allclose(p.position, [1.0, 0.5]) and math.isclose(p.facing, math.pi / 2)
    p.advance(10.0)
    assert np.allclose(p.position, [1.0, 1.0]) and not p.waypoints


def test_a_person_asked_to_face_somewhere_turns_there_on_arrival_not_before():
    p = Person(np.array([2.0, 0.5]), turn_to=math.pi)
    p.waypoints = [np.array([1.0, 0.5])]
    p.advance(0.5)
    assert math.isclose(p.facing, math.pi), "walking toward -x"
    p.turn_to = math.pi / 2
    p.advance(0.25)
    assert math.isclose(p.facing, math.pi), "still on the way: facing the way"
    p.advance(1.0)
    assert np.allclose(p.position, [1.0, 0.5]) and math.isclose(p.facing, math.pi / 2)
    p.advance(1.0)
    assert math.isclose(p.facing, math.pi / 2), "standing, they keep facing there"


def test_leaning_brings_the_hands_forward_to_table_height():
    upright = Person(np.array([1.3, 0.0]), facing=math.pi).skeleton(floor=-0.8)
    leaning = Person(np.array([1.3, 0.0]), facing=math.pi, lean=0.7).skeleton(floor=-0.8)
    hand = JOINTS.index("right_hand")
    assert leaning[hand, 0] < upright[hand, 0] - 0.5, "reaching toward -x (the robot)"
    assert math.isclose(leaning[hand, 2], -0.8 + 0.85)
    assert np.allclose(upright[JOINTS.index("head")], leaning[JOINTS.index("head")])
