"""Spec: what a device loop's thread asks of the host (framework/realtime.py). The robot
interface's loop takes SCHED_FIFO where the host gives it; a simulated device's (the
simulated OR's KRC) takes SCHED_DEADLINE with a bounded share of each period there (on
time whatever else runs, never more: a host too slow for the whole simulation slows the
simulation instead of starving the system under test), SCHED_OTHER elsewhere, and it
learns whether the host gives real-time priority (the interface's loop then has it)."""

import os
import subprocess
import sys
import threading

import pytest

from framework.realtime import PRIORITY, RealTimePolicy
from tests.conftest import REPO


def fifo_allowed() -> bool:
    """Whether this host lets this process raise a thread to SCHED_FIFO."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except (PermissionError, OSError):
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


def enter_in_a_thread(policy: RealTimePolicy, fifo: bool) -> tuple[str, int]:
    """What `enter` says, and the policy the loop's thread has after it."""
    out: dict[str, object] = {}

    def loop() -> None:
        out["said"] = policy.enter("device", PRIORITY - 1, fifo=fifo)
        out["policy"] = os.sched_getscheduler(0)

    interval = sys.getswitchinterval()
    thread = threading.Thread(target=loop)
    thread.start()
    thread.join()
    sys.setswitchinterval(interval)  # enter set it for the whole process
    return str(out["said"]), int(out["policy"])  # type: ignore[call-overload]


def in_a_process_of_its_own(script: str) -> str:
    """What `script` prints, run by a Python of its own (the scheduling, the memory lock
    and the collector are the process's: a test must not leave them to the next)."""
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60, cwd=REPO
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_a_simulated_devices_loop_without_a_period_keeps_sched_other_and_learns_the_host():
    policy = RealTimePolicy(manage_gc=False)
    said, policy_after = enter_in_a_thread(policy, fifo=False)
    assert policy_after == os.SCHED_OTHER
    assert said.startswith("SCHED_OTHER") and "a simulated device" in said
    assert policy.granted is fifo_allowed()
    assert ("the host allows it" in said) is fifo_allowed()


SCHED_DEADLINE, SCHED_RESET_ON_FORK = 6, 0x40000000


@pytest.mark.skipif(not fifo_allowed(), reason="this host gives no real-time priority")
def test_a_simulated_devices_loop_takes_a_bounded_share_of_each_period_at_sched_deadline():
    """0.3 ms of every 1 ms (the runtime as the kernel holds it: the thread's /proc
    sched), and the host's real-time priority learnt; in a process of its own, as the
    scheduling is."""
    script = (
        "import os, threading\n"
        "from framework.realtime import PRIORITY, RealTimePolicy\n"
        "policy, out = RealTimePolicy(manage_gc=False), {}\n"
        "def loop():\n"
        "    out['said'] = policy.enter('krc', PRIORITY - 1, fifo=False, period=0.001)\n"
        "    out['policy'] = os.sched_getscheduler(0)\n"
        "    tid = threading.get_native_id()\n"
        "    sched = open(f'/proc/self/task/{tid}/sched').read().splitlines()\n"
        "    out['dl'] = {l.split(':')[0].strip(): l.split(':')[1].strip()\n"
        "                 for l in sched if l.startswith('dl.')}\n"
        "t = threading.Thread(target=loop); t.start(); t.join()\n"
        "print(out['policy'], policy.granted, out['dl'].get('dl.runtime'), out['said'])\n"
    )
    policy, granted, runtime, said = in_a_process_of_its_own(script).split(" ", 3)
    # and reset on fork: a child it started would not inherit its reservation
    assert (int(policy), granted) == (SCHED_DEADLINE | SCHED_RESET_ON_FORK, "True")
    assert int(runtime) == 300_000
    assert said.startswith("SCHED_DEADLINE, 0.3 ms of every 1 ms (a simulated device")


def test_a_simulated_device_the_host_refuses_real_time_keeps_sched_other():
    """Without real-time priority (here: not asked of the host at all) no deadline is
    taken either."""
    policy = RealTimePolicy(enabled=False, manage_gc=False)
    out: dict[str, object] = {}

    def loop() -> None:
        out["said"] = policy.enter("krc", PRIORITY - 1, fifo=False, period=0.001)
        out["policy"] = os.sched_getscheduler(0)

    interval = sys.getswitchinterval()
    thread = threading.Thread(target=loop)
    thread.start()
    thread.join()
    sys.setswitchinterval(interval)
    assert out["policy"] == os.SCHED_OTHER and policy.granted is False


@pytest.mark.skipif(not fifo_allowed(), reason="this host gives no real-time priority")
def test_a_device_loop_takes_sched_fifo_where_the_host_gives_it():
    # in a process of its own: the loop also locks its process's memory (mlockall)
    script = (
        "import os, threading\n"
        "from framework.realtime import PRIORITY, RealTimePolicy\n"
        "policy, out = RealTimePolicy(manage_gc=False), {}\n"
        "def loop():\n"
        "    out['said'] = policy.enter('device', PRIORITY - 1)\n"
        "    out['fifo'] = os.sched_getscheduler(0) == os.SCHED_FIFO\n"
        "t = threading.Thread(target=loop); t.start(); t.join()\n"
        "print(out['fifo'], policy.granted, out['said'])\n"
    )
    out = in_a_process_of_its_own(script)
    assert out.startswith(f"True True SCHED_FIFO {PRIORITY - 1}")


def test_a_loop_not_asking_for_real_time_is_said_so_and_given_none():
    policy = RealTimePolicy(enabled=False, manage_gc=False)
    said, policy_after = enter_in_a_thread(policy, fifo=True)
    assert policy_after == os.SCHED_OTHER and "real-time not asked for" in said
    assert policy.granted is False


def test_the_collector_is_pythons_again_once_the_last_loop_of_the_process_has_left():
    """A loop freezes what exists and turns automatic collection off; once no loop of
    the process runs, both are undone (a frozen extension object is never freed at
    exit, and nanobind's modules then report leaks in the process's log)."""
    script = (
        "import gc\n"
        "from framework.realtime import RealTimePolicy\n"
        "policy = RealTimePolicy(enabled=False)\n"
        "policy.leave()\n"  # a leave with no loop in: nothing to undo, and no debt
        "policy.enter('a'); policy.enter('b')\n"
        "states = [(gc.isenabled(), gc.get_freeze_count() > 0)]\n"
        "policy.leave(); states.append((gc.isenabled(), gc.get_freeze_count() > 0))\n"
        "policy.leave(); states.append((gc.isenabled(), gc.get_freeze_count() > 0))\n"
        "policy.leave(); states.append((gc.isenabled(), gc.get_freeze_count() > 0))\n"
        "print(states)\n"
    )
    out = in_a_process_of_its_own(script)
    # both loops in: frozen, off; one left: still; both left: Python's; a stray leave: no change
    assert out.strip() == str([(False, True), (False, True), (True, False), (True, False)])
