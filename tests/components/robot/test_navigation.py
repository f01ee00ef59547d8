"""Spec: navigation on the patient. The tracked end-effector and reference tool give
where the patient is in the robot's own (nominal) terms; steering the nominal TCP to the
goal found there puts the real TCP on the target, whatever the arm's model errors and
the head's motion, without ever a step or a speed over the limit; a patient moved too
far or too fast is refused (components/robot/navigation.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.robot.interpolator import InterpolatorCore, Phase
from components.robot.lwr4 import HOME, Kinematics
from components.robot.navigation import NavigatorCore, frames_of
from components.supervisor.procedure import pose_from
from components.tracking.geometry import invert, pose_matrix
from components.tracking.synthetic import rigid, sensors_config, standard_rigs

KIN = Kinematics()
DT = 0.001
RIGS = standard_rigs()
CERTUS, VICRA = RIGS
TRACKERS, REGISTRATION = frames_of(sensors_config(RIGS, camera=True))
BASE_FROM_RTO = invert(CERTUS.rto_from_base)  # where the head clamp's reference tool rests
TARGET_IN_BASE = pose_from((0.60, 0.0, 0.12), (0, 180, 0))
TARGET = CERTUS.rto_from_base @ TARGET_IN_BASE  # the same target, on the patient
ARM_ERROR = rigid((0.002, -0.003, 0.0015), (0.002, -0.001, 0.003))  # real arm vs its model


@dataclasses.dataclass
class Loop:
    """The interpolator steered by the navigator, on a simulated arm that reaches its
    command exactly but whose real TCP is `ARM_ERROR` off its model; a tracker samples
    the real TCP and the head's reference tool at its rate."""

    rig: object = dataclasses.field(default_factory=lambda: CERTUS)
    noise: bool = False
    velocity: float = 0.05
    q0: tuple[float, ...] = HOME
    head: object = None  # t -> offset of the head (m, base frame)

    def __post_init__(self):
        self.core = InterpolatorCore(
            np.array(self.q0), velocity=self.velocity, acceleration=0.25, brake_acceleration=2.0
        )
        self.nav = NavigatorCore(TRACKERS, REGISTRATION)
        self.rng = np.random.default_rng(3)
        self.t = 0.0
        self.commands = []

    def base_from_rto(self, t):
        out = BASE_FROM_RTO.copy()
        if self.head is not None:
            out[:3, 3] += self.head(t)
        return out

    def real_tcp(self):
        return ARM_ERROR @ KIN.tcp(self.core.q)

    def true_target(self):
        return self.base_from_rto(self.t) @ TARGET

    def sample(self, rig=None):
        rig = rig or self.rig
        if not self.noise:
            rig = dataclasses.replace(rig, noise=0.0)
        cto, rto = rig.observe(
            self.real_tcp(), self.rng, self.t, base_from_rto=self.base_from_rto(self.t)
        )
        self.nav.offer(rig.name, pose_matrix(cto), pose_matrix(rto), KIN.tcp(self.core.q), self.t)

    def run(self, seconds, rig=None):
        period = round(1.0 / (rig or self.rig).rate / DT)
        for _ in range(round(seconds / DT)):
            if round(self.t / DT) % period == 0:
                self.sample(rig)
                self.core.steer(self.nav.goal(TARGET))
            self.core.step()
            self.commands.append(self.core.pose[:3, 3].copy())
            self.t += DT
        return self

    def go(self):
        self.core.go_to(self.nav.goal(TARGET))
        return self

    def error(self):
        return float(np.linalg.norm(self.real_tcp()[:3, 3] - self.true_target()[:3, 3]))


def test_by_the_joints_alone_the_real_tcp_misses_the_target_by_the_arms_model_error():
    loop = Loop()
    loop.core.go_to(REGISTRATION @ TARGET)  # no tracker: where the calibration puts it
    loop.t = 0.0
    for _ in range(8000):
        loop.core.step()
    assert loop.core.phase is Phase.REACHED
    assert loop.error() > 0.003


@settings(max_examples=15, deadline=None)
@given(start=st.tuples(*[st.floats(-0.15, 0.15)] * 7))
def test_navigation_brings_the_real_tcp_onto_a_static_target_from_any_reachable_start(start):
    loop = Loop(q0=tuple(np.array(HOME) + np.array(start))).go().run(8.0)
    assert loop.core.phase is Phase.REACHED
    assert loop.error() < 5e-5  # noise-free: exactly, up to the IK's convergence


def test_with_the_certus_noise_the_target_is_reached_within_a_tenth_of_a_millimetre():
    loop = Loop(noise=True).go().run(8.0)
    assert loop.error() < 1e-4


