"""`fw bench chaos --hosts`: every host of the SEEG deployment on several machines
(topologies/seeg_hosts.yaml, built as network namespaces of this one:
framework/netns.py) cut off or made lossy while the arm approaches the target at
7.5 cm/s, on a fresh deployment each time.

Each case starts every host's part (`fw deploy --host`), runs the control host's
part in the control namespace (a child process: `python -m fw_bench.hosts_chaos
--case ...`, printing its case as one JSON line; a deployment that never began its approach is
run again, at most three times, as `fw bench chaos` does), releases the arm for the approach,
and injects the link fault 0.6 s into it. A watcher on the control host cannot time
what happens behind a cut link, so the times come from the hosts that saw them: the
robot interface's report says when its stop began (`latched_at`), the simulated KRC's
when its brakes engaged (`braked_at`), both asked once the links are back (the
namespaces share this machine's clock, so the stamps compare; on real machines they
would need a synchronised clock, docs/hosts.md). From them:

* **to braking**: from the fault (when the command that made it, `ip` or `nft`,
  returned: it takes ~5-10 ms, which timing from before it would have counted as
  the robot's) to the first of the two;
* **to standstill**: from the fault to the brakes being on;
* **moved without RELEASE**: the KRC released its brakes after the fault (its count
  of releases grew: no RELEASE is sent during a case), or ended released, or a state
  it published after its brakes engaged moves faster than 1 mrad/s;
* **no stop** (a delay only): the delayed inputs stayed within their deadlines, and the
  approach went on, which is right; a partition or a loss must stop it;
* **tripped before the fault**: a stop that began before the fault (a starved host):
  the case measured nothing and says so;
* **missing from the recording**: the control host records the run as `fw deploy
  --record` does; the chart's records (events, transitions, configurations), its
  configuration requests and the Configurator's answers that were written but are not
  in the recording (all are written on the control host, so a cut link must lose none).

Delay is the kernel's netem where it has it (`framework.netns.netem_available`), else
fw's wire of two TAP devices (framework/netns_delay.py); the KRC's link has no wire
(FRI's own delay is `arm.impair`'s), so there, without netem, its delay case is not run
and the report says so.
"""

from __future__ import annotations

import argparse
import functools
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from fw_bench.chaos import STILL, Case, SetupFailed, set_up_and_run, setup_failed
from fw_bench.files import seeg_home

HOSTS = ("control", "tracking", "cameras", "robot", "krc")
FAULTS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("partition 2s", {"partition": True, "hold": 2.0}),
    ("loss 30% 5s", {"loss": 0.3, "hold": 5.0}),
    ("delay 100ms 5s", {"delay": 0.1, "hold": 5.0}),
)
"""The link faults: name, `Fault` fields (framework/scenario/model.py)."""
AFTER = 3.0
"""s after the fault ends before the reports are asked (links come back in ~1-2 s)."""
ASK_FOR = 30.0
"""s to keep asking a component for its report after the fault (its route back)."""
CASE_TIMEOUT = 240.0
"""s a case may take in all (deploy, approach, fault, reports, shutdown)."""


def chaos_on_hosts(
    repetitions: int, progress: Any = None, kinds: tuple[str, ...] = ()
) -> tuple[list[Case], list[str], list[str]]:
    """Every host x link fault (those of `kinds` only, if given: partition, loss,
    delay), `repetitions` times each, a line per case printed; the cases, the fault
    kinds this machine cannot inject (and why), and why each setup that never began
    its approach failed (the case was run again on fresh parts, as `chaos` does)."""
    from framework import netns
    from fw_bench.seeg_run import BenchError

    why = netns.available()
    if why:
        raise BenchError(f"chaos --hosts needs the hosts as network namespaces: {why}")
    skipped = []
    setups: list[str] = []
    faults = [f for f in FAULTS if not kinds or f[0].split()[0] in kinds]
    loss = netns.loss_available()
    if loss:
        faults = [f for f in faults if "loss" not in f[1]]
        skipped.append(f"loss: {loss}, not injected")
    home = seeg_home()
    topology = home / "topologies" / "seeg_hosts.yaml"
    folder = Path(tempfile.mkdtemp(prefix="fw-bench-hosts-"))
    keys = make_keys(topology, folder)
    hosts = netns.Hosts(prefix="fwb-", bridge="fwbbr0").up()
    cases: list[Case] = []
    netem = netns.netem_available()
    if not netem and any("delay" in f[1] for f in faults):
        skipped.append("delay on the KRC's link: this kernel has no sch_netem, not injected")
    plan = [
        (host, name, fault)
        for host in HOSTS
        for name, fault in faults
        if netem or host != "krc" or "delay" not in fault
    ]
    total = repetitions * len(plan)
    try:
        for _ in range(repetitions):
            for host, name, fault in plan:
                case = set_up_and_run(
                    f"{host} {name}",
                    functools.partial(run_case, hosts, topology, keys, host, name, fault),
                    setups,
                )
                cases.append(case)
                print(case.line(), file=sys.stderr, flush=True)
                if progress is not None:
                    progress(len(cases), total)
    finally:
        hosts.down()
        shutil.rmtree(folder, ignore_errors=True)
    return cases, skipped, setups


