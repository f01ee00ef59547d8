"""Spec: the simulated LWR 4+ (components/sim/arm.py): a braked arm at rest is not
integrated again, and nothing it reports shows it."""

import numpy as np
import pytest

from components.domain import lwr4
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