@settings(max_examples=20, deadline=None)
@given(velocity=st.sampled_from([0.01, 0.05, 0.075]), noisy=st.booleans())
def test_the_command_never_moves_faster_than_the_velocity_limit(velocity, noisy):
    loop = Loop(velocity=velocity, noise=noisy, head=lambda t: np.array([0, 0.005 * (t > 1.0), 0]))
    loop.go().run(3.0)
    steps = np.linalg.norm(np.diff(np.array(loop.commands), axis=0), axis=1) / DT
    assert steps.max() <= velocity * (1 + 1e-9)


def test_a_step_in_the_measured_pose_moves_the_goal_by_the_filters_share_only():
    nav = NavigatorCore(TRACKERS, REGISTRATION, smoothing=0.1)
    tcp = KIN.tcp(np.array(HOME))
    rig = dataclasses.replace(CERTUS, noise=0.0)
    rng = np.random.default_rng(0)
    cto, rto = rig.observe(ARM_ERROR @ tcp, rng, 0.0)
    nav.offer("certus", pose_matrix(cto), pose_matrix(rto), tcp, 0.0)
    before = nav.goal(TARGET)
    jumped = rigid((0.005, 0.0, 0.0), (0.0, 0.0, 0.0)) @ ARM_ERROR @ tcp  # a 5 mm glitch
    cto, rto = rig.observe(jumped, rng, 0.01)
    nav.offer("certus", pose_matrix(cto), pose_matrix(rto), tcp, 0.01)
    moved = np.linalg.norm(nav.goal(TARGET)[:3, 3] - before[:3, 3])
    assert moved == pytest.approx(0.005 * (1 - np.exp(-0.1)), rel=1e-6)


def test_the_head_bumped_by_5_mm_is_followed_back_onto_the_target_within_a_second():
    loop = Loop(noise=True, head=lambda t: np.array([0.0, 0.005 * (t > 9.05), 0.0]))
    loop.go().run(8.0)
    loop.core.set_limits(0.01)  # the critical area's speed
    loop.run(1.0)
    assert loop.error() < 2e-4
    errors = []
    for _ in range(20):
        loop.run(0.05)
        errors.append(loop.error())
    assert max(errors) > 0.004  # the bump was felt...
    assert errors[-1] < 5e-4  # ...and corrected within a second
    assert loop.nav.refused == ""


def test_a_swap_to_a_tracker_with_another_calibration_blends_the_goal_without_a_step():
    off = dataclasses.replace(
        VICRA, ee_from_cto=VICRA.ee_from_cto @ rigid((0.0005, 0, 0), (0, 0, 0))
    )
    loop = Loop().go().run(8.0)
    assert loop.error() < 5e-5
    before = len(loop.commands)
    loop.run(2.0, rig=off)  # the Vicra's Y is half a millimetre off
    steps = np.linalg.norm(np.diff(np.array(loop.commands[before - 1 :]), axis=0), axis=1)
    assert steps.max() <= 0.05 * DT * (1 + 1e-9)
    assert loop.nav.tracker == "vicra"
    assert 3e-4 < loop.error() < 7e-4  # it follows the Vicra's view now, half a mm away


@pytest.mark.parametrize(
    ("head", "refusal"),
    [
        (lambda t: np.array([0.004 * min(t, 1.0), 0.0, 0.0]), ""),  # 4 mm, slowly
        (lambda t: np.array([0.012 * min(t / 3, 1.0), 0.0, 0.0]), "moved 12.0 mm"),
        (lambda t: np.array([0.0, 0.0, 0.009 * min(max(t - 1, 0) / 0.3, 1.0)]), "moves at"),
    ],
    ids=["followed", "too far", "too fast"],
)
def test_a_patient_moved_too_far_or_too_fast_is_refused_until_registered_again(head, refusal):
    loop = Loop(head=head).run(4.0)
    assert (refusal in loop.nav.refused) if refusal else loop.nav.refused == ""
    if refusal:
        loop.nav.register()
        loop.run(2.0)
        assert loop.nav.refused == ""
        assert np.linalg.norm(loop.nav.patient_offset) < 1e-3


def test_samples_of_an_unknown_tracker_change_nothing_and_without_any_the_goal_is_registered():
    nav = NavigatorCore(TRACKERS, REGISTRATION)
    assert np.allclose(nav.goal(TARGET), REGISTRATION @ TARGET)
    assert nav.offer("optotrak", np.eye(4), np.eye(4), np.eye(4), 0.0) is False
    assert nav.tracker is None and np.allclose(nav.goal(TARGET), REGISTRATION @ TARGET)
    with pytest.raises(ValueError, match="positive"):
        NavigatorCore(TRACKERS, REGISTRATION, smoothing=0.0)
