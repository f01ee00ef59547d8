"""Spec: what speed and separation monitoring is for. A person walking straight at the
moving arm at up to 1.6 m/s never reaches it while it moves: the arm slows as they
approach and stops in time (components/domain/separation.py)."""

from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain.separation import SeparationMonitor, SsmParams
from tests.components.domain.test_separation import arm, person

P = SsmParams()


@settings(max_examples=80, deadline=None)
@given(
    start=st.floats(0.3, 3.0),
    walk=st.floats(0.2, 1.6),
    age=st.floats(0.0, 0.1),
    cruise=st.floats(0.0, 0.075),
)
def test_a_person_walking_at_the_arm_never_reaches_it_while_it_moves(start, walk, age, cruise):
    """1 ms cycles: a person walks straight at the arm, which heads toward them at its
    cruise speed, slowed by the cap at the procedure's acceleration, braked at once on
    a stop (then decelerating at the stop's rate after `engage`). The envelope seen is
    `age` old. Whenever the arm still moves, they have not met. Once it stands, braked
    or capped to 0, it stays: the person only comes closer, and the cap only falls."""
    dt, accel = 0.001, 0.25
    monitor = SeparationMonitor(P, max_speed=0.075)
    x_arm, v_arm, x_person = 0.0, cruise, 0.2 + start
    braking_since = None
    seen: list[float] = []
    for cycle in range(int(6.0 / dt)):
        t = cycle * dt
        seen.append(x_person)
        delayed = seen[max(0, len(seen) - 1 - round(age / dt))]
        verdict = monitor.check(arm(x_arm), person(delayed), age, t)
        if verdict.stop and braking_since is None:
            braking_since = t
        if braking_since is not None:
            if t - braking_since >= P.engage:
                v_arm = max(0.0, v_arm - P.deceleration * dt)
        else:
            target = min(cruise, verdict.cap)
            v_arm = max(target, v_arm - accel * dt) if v_arm > target else target
        x_arm += v_arm * dt
        x_person -= walk * dt
        gap = (x_person - x_arm) - 0.2
        if v_arm > 0.0:
            assert gap > 0.0, f"met at {t:.3f}s while the arm moved at {v_arm:.3f} m/s"
        if v_arm == 0.0 and (braking_since is not None or verdict.cap == 0.0 or cruise == 0.0):
            break
