"""Spec: navigation on the patient. The tracked end-effector and reference tool give
where the patient is in the robot's own (nominal) terms; steering the nominal TCP to the
goal found there puts the real TCP on the target, whatever the arm's model errors and
the head's motion, without ever a step or a speed over the limit; a patient moved too
far or too fast is refused (components/robot/navigation.py)."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain.geometry import invert, pose_from_list, pose_matrix, rigid
from components.domain.lwr4 import HOME, Kinematics
from components.domain.procedure import pose_from
from components.domain.rigs import sensors_config, standard_rigs
from components.robot.interpolator import InterpolatorCore, Phase
from components.robot.navigation import Navigator, NavigatorCore, frames_of
from framework.activity import Activity, SteppedExecutor
from framework.clock import SimulatedClock
from framework.container import Container
from framework.errors import FwError
from framework.messages import EventMessage, JointState, Pose
from tests.conftest import REPO, drained, reader_port, writer_port
from tests.support.peer_clock import from_host_apart

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


def test_the_tracked_tcp_is_where_pivoting_found_the_tip_not_where_the_hand_eye_fit_put_it():
    """The hand-eye Y absorbs the arm's model error into the tool; the tip found by
    pivoting the tool in a divot does not: steered by it, the real TCP ends on the target
    even when Y's translation is half a millimetre off."""
    config = sensors_config(RIGS, camera=True)
    certus = config.sensors[0]
    off_y = certus.ee_from_cto.copy()
    off_y[:3, 3] += (0.0004, -0.0003, 0.0)  # a hand-eye Y 0.5 mm off, as fw calibrate's is
    errors = {}
    for tip in (None, invert(CERTUS.ee_from_cto)[:3, 3]):
        config.sensors[0] = dataclasses.replace(certus, ee_from_cto=off_y, tip=tip)
        trackers, registration = frames_of(config)
        loop = Loop()
        loop.nav = NavigatorCore(trackers, registration)
        loop.go().run(8.0)
        assert loop.core.phase is Phase.REACHED
        errors["tip" if tip is not None else "Y"] = loop.error()
    assert errors["tip"] < 1e-5
    assert errors["Y"] > 4e-4


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
    loop = Loop(q0=tuple(np.array(HOME) + np.array(start))).go()
    while loop.core.phase is not Phase.REACHED and loop.t < 15.0:  # 0.5 m at 5 cm/s at most
        loop.run(0.5)
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


@pytest.mark.parametrize("rig", [CERTUS, VICRA], ids=["certus", "vicra"])
def test_a_trackers_noise_reaches_the_goals_at_most_by_the_jitter_allowed(rig):
    """The Vicra's 0.35 mm (both tools) is filtered down to 0.1 mm RMS; the Certus's
    0.14 mm already is, by the smoothing alone, and steers as fast as before."""
    nav = NavigatorCore(TRACKERS, REGISTRATION, smoothing=0.1, jitter=1e-4)
    tcp = KIN.tcp(np.array(HOME))
    rng = np.random.default_rng(5)
    goals = []
    for k in range(3000):
        t = k / rig.rate
        cto, rto = rig.observe(ARM_ERROR @ tcp, rng, t)
        nav.offer(rig.name, pose_matrix(cto), pose_matrix(rto), tcp, t, np.hypot(cto.rms, rto.rms))
        goals.append(nav.goal(TARGET)[:3, 3])
    settled = np.array(goals[100:])
    jitter = float(np.sqrt(np.mean(np.sum((settled - settled.mean(axis=0)) ** 2, axis=1))))
    assert jitter < 1.1e-4
    if rig is CERTUS:
        assert nav.noise_weight(np.hypot(rig.noise, rig.noise)) > 1 - np.exp(-0.01 / 0.1)


def test_a_sample_quieter_than_the_jitter_allowed_is_not_held_back():
    nav = NavigatorCore(TRACKERS, REGISTRATION, jitter=1e-4)
    assert nav.noise_weight(0.0) == nav.noise_weight(1e-4) == 1.0
    assert nav.noise_weight(2e-4) == pytest.approx(2 * 0.25 / 1.25)


