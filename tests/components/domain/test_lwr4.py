"""The LWR 4+ model: MuJoCo and Pinocchio built from one DH table agree."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain import lwr4
from components.domain.ik import DifferentialIK
from components.sim.arm import SimulatedArm, resting_tcp

KIN = lwr4.Kinematics()
MODEL = mujoco.MjModel.from_xml_string(lwr4.mjcf())
DATA = mujoco.MjData(MODEL)

joints = st.tuples(*[st.floats(-limit, limit) for limit in lwr4.POSITION_LIMIT]).map(np.array)


def mujoco_tcp(q: np.ndarray) -> np.ndarray:
    DATA.qpos[:7] = q
    mujoco.mj_kinematics(MODEL, DATA)
    site = MODEL.site("tcp").id
    out = np.eye(4)
    out[:3, :3] = DATA.site_xmat[site].reshape(3, 3)
    out[:3, 3] = DATA.site_xpos[site]
    return out


@settings(max_examples=60, deadline=None)
@given(joints)
def test_mujoco_pinocchio_and_dh_agree_on_the_tcp(q):
    reference = lwr4.dh_forward(q)
    assert np.allclose(KIN.tcp(q), reference, atol=1e-9)
    assert np.allclose(mujoco_tcp(q), reference, atol=1e-9)


def test_stretched_arm_reaches_the_sum_of_link_lengths():
    tcp = KIN.tcp(np.zeros(7))
    assert np.isclose(tcp[2, 3], sum(lwr4.D) + lwr4.TOOL_LENGTH)


def test_model_carries_the_published_limits():
    for i, name in enumerate(lwr4.JOINTS):
        low, high = MODEL.joint(name).range  # MuJoCo keeps radians after compiling
        assert np.isclose(high, lwr4.POSITION_LIMIT[i]) and np.isclose(low, -high)
        assert np.isclose(MODEL.actuator(f"{name}_servo").forcerange[1], lwr4.TORQUE_LIMIT[i])
    assert np.allclose(np.degrees(KIN.velocity_limit), [110, 110, 128, 128, 204, 184, 184])


@settings(max_examples=30, deadline=None)
@given(joints)
def test_capsules_follow_the_arm_and_end_at_the_tcp(q):
    capsules = KIN.capsules(q)
    assert np.allclose(capsules.a[0], 0.0)
    assert np.allclose(capsules.b[-1], KIN.tcp(q)[:3, 3])
    assert np.allclose(capsules.b[:-1], capsules.a[1:])  # a connected chain


def test_jacobian_matches_finite_differences():
    q = np.array(lwr4.HOME) + 0.1
    _, jac = KIN.jacobian(q)
    eps = 1e-6
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = eps
        numeric = (KIN.tcp(q + dq)[:3, 3] - KIN.tcp(q - dq)[:3, 3]) / (2 * eps)
        assert np.allclose(jac[:3, j], numeric, atol=1e-6)


def test_ik_reaches_a_reachable_pose():
    ik = DifferentialIK()
    truth = np.array(lwr4.HOME) + np.array([0.2, 0.1, -0.1, 0.15, 0.1, 0.1, -0.2])
    q = ik.solve(np.array(lwr4.HOME), KIN.tcp(truth))
    assert np.linalg.norm(ik.error(q, KIN.tcp(truth))) < 1e-6


def test_arm_powers_up_braked_and_holds_home():
    arm = SimulatedArm()
    assert arm.braked
    for _ in range(500):
        arm.step()
    assert np.allclose(arm.q, lwr4.HOME, atol=1e-6)
    assert not arm.command(np.array(lwr4.HOME)), "braked: setpoints are refused"


def test_watchdog_brakes_when_setpoints_stop():
    arm = SimulatedArm(watchdog_cycles=5)
    arm.release()
    for _ in range(3):
        assert arm.command(arm.q)
        arm.step()
    for _ in range(5):
        arm.step()
    assert not arm.braked
    arm.step()
    assert arm.braked and arm.reason.startswith("watchdog")


def test_setpoint_jump_and_nan_are_refused_and_brake():
    arm = SimulatedArm()
    arm.release()
    assert not arm.command(arm.q + np.radians([5, 0, 0, 0, 0, 0, 0]))
    assert arm.braked and "setpoint jump on a1" in arm.reason
    arm.release()
    assert not arm.command(np.full(7, np.nan))
    assert arm.braked and "finite" in arm.reason


def test_impedance_mode_yields_more_than_position_mode():
    def sag(mode: str) -> float:
        arm = SimulatedArm(mode=mode)
        arm.release()
        arm.data.xfrc_applied[arm.model.body("link7").id, 2] = -40.0  # push down, N
        for _ in range(400):
            arm.command(np.array(lwr4.HOME))
            arm.step()
        return float(np.linalg.norm(arm.q - lwr4.HOME))

    assert sag("impedance") > 3 * sag("position")


# --- the real arm is not its model ------------------------------------------------------

RIGID = lwr4.ArmErrors(
    joint_offset=lwr4.LWR4_ERRORS.joint_offset,
    link_error=lwr4.LWR4_ERRORS.link_error,
    tool_error=lwr4.LWR4_ERRORS.tool_error,
)


@settings(max_examples=10, deadline=None)
@given(st.tuples(*[st.floats(-0.4, 0.4)] * 7))
def test_the_real_arms_tcp_is_where_its_geometric_errors_put_it(offset):
    q = np.array(lwr4.HOME) + np.array(offset)
    arm = SimulatedArm(tuple(q), errors=RIGID)
    assert np.allclose(arm.q, q, atol=1e-9), "the encoders read what was asked"
    assert np.allclose(arm.tcp(), lwr4.dh_forward(q, RIGID), atol=1e-9)


@settings(max_examples=10, deadline=None)
@given(st.tuples(*[st.floats(-0.4, 0.4)] * 7))
def test_by_its_model_the_simulated_ors_arm_is_a_few_millimetres_off(offset):
    q = np.array(lwr4.HOME) + np.array(offset)
    miss = np.linalg.norm(resting_tcp(q, lwr4.LWR4_ERRORS)[:3, 3] - KIN.tcp(q)[:3, 3])
    assert 1.5e-3 < miss < 5e-3


def test_the_gears_twist_under_gravity_where_the_encoders_cannot_see_it():
    rigid = resting_tcp(np.array(lwr4.HOME), RIGID)
    elastic = resting_tcp(np.array(lwr4.HOME), lwr4.LWR4_ERRORS)
    sag = np.linalg.norm(elastic[:3, 3] - rigid[:3, 3])
    assert 2e-4 < sag < 2e-3  # the shoulder carries the arm: tenths of a millimetre


@pytest.mark.parametrize(
    ("mode", "lag"), [("impedance", (0.06, 0.08)), ("position", (-0.002, 0.002))]
)
def test_joint_impedance_control_trails_a_moving_command_position_control_does_not(mode, lag):
    arm = SimulatedArm(mode=mode, errors=lwr4.LWR4_ERRORS)
    arm.release()
    velocity = 0.1  # rad/s on every joint
    setpoint = np.array(lwr4.HOME)
    for _ in range(1500):  # 1.5 s: the lag has settled
        setpoint = setpoint + velocity * arm.dt
        assert arm.command(setpoint), arm.reason
        arm.step()
    behind = (setpoint - arm.q) / velocity  # s
    assert lag[0] <= behind[1] <= lag[1], behind
