"""Spec: the simulated LWR 4+ (components/sim/arm.py): a braked arm at rest is not
integrated again, and nothing it reports shows it."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain import lwr4
from components.sim import arm as arm_module
from components.sim.arm import SimulatedArm


class AlwaysIntegrated(SimulatedArm):
    """The reference: the physics runs every cycle, braked or not."""

    def step(self):
        self._at_rest = False
        super().step()


def _play(arm):
    """Braked at power on, released and moved, braked, mode switched while braked,
    released again, then a setpoint jump (refused: braked); what it reported."""
    readings = []
    push = np.array([3, -2, 1, 2, -1, 1, 2]) * 1e-4  # rad per cycle at full speed
    setpoint = arm.q
    for k in range(400):
        if k in (50, 250):
            arm.release()
            setpoint = arm.q
        if 50 <= k < 150 or 250 <= k < 300:
            setpoint = setpoint + push * min(k % 200 - 49, 20) / 20
            arm.command(setpoint)
        if k == 150:
            arm.brake("test")
        if k == 200:
            arm.set_mode("impedance")
        if k == 300:
            arm.command(setpoint + 0.5)
        arm.step()
        readings.append((arm.q, arm.torque, arm.qd, arm.tcp(), arm.time, arm.braked, arm.reason))
    return readings


@pytest.mark.parametrize("errors", [lwr4.NOMINAL, lwr4.LWR4_ERRORS], ids=["nominal", "lwr4"])
def test_a_braked_arm_at_rest_reads_exactly_as_if_its_physics_still_ran(errors):
    fast, reference = _play(SimulatedArm(errors=errors)), _play(AlwaysIntegrated(errors=errors))
    moved = [k for k, r in enumerate(reference) if not r[5]]
    assert moved and moved[0] == 50 and moved[-1] == 299  # it moved twice, then the jump
    for k, (a, b) in enumerate(zip(fast, reference, strict=True)):
        assert all(np.array_equal(x, y) for x, y in zip(a[:4], b[:4], strict=True)), f"cycle {k}"
        assert a[4:] == b[4:], f"cycle {k}"


kernel_built = pytest.mark.skipif(
    arm_module._fwkernel is None, reason="the compiled kernel was not built (pip install -e .)"
)
step = st.floats(-2e-3, 2e-3)  # rad per cycle: within and beyond the joints' 1.9-3.6 mrad
odd = st.sampled_from([math.nan, math.inf, -math.inf, 10**400, True, "0.1", None])


@st.composite
def setpoints(draw):
    """What a setpoint may be: a step from where the arm is (some joints past their
    velocity), a huge jump, or something that is no 7 finite numbers."""
    kind = draw(st.sampled_from(["step", "step", "step", "jump", "odd", "length"]))
    if kind == "length":
        return ("length", draw(st.integers(0, 9).filter(lambda n: n != 7)))
    steps = draw(st.tuples(*[step] * 7))
    if kind == "jump":
        steps = tuple(s + draw(st.sampled_from([0.0, 0.5, -3.0])) for s in steps)
    if kind == "odd":
        return ("odd", steps, draw(st.integers(0, 6)), draw(odd))
    return (kind, steps)


def _setpoint(arm, spec):
    if spec[0] == "length":
        return tuple(arm.q.tolist()[: spec[1]]) + (0.0,) * max(0, spec[1] - 7)
    values = [q + s for q, s in zip(arm.q.tolist(), spec[1], strict=True)]
    if spec[0] == "odd":
        values[spec[2]] = spec[3]
    return tuple(values)


@kernel_built
@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from(["position", "impedance"]),
    st.lists(st.tuples(setpoints(), st.integers(0, 3)), min_size=1, max_size=6),
)
def test_the_kernels_setpoint_guard_is_the_pythons(mode, plan):
    """The compiled guard and servo targets (`servo_aim`) take and refuse the setpoints
    the Python `_command` does, with the same reason and the same servo targets to the
    bit, whether the arm was just released or is being commanded, in either mode; and
    the encoders the kernel reads after each step (`arm_sense`) are numpy's, to the bit."""
    compiled, reference = SimulatedArm(mode=mode), SimulatedArm(mode=mode)
    reference._reference_guard = True
    for arm in (compiled, reference):
        arm.release()
    for spec, idle in plan:
        taken = [arm.command(_setpoint(arm, spec)) for arm in (compiled, reference)]
        assert taken[0] == taken[1]
        assert compiled.data.ctrl.tobytes() == reference.data.ctrl.tobytes()
        assert (compiled.braked, compiled.reason) == (reference.braked, reference.reason)
        assert compiled.last_setpoint == reference.last_setpoint
        for _ in range(idle + 1):
            compiled.step()
            reference.step()
        assert compiled.q.tobytes() == reference.q.tobytes()
        assert compiled.torque_values == reference.torque_values
        assert compiled._aim == reference._aim