def test_a_noisy_trackers_sample_far_beyond_its_noise_is_news_and_not_held_back():
    """The jitter cap filters a noisy tracker heavily; a sample more than three times its
    noise from the filtered view is the head moving, and moves the goals at the
    smoothing's pace."""
    nav = NavigatorCore(TRACKERS, REGISTRATION, smoothing=0.1, jitter=7e-5)
    cto, rto = CERTUS.observe(KIN.tcp(np.array(HOME)), np.random.default_rng(0))
    cto, rto = pose_matrix(cto), pose_matrix(rto)
    nominal = KIN.tcp(np.array(HOME))
    noise = 3.5e-4  # the Vicra's, both tools
    nav.offer("certus", cto, rto, nominal, 0.0, noise)
    start = nav.base_from_patient[:3, 3].copy()
    full = 1.0 - np.exp(-0.05 / 0.1)  # a 20 Hz sample's weight without the cap

    def moved_by(shift, t):
        shifted = rto.copy()
        shifted[:3, 3] += (shift, 0.0, 0.0)  # the reference tool moved: the patient moved
        before = nav.base_from_patient[:3, 3].copy()
        nav.offer("certus", cto, shifted, nominal, t, noise)
        return np.linalg.norm(nav.base_from_patient[:3, 3] - before) / shift

    assert moved_by(0.0005, 0.05) == pytest.approx(nav.noise_weight(noise), rel=0.05)
    nav.base_from_patient[:3, 3] = start
    assert moved_by(0.005, 0.10) == pytest.approx(full, rel=0.05)


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
    loop.run(1.0, rig=off)  # the Vicra's Y is half a millimetre off
    steps = np.linalg.norm(np.diff(np.array(loop.commands[before - 1 :]), axis=0), axis=1)
    assert steps.max() <= 0.05 * DT * (1 + 1e-9)
    assert loop.nav.tracker == "vicra"
    assert loop.error() < 0.1 * 5e-4 + 5e-5, "the Certus's registration carried across"
    loop.run(30.0, rig=off)
    assert 4e-4 < loop.error() < 6e-4  # faded over swap_settle: the Vicra's own view


def test_the_offset_carried_across_a_swap_is_averaged_not_taken_from_one_noisy_sample():
    """A single sample of the new tracker carries its whole noise; the carry is the
    trackers' offset averaged over the new tracker's first half second."""
    off = dataclasses.replace(
        VICRA, ee_from_cto=VICRA.ee_from_cto @ rigid((0.0005, 0, 0), (0, 0, 0))
    )
    ends = []
    for outlier in (0.0, 0.001):
        loop = Loop().go().run(8.0)
        cto, rto = dataclasses.replace(off, noise=0.0).observe(
            loop.real_tcp(), loop.rng, loop.t, base_from_rto=loop.base_from_rto(loop.t)
        )
        moved = pose_matrix(cto)
        moved[:3, 3] += (0.0, outlier, 0.0)  # the swap's first sample 1 mm off
        loop.nav.offer("vicra", moved, pose_matrix(rto), KIN.tcp(loop.core.q), loop.t)
        loop.core.steer(loop.nav.goal(TARGET))
        loop.run(2.0, rig=off)
        ends.append(loop.real_tcp()[:3, 3])
    assert np.linalg.norm(ends[1] - ends[0]) < 0.1 * 0.001 * 1.2  # a tenth: one of ten samples


def test_after_a_swap_the_new_tracker_follows_the_head_from_its_first_sample():
    off = dataclasses.replace(
        VICRA, ee_from_cto=VICRA.ee_from_cto @ rigid((0.002, 0, 0), (0, 0, 0))
    )
    loop = Loop(head=lambda t: np.array([0.0, 0.003 * (t > 9.0), 0.0])).go().run(8.0)
    loop.core.set_limits(0.01)
    loop.run(3.0, rig=off)  # swapped at 8 s, the head moved 3 mm at 9 s
    faded = 0.002 * (1 - np.exp(-3.0 / loop.nav.swap_settle))  # the Vicra's own view, so far
    assert abs(loop.error() - faded) < 1e-4  # the head's 3 mm followed in full


def same_instant_offsets(loop, rigs):
    """What the Sensor Manager measures (`offsets`): each tracker's view of the
    end-effector on the patient against the Certus's, both seen at one instant."""
    views = {}
    for rig in rigs:
        quiet = dataclasses.replace(rig, noise=0.0)
        cto, rto = quiet.observe(loop.real_tcp(), loop.rng, loop.t, base_from_rto=BASE_FROM_RTO)
        frames = TRACKERS[rig.name]
        views[rig.name] = (
            frames.master_from_sensor @ invert(pose_matrix(rto)) @ pose_matrix(cto)
        ) @ frames.cto_from_ee
    return {name: view @ invert(views["certus"]) for name, view in views.items()}