def make_keys(topology: Path, folder: Path) -> Path:
    """The keystore every host's part of `topology` uses (`fw keys`), in `folder`."""
    from fw_bench.seeg_run import BenchError

    keys = folder / "keys"
    made = subprocess.run(
        [sys.executable, "-m", "framework.cli", "keys", str(topology), "-o", str(keys)],
        capture_output=True,
        text=True,
        cwd=seeg_home(),
    )
    if made.returncode != 0:
        raise BenchError(f"fw keys failed: {made.stderr.strip()}")
    return keys


def run_case(
    hosts: Any, topology: Path, keys: Path, host: str, name: str, fault: dict[str, Any]
) -> Case:
    """One fault on a fresh deployment across the hosts (module docstring)."""
    home = seeg_home()
    parts = []
    case = Case(host, "LINK", float(fault["hold"]), link=name)
    try:
        parts = hosts.deploy_others(topology, keys, home)
        argv = [sys.executable, "-m", "fw_bench.hosts_chaos", "--case", host, name]
        argv += ["--topology", str(topology), "--keys", str(keys)]
        try:
            run = subprocess.run(
                hosts.command("control", "env", f"FW_NETNS_PREFIX={hosts.prefix}", *argv),
                capture_output=True,
                text=True,
                cwd=home,
                timeout=CASE_TIMEOUT,
            )
        except subprocess.TimeoutExpired as exc:  # what it said last, to find out why
            said = exc.stderr or ""
            said = said.decode(errors="replace") if isinstance(said, bytes) else said
            case.detail = f"{NO_VERDICT} did not end in {CASE_TIMEOUT:g} s"
            case.notes += said.strip().splitlines()[-5:]
            return case
        lines = [line for line in run.stdout.splitlines() if line.startswith("{")]
        if not lines:
            tail = (run.stderr.strip().splitlines() or ["no output"])[-1]
            case.detail = f"{NO_VERDICT} failed: {tail[:160]}"
            return case
        said = json.loads(lines[-1])
        if SETUP_FAILED in said:
            raise SetupFailed(said[SETUP_FAILED])
        return Case(**said)
    finally:
        hosts.end(parts)


def _control_case(host: str, name: str, topology: Path, keys: Path) -> Case:
    """The control host's side of a case (in its namespace): deploy its part, start
    the approach, inject the fault, ask the robot and the KRC what they did."""
    from framework.messages import ArmState
    from framework.scenario.model import Fault
    from fw_bench.seeg_run import BenchError, SeegRun

    spec = dict(FAULTS)[name]
    case = Case(host, "LINK", float(spec["hold"]), link=name, may_go_on="delay" in spec)
    recording = Path(tempfile.mkdtemp(prefix="fw-bench-case-")) / "control.mcap"
    run = SeegRun(hosts=(topology, keys), record=recording)
    try:
        try:
            run.start()
            run.watch("arm/measured", ArmState)
            before = _ask(run, "arm")
            run.send("e_START")
            run.wait_state("Moving_Fast", 30.0)
        except BenchError as exc:
            raise setup_failed(run, exc) from exc
        time.sleep(0.6)  # well into the approach: at speed
        assert run.deployment is not None
        asked = time.time()
        run.deployment.inject_fault(Fault(link=host, **spec))
        fault = time.time()  # the link is cut (or lossy) once `ip` or `nft` returned
        time.sleep(case.hold + AFTER)
        arm, robot = _ask(run, "arm"), _ask(run, "robot")
        _judge(case, run, fault, before, arm, robot)
        case.notes.append(f"the fault took {(fault - asked) * 1e3:.1f} ms to make")
        case.chart = run.last_entered(
            ("Fault", "Stopped", "No_Tracker", "Moving_Fast", "Moving_Slow", "Target_Reached")
        )
        case.recording_gaps = run.recording_gaps()
    finally:
        run.stop()
        shutil.rmtree(recording.parent, ignore_errors=True)
    return case