@pytest.mark.parametrize("measured", [True, False], ids=["offsets measured", "none measured"])
def test_a_swap_during_a_head_bump_carries_only_the_trackers_difference(measured):
    """The Certus steers, the head is bumped 5 mm (50 ms ramp) and the swap to a Vicra
    calibrated 2 mm apart comes 20 ms into it, before the Certus's view settled. With
    the Sensor Manager's same-instant offset, the carry is the 2 mm of calibration
    alone (fading over swap_settle): 1 s later the tool is within 0.5 mm of the target
    and the bump is followed in full. Without it, the carry takes the view as it was
    and carries part of the bump with it, for seconds."""
    off = dataclasses.replace(
        VICRA, ee_from_cto=VICRA.ee_from_cto @ rigid((0.002, 0, 0), (0, 0, 0))
    )
    bump_at = 9.0

    def head(t):
        u = min(max(t - bump_at, 0.0) / 0.05, 1.0)
        return np.array([0.0, 0.005 * (0.5 - 0.5 * np.cos(np.pi * u)), 0.0])

    loop = Loop(head=head).go().run(bump_at + 0.02)
    loop.core.set_limits(0.01)
    if measured:
        loop.nav.tracker_offsets(same_instant_offsets(loop, [CERTUS, off]))
    loop.run(1.0, rig=off)
    settled = 0.002 * (1 - np.exp(-1.0 / loop.nav.swap_settle))  # the Vicra's own view so far
    if measured:
        assert loop.error() < 5e-4
        assert abs(loop.error() - settled) < 1e-4, "the bump followed in full"
    else:
        assert abs(loop.error() - settled) > 1e-3, "part of the bump carried"


@pytest.mark.parametrize(
    ("head", "refusal"),
    [
        (lambda t: np.array([0.004 * min(t, 1.0), 0.0, 0.0]), ""),  # 4 mm, slowly
        (lambda t: np.array([0.012 * min(t / 3, 1.0), 0.0, 0.0]), "(limit 10.0 mm)"),
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


def test_a_reference_tool_slipped_on_the_clamp_holds_the_goals_and_is_not_refused_after_a_swap():
    loop = Loop().go().run(3.0)
    goal = loop.nav.goal(TARGET)
    slipped = dataclasses.replace(
        CERTUS, rto_from_base=rigid((0.02, 0.0, 0.0), (0, 0, 0)) @ CERTUS.rto_from_base
    )
    loop.run(0.2, rig=slipped)  # the Certus sees the patient 2 cm away, suddenly
    assert "moved 20.0 mm" in loop.nav.suspect and loop.nav.refused == ""
    assert np.allclose(loop.nav.goal(TARGET), goal)  # the robot does not chase it
    loop.run(2.0, rig=VICRA)  # the Sensor Manager found the Certus out; the Vicra steers
    assert loop.nav.refused == "" and loop.nav.suspect == ""
    assert np.linalg.norm(loop.nav.patient_offset) < 1e-3


def test_a_tool_loosened_on_the_arm_does_not_drag_the_goals_and_is_refused():
    """Its view puts the patient 3 cm off although the reference tool did not move:
    beyond the patient's 10 mm plus the arm model's 5 mm."""
    loop = Loop().go().run(3.0)
    goal = loop.nav.goal(TARGET)
    loose = dataclasses.replace(
        CERTUS, ee_from_cto=CERTUS.ee_from_cto @ rigid((0.03, 0, 0), (0, 0, 0))
    )
    loop.run(0.01, rig=loose)  # one sample: held, not yet refused
    assert "a tool moved on the arm" in loop.nav.suspect and loop.nav.refused == ""
    assert np.allclose(loop.nav.goal(TARGET), goal)
    loop.run(0.5)  # the glitch is over
    assert loop.nav.suspect == "" and loop.nav.refused == ""
    loop.run(loop.nav.confirm + 0.05, rig=loose)  # loose for good
    assert "(limit 15.0 mm" in loop.nav.refused
    assert np.allclose(loop.nav.goal(TARGET), goal, atol=1e-4)


def test_the_arms_own_model_error_is_steered_out_not_refused():
    """A few millimetres between the model and the arm are what navigation corrects."""
    bent = rigid((0.004, -0.003, 0.0), (0.004, 0.0, 0.0))  # 5 mm and 0.23 deg
    nav = NavigatorCore(TRACKERS, REGISTRATION)
    rig = dataclasses.replace(CERTUS, noise=0.0)
    tcp = KIN.tcp(np.array(HOME))
    cto, rto = rig.observe(bent @ tcp, np.random.default_rng(0), 0.0)
    nav.offer("certus", pose_matrix(cto), pose_matrix(rto), tcp, 0.0)
    assert nav.suspect == "" and not np.allclose(nav.goal(TARGET), REGISTRATION @ TARGET)


def test_a_motion_beyond_the_limits_seen_for_the_confirmation_time_is_refused():
    loop = Loop(head=lambda t: np.array([0.02 * (t > 1.0), 0.0, 0.0])).go()
    loop.run(1.0 + loop.nav.confirm - 0.05)
    assert loop.nav.suspect and loop.nav.refused == ""
    loop.run(0.1)
    assert "moved 20.0 mm" in loop.nav.refused


def test_samples_of_an_unknown_tracker_change_nothing_and_without_any_the_goal_is_registered():
    nav = NavigatorCore(TRACKERS, REGISTRATION)
    assert np.allclose(nav.goal(TARGET), REGISTRATION @ TARGET)
    assert nav.offer("optotrak", np.eye(4), np.eye(4), np.eye(4), 0.0) is False
    assert nav.tracker is None and np.allclose(nav.goal(TARGET), REGISTRATION @ TARGET)
    with pytest.raises(ValueError, match="positive"):
        NavigatorCore(TRACKERS, REGISTRATION, smoothing=0.0)
    with pytest.raises(ValueError, match="confirm not negative"):
        NavigatorCore(TRACKERS, REGISTRATION, confirm=-0.1)


# --- the Navigator component: ports in, goals out ---------------------------------------


class NavigatorRig:
    """A Navigator on the hub session, the test playing the robot interface (joints) and
    the tracker connected to it (cto, rto); same session: delivered on `write`."""

    def __init__(self, hub, stale=0.25):
        self.clock = SimulatedClock()
        self.container = Container("c", hub, SteppedExecutor(self.clock))
        self.nav = self.container.add(Navigator("navigator"), Activity())
        self.nav.set_property("procedure_file", str(REPO / "procedures" / "seeg.yaml"))
        self.nav.set_property("sensors_file", str(REPO / "procedures" / "seeg" / "sensors.yaml"))
        self.nav.set_property("stale", stale)
        self.writers = {}
        for name, kind in [("joints", JointState), ("cto", Pose), ("rto", Pose)]:
            self.writers[name] = writer_port(hub, f"test/{name}", kind)
            self.container.connect("navigator", name, f"test/{name}")
        self.goals = reader_port(hub, "navigator/goals", EventMessage)
        self.sources = reader_port(hub, "navigator/sources", EventMessage)
        self.refusals = []
        self.nav.add_refusal_listener(self.refusals.append)
        self.container.start()
        assert self.nav.configure() and self.nav.start(), self.nav.last_error
        self.rng = np.random.default_rng(1)

    def sample(self, rig=CERTUS, stamp=None, tcp_error=ARM_ERROR, head=BASE_FROM_RTO, after=None):
        """The arm at HOME (its joints stamped now), seen by `rig` `after` seconds on the
        component's clock (one goals period unless given); the navigator runs. The last
        goals it said (None if it said none)."""
        stamp = time.time() if stamp is None else stamp
        self.writers["joints"].write(JointState(stamp, HOME))
        real = tcp_error @ KIN.tcp(np.array(HOME))
        cto, rto = dataclasses.replace(rig, noise=0.0).observe(
            real, self.rng, stamp, base_from_rto=head
        )
        self.writers["rto"].write(rto)
        self.writers["cto"].write(cto)
        self.clock.advance(1 / self.nav.goals_rate if after is None else after)
        self.nav.update_hook()
        said = drained(self.goals)
        return said[-1].payload if said else None

    def close(self):
        self.container.shutdown()


@pytest.fixture
def navigator(hub):
    rig = NavigatorRig(hub)
    yield rig
    rig.close()


def goal_of(payload, name="target"):
    return pose_from_list(payload["goals"][name])


def test_before_any_sample_the_goals_are_where_the_registration_puts_them(navigator):
    navigator.nav.idle_hook()
    payload = drained(navigator.goals)[-1].payload
    assert payload["tracker"] is None and payload["refused"] == ""
    assert np.allclose(
        goal_of(payload)[:3, 3], [0.60, 0.0, 0.12], atol=3e-3
    )  # calibrated on the real arm: 2 mm off
    assert payload["goals"]["home"][:3] == [0.54, 0.0, 0.37]  # in the base frame: as given


def test_the_tracker_in_use_places_the_target_where_the_arm_must_go_in_its_own_terms(navigator):
    payload = navigator.sample()
    assert payload["tracker"] == "certus"
    # the real TCP is ARM_ERROR off the model: the goal is moved so the real TCP lands
    wanted = invert(ARM_ERROR) @ BASE_FROM_RTO @ TARGET
    assert np.linalg.norm(goal_of(payload)[:3, 3] - wanted[:3, 3]) < 3e-3  # the calibration: 2 mm


def test_the_first_sample_of_each_tracker_is_marked_as_its_source_once(navigator):
    navigator.sample(stamp=time.time() - 0.01)
    navigator.sample()
    navigator.sample(rig=VICRA)
    sources = [m.payload for m in drained(navigator.sources)]
    assert [s["tracker"] for s in sources] == ["certus", "vicra"]


def test_goals_go_out_at_their_rate_and_at_once_when_what_steers_changes(navigator):
    """A 100 Hz tracker gives goals at `goals_rate` (50 Hz: every second sample); a
    sample of another tracker, which then steers, is said at once."""
    assert navigator.sample()["tracker"] == "certus"
    said = [navigator.sample(after=0.01) for _ in range(10)]
    assert [s is not None for s in said] == [False, True] * 5
    assert navigator.sample(rig=VICRA, after=0.001)["tracker"] == "vicra", "said at once"
    assert navigator.sample(rig=VICRA, after=0.001) is None


def test_samples_of_an_unknown_tracker_or_of_two_trackers_mixed_are_not_used(navigator):
    stranger = dataclasses.replace(CERTUS, name="optotrak")
    payload = navigator.sample(rig=stranger)
    assert payload["tracker"] is None
    assert "'optotrak', a tracker the sensors file lacks" in navigator.refusals[0].reason
    navigator.writers["rto"].write(dataclasses.replace(CERTUS).observe(np.eye(4), navigator.rng)[1])
    cto = dataclasses.replace(VICRA).observe(np.eye(4), navigator.rng)[0]
    navigator.writers["cto"].write(cto)  # a Vicra CTO with a Certus RTO: not a pair
    navigator.clock.advance(1 / navigator.nav.goals_rate)
    navigator.nav.update_hook()
    assert drained(navigator.goals)[-1].payload["tracker"] is None


def test_a_tracker_whose_samples_stopped_no_longer_steers(hub):
    rig = NavigatorRig(hub, stale=0.02)
    try:
        assert rig.sample()["tracker"] == "certus"
        time.sleep(0.05)  # longer than `stale`
        rig.nav.idle_hook()
        assert drained(rig.goals)[-1].payload["tracker"] is None
    finally:
        rig.close()


def test_a_patient_moved_too_far_is_refused_until_registered_again(navigator):
    t0 = time.time() - 1.0
    navigator.sample(stamp=t0)
    moved = BASE_FROM_RTO.copy()
    moved[:3, 3] += (0.0, 0.012, 0.0)
    payload = navigator.sample(head=moved, stamp=t0 + 0.01)
    assert payload["refused"] == "" and payload["holding"].startswith("the patient moved 12.0")
    payload = navigator.sample(head=moved, stamp=t0 + 0.02 + navigator.nav.core.confirm)
    assert payload["refused"].startswith("the patient moved 12.0 mm")
    assert payload["patient_mm"] == pytest.approx([0.0, 12.0, 0.0], abs=1.0)  # calibration
    registered = navigator.nav.call("register")
    assert registered["refused"] == "" and registered["holding"] == ""
    assert drained(navigator.goals)[-1].payload["refused"] == "", "said at once"


def test_a_target_defined_anew_has_a_new_revision_and_a_bad_one_is_refused(navigator):
    navigator.nav.idle_hook()
    assert drained(navigator.goals)[-1].payload["revisions"] == {"target": 0, "home": 0}
    report = navigator.nav.call("define_target", x=0.1, y=0.2, z=0.15, roll=180, pitch=0, yaw=0)
    assert report["revisions"]["target"] == 1
    with pytest.raises(FwError, match="frame 'skull'"):
        navigator.nav.call("define_target", x=0, y=0, z=0, roll=0, pitch=0, yaw=0, frame="skull")
    base = navigator.nav.call(
        "define_target", x=0.6, y=0, z=0.2, roll=0, pitch=180, yaw=0, frame="base"
    )
    assert base["goals"]["target"][:3] == [0.6, 0.0, 0.2]


def test_the_goals_say_where_the_patients_reference_is_for_the_3d_view(navigator):
    """The target is defined on the patient (its reference tool's frame): the reference
    said beside it is the frame that puts the target where the goals say."""
    payload = navigator.sample()
    on_patient = navigator.nav.procedure.goals["target"]
    reference = goal_of(payload) @ np.linalg.inv(on_patient)
    assert payload["patient"] == pytest.approx(reference[:3, 3].tolist(), abs=1e-4)


# --- trackers on a host whose clock runs apart (issue 46, docs/hosts.md) ------------------


def tracking_host_clock(rig: NavigatorRig, offset: float | None) -> None:
    """The tracker's samples (cto, rto) come from another host (`tracking`) whose clock
    is `offset` s ahead of this one, as measured by a 1 ms round trip (None: not yet)."""
    from_host_apart(rig.container, "tracking", "trackers", offset, ("test/cto", "test/rto"))


def sample_of_the_past(rig: NavigatorRig, skew: float) -> dict:
    """The arm passed HOME 50 ms ago, moving 1.5 cm each 50 ms; the tracker saw it at
    HOME then and stamped that moment on its host's clock, `skew` s ahead. The goals."""
    now = time.time()
    step = np.array([0.025, 0, 0, 0, 0, 0, 0])  # the base joint: about 1.5 cm at the TCP
    rig.writers["joints"].write(JointState(now - 0.1, tuple(np.array(HOME) - step)))
    rig.writers["joints"].write(JointState(now - 0.05, HOME))
    rig.writers["joints"].write(JointState(now, tuple(np.array(HOME) + step)))
    real = ARM_ERROR @ KIN.tcp(np.array(HOME))
    cto, rto = dataclasses.replace(CERTUS, noise=0.0).observe(
        real, rig.rng, now - 0.05 + skew, base_from_rto=BASE_FROM_RTO
    )
    rig.writers["rto"].write(rto)
    rig.writers["cto"].write(cto)
    rig.clock.advance(1 / rig.nav.goals_rate)
    rig.nav.update_hook()
    return drained(rig.goals)[-1].payload


@pytest.mark.parametrize("skew", [0.05, -0.05])
def test_a_sample_stamped_on_a_clock_apart_is_paired_with_the_joints_of_its_moment(hub, skew):
    """The tracking PC's clock runs 50 ms ahead (or behind) of the robot's. Paired by
    its stamp as written, the sample would meet the joints of another moment (1.5 cm
    away) and move the target by as much; on the robot's clock, by the host's measured
    offset, it meets HOME's and the target is where the arm must go."""
    rig = NavigatorRig(hub)
    try:
        tracking_host_clock(rig, skew)
        payload = sample_of_the_past(rig, skew)
        assert payload["tracker"] == "certus"
        wanted = invert(ARM_ERROR) @ BASE_FROM_RTO @ TARGET
        assert np.linalg.norm(goal_of(payload)[:3, 3] - wanted[:3, 3]) < 3e-3
    finally:
        rig.close()


def test_samples_from_a_host_whose_clock_is_not_measured_yet_steer_nothing(hub):
    """Until the tracking PC's clock has answered, its samples cannot be placed in time:
    refused, said why, and no tracker steers."""
    rig = NavigatorRig(hub)
    try:
        tracking_host_clock(rig, None)
        assert rig.sample()["tracker"] is None
        assert "clock offset is not measured yet" in rig.refusals[0].reason
        tracking_host_clock(rig, 0.0)
        assert rig.sample()["tracker"] == "certus"
    finally:
        rig.close()


def test_a_samples_joints_are_those_between_the_two_measured_around_its_stamp():
    """The robot's joints come at 100 Hz: a tracker's sample 3 ms after one is paired
    with the joints 3/10 of the way to the next, not with the nearer of the two (0.2 mm
    off at 7.5 cm/s); before the first and after the last, with that one."""
    nav = NavigatorCore(TRACKERS, REGISTRATION)
    assert nav.joints_at(1.0) is None
    first, second = np.zeros(7), np.arange(7) * 0.01
    nav.joints(1.000, first)
    nav.joints(1.010, second)
    assert np.allclose(nav.joints_at(1.003), 0.3 * second)
    assert np.array_equal(nav.joints_at(1.010), second)
    assert np.array_equal(nav.joints_at(0.5), first)
    assert np.array_equal(nav.joints_at(1.5), second)