SETUP_FAILED = "setup_failed"
"""The key of the line the control host's run prints for a case whose deployment never
began its approach (no fault injected): the case is run again (`set_up_and_run`)."""

NO_VERDICT = "the control host's run"
"""How the detail of a case the control host's run never judged begins (it did not
end, or failed before its reports): nothing is known of its times or its motion."""


def judged(case: Case) -> bool:
    """Whether the case's control host's run judged it (times, motion, recording)."""
    return not case.detail.startswith(NO_VERDICT)


_DEADLINE = re.compile(r"\((?:deadline|timeout) (\d+(?:\.\d+)?) ms\)")


def beyond_deadline(case: Case) -> float | None:
    """How long after the deadline of the input whose silence stopped the arm the first
    braking cycle came (ms; negative: before it, as when the KRC brakes by itself
    first); None if the case was not timed or its robot said no deadline. The deadline
    counts from that input's last sample, which came before the fault: a stop later
    than the deadline after the fault is the robot side's own lateness."""
    reason = next((n for n in case.notes if n.startswith("robot: ")), "")
    found = _DEADLINE.search(reason)
    if case.to_braking_ms is None or found is None:
        return None
    return case.to_braking_ms - float(found.group(1))


def _ask(run: Any, component: str) -> dict[str, Any]:
    """`component.report`, asked until answered (its route back after a fault)."""
    until = time.monotonic() + ASK_FOR
    while True:
        try:
            return run.call(f"{component}.report")
        except Exception:  # unreachable for now: asked again until ASK_FOR
            if time.monotonic() >= until:
                raise
            time.sleep(0.2)


def _judge(
    case: Case,
    run: Any,
    fault: float,
    before: dict[str, Any],
    arm: dict[str, Any],
    robot: dict[str, Any],
) -> None:
    """The case's times and verdict from the two reports (module docstring)."""
    case.notes.append(f"robot: {robot.get('reason', '')}"[:200])  # what stopped it
    latched_at, braked_at = robot.get("latched_at"), arm.get("braked_at")
    released = int(arm.get("releases", 0)) > int(before.get("releases", 0)) + 1
    seen = [s.message for s in run.since(fault, "arm/measured")]
    moving = [
        m
        for m in seen
        if braked_at is not None
        and m.stamp >= braked_at
        and (not m.braked or max((abs(v) for v in m.velocity), default=0.0) > STILL)
    ]
    case.ended_braked = bool(arm.get("braked"))
    stopped = latched_at is not None or braked_at is not None
    carried_on = case.may_go_on and not stopped  # a delay within every deadline
    case.moved_without_release = released or bool(moving) or not (case.ended_braked or carried_on)
    if carried_on and not case.moved_without_release:
        case.detail = "no stop: the delayed inputs stayed within their deadlines"
    if moving:
        case.detail = f"moving {(moving[0].stamp - fault) * 1e3:.0f} ms after the fault"
    elif released:
        case.detail = "released after the fault without RELEASE"
    starts = [t for t in (latched_at, braked_at) if t is not None]
    if starts and min(starts) < fault:  # a stop before the fault: no time to measure
        case.detail = (
            case.detail or f"tripped {(fault - min(starts)) * 1e3:.0f} ms before the fault"
        )
        return
    if starts:
        case.to_braking_ms = (min(starts) - fault) * 1e3
    if braked_at is not None:
        case.to_standstill_ms = (braked_at - fault) * 1e3


def main(argv: list[str] | None = None) -> int:
    """`python -m fw_bench.hosts_chaos --case HOST FAULT --topology T --keys K`: one
    case's control-host side; prints the case as a JSON line."""
    parser = argparse.ArgumentParser(prog="python -m fw_bench.hosts_chaos")
    parser.add_argument("--case", nargs=2, metavar=("HOST", "FAULT"), required=True)
    parser.add_argument("--topology", type=Path, required=True)
    parser.add_argument("--keys", type=Path, required=True)
    args = parser.parse_args(argv)
    host, name = args.case
    if host not in HOSTS or name not in dict(FAULTS):
        parser.error(f"a host of {', '.join(HOSTS)} and a fault of {', '.join(dict(FAULTS))}")
    try:
        case = _control_case(host, name, args.topology, args.keys)
    except SetupFailed as exc:  # the parent runs the case again on fresh parts
        print(json.dumps({SETUP_FAILED: str(exc)}), flush=True)
        return 0
    print(json.dumps({k: v for k, v in case.__dict__.items()}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
