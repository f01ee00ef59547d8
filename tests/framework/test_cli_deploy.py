"""Spec: `fw deploy` runs a topology as real processes; `fw send/status/ls` talk to it;
the flight recording read back with `fw log` / `fw replay` matches what happened."""

import json
import re
import signal
import subprocess
import sys
import time

import pytest

from framework.recorder import read_recording
from framework.remote import RemoteComponent, RemoteError
from tests.conftest import REPO, interrupt, join_deployment, wait_until

TOY = REPO / "tests" / "data" / "toy"


def fw(*args, timeout=60):
    return subprocess.run(
        [sys.executable, "-m", "framework.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
    )


def deploy_in_background(topology, *options, stdout=subprocess.DEVNULL, **popen):
    """`fw deploy TOPOLOGY --headless` as its own process, bounded to 120 s; tests stop
    it with Ctrl-C (SIGINT) when they are done."""
    command = [sys.executable, "-m", "framework.cli", "deploy", str(topology), "--headless"]
    return subprocess.Popen(
        [*command, "--duration", "120", *options],
        stdout=stdout,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        **popen,
    )


@pytest.fixture
def topology(tmp_path, bus_config):
    text = (
        (TOY / "toy.yaml")
        .read_text()
        .replace(
            "topology: toy\n",
            f"topology: toy\nbus: {{namespace: {bus_config.namespace}, "
            f"hub_port: {bus_config.hub_port}}}\n",
        )
    )
    (tmp_path / "toy_chart.yaml").write_text((TOY / "toy_chart.yaml").read_text())
    path = tmp_path / "toy.yaml"
    path.write_text(text)
    return path


def chart_state(bus):
    try:
        return RemoteComponent(bus, "coordinator", 0.5).call("active")
    except RemoteError:
        return {"active": [], "pending": {}}


def settled(bus, state):
    return wait_until(
        lambda: state in chart_state(bus)["active"] and not chart_state(bus)["pending"], timeout=20
    )


def test_deploy_send_status_ls_log_replay(topology, bus_config, tmp_path):
    record = tmp_path / "run.mcap"
    deploy = deploy_in_background(
        topology,
        "--record",
        str(record),
        "--record-samples",
        "t1/out=Scalar",
        stdout=subprocess.PIPE,
    )
    bus = join_deployment(bus_config)
    try:
        assert settled(bus, "Use_T1"), deploy.stderr.read() if deploy.poll() else "no chart"
        sent = fw("send", "e_SWAP", "--topology", str(topology))
        assert sent.returncode == 0 and sent.stdout.strip() == "accepted e_SWAP"
        assert settled(bus, "Use_T2")
        refused = fw("send", "e_NOPE", "--topology", str(topology))
        assert refused.returncode == 1 and "Traceback" not in refused.stderr
        assert refused.stderr.strip() == (
            "refused e_NOPE: e_NOPE is not an operator event of this topology "
            "(those are: e_BREAK, e_SWAP)"
        )
        internal = fw(
            "send", "config.done", "--payload", '{"tag": "x"}', "--topology", str(topology)
        )
        assert internal.returncode == 1
        assert "config.done is the Coordinator's own event" in internal.stderr
        status = fw("status", "--topology", str(topology), "--json")
        info = json.loads(status.stdout)
        assert info["chart"]["active"] == ["Use_T2"]
        assert info["containers"]["trackers"] == ["t1", "t2"]
        watch = fw("status", "--topology", str(topology), "--watch", "--frames", "6")
        assert watch.returncode == 0, watch.stderr
        last = watch.stdout.strip().split("\n\n")[-3:]
        screen = "\n\n".join(last)
        assert "chart      Use_T2" in screen and "can send   e_SWAP" in screen
        assert "supervisor" in screen and "Running" in screen
        listing = fw("ls", "--topology", str(topology))
        assert "t2/out" in listing.stdout and "t2.out -> supervisor.inp" in listing.stdout
        called = fw("call", "supervisor.stats", "--topology", str(topology))
        assert called.returncode == 0, called.stderr
        assert json.loads(called.stdout)["received"] > 0
        changes = fw("call", "t1.reset", "--args", '{"to": 5}', "--topology", str(topology))
        assert changes.returncode == 1 and "t1.reset changes state" in changes.stderr
        typo = fw("call", "supervisr.stats", "--topology", str(topology))
        assert "no component 'supervisr' in 'toy'; did you mean 'supervisor'?" in typo.stderr
    finally:
        bus.close()
        out, err = interrupt(deploy)
    assert deploy.returncode == 0, err
    assert "transition Use_T1 -> Use_T2" in out and "fw: stopped" in err

    records = list(read_recording(record))
    topics = {topic for topic, _, _ in records}
    assert {"/fw/chart", "/fw/config/request", "/fw/config/ack", "/fw/components"} <= topics
    samples = [d["value"] for t, _, d in records if t == "/fw/samples/t1/out"]
    assert len(samples) > 10 and samples == sorted(samples), "port samples, in order"
    requests = [d["tag"] for t, _, d in records if t == "/fw/config/request"]
    assert requests == ["setup", "tracker_1_up", "tracker_2_up"]
    acks = [(d["tag"], d["ok"]) for t, _, d in records if t == "/fw/config/ack"]
    assert acks == [(tag, True) for tag in requests]
    stamps = [s for _, s, _ in records]
    assert stamps == sorted(stamps)

    log = fw("log", str(record))
    assert log.returncode == 0 and "request    #3 tracker_2_up" in log.stdout
    requests = [line for line in log.stdout.splitlines() if " request " in line]
    assert len(requests) == 3 and requests[-1].endswith("request    #3 tracker_2_up"), (
        "each request once: the chart's own record of it is not repeated"
    )
    chart_only = fw("log", str(record), "--topic", "/fw/chart")
    assert '"tag": "tracker_2_up"' in chart_only.stdout, "alone, the chart's record shows"
    assert "component  supervisor: Running -> Stopped" in log.stdout
    replay = fw("replay", str(record))
    assert replay.returncode == 0, replay.stderr
    assert replay.stdout.strip().splitlines()[-1] == "active: Use_T2"


def test_topology_errors_are_one_line_each_and_nothing_starts(tmp_path):
    (tmp_path / "toy_chart.yaml").write_text((TOY / "toy_chart.yaml").read_text())
    bad = tmp_path / "bad.yaml"
    bad.write_text((TOY / "toy.yaml").read_text().replace("{step: 1.0}", "{step: fast}"))
    result = fw("deploy", str(bad), "--headless", "--duration", "1")
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert f"{bad}:" in result.stderr and "property t1.step expects float" in result.stderr
    assert "starting" not in result.stderr


def test_a_second_deploy_on_a_port_in_use_says_so_and_returns(topology, bus_config):
    """The hub's port is taken (the same topology already running, or anything else):
    one clear line naming the port and what to do, exit 1, no traceback, no hang."""
    import socket

    with socket.socket() as taken:
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        taken.bind(("127.0.0.1", bus_config.hub_port))
        taken.listen()
        result = fw("deploy", str(topology), "--headless", "--duration", "5", timeout=60)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert f"port {bus_config.hub_port} on 127.0.0.1 is in use" in result.stderr
    assert "already running" in result.stderr and "tcp.rs" not in result.stderr
    assert f"(`fw status --topology {topology}`)" in result.stderr, "a command that runs"


def test_validate_checks_a_topology_with_its_chart(tmp_path):
    assert fw("validate", str(TOY / "toy.yaml")).returncode == 0
    (tmp_path / "toy_chart.yaml").write_text((TOY / "toy_chart.yaml").read_text())
    bad = tmp_path / "bad.yaml"
    bad.write_text((TOY / "toy.yaml").read_text().replace("  broken:\n", "  brokn:\n"))
    result = fw("validate", str(bad))
    assert result.returncode == 1 and "unknown-tag" in result.stdout


def test_log_of_a_missing_or_corrupt_file_is_a_clear_error(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    for path in (tmp_path / "none.mcap", junk):
        result = fw("log", str(path))
        assert result.returncode == 1 and "Traceback" not in result.stderr
        assert str(path) in result.stderr


def test_a_recording_cut_by_sigkill_reads_back_up_to_the_kill(topology, bus_config, tmp_path):
    """`fw deploy --record` (with 50 Hz port samples) is killed without warning: every
    chart step the bus carried well before the kill is in the file, and `fw log` and
    `fw replay` read it (no summary section, maybe a torn last record)."""
    import time

    from framework import messages
    from framework.coordinator import STATUS_KEY
    from framework.messages import EventMessage

    record = tmp_path / "cut.mcap"
    deploy = deploy_in_background(
        topology, "--record", str(record), "--record-samples", "t1/out=Scalar"
    )
    bus = join_deployment(bus_config)
    seen = []
    sub = bus.subscribe(
        STATUS_KEY,
        lambda s: seen.append(messages.decode(s.payload.to_bytes(), EventMessage)[0]),
        history=False,
    )
    try:
        assert settled(bus, "Use_T1")
        assert fw("send", "e_SWAP", "--topology", str(topology)).returncode == 0
        assert settled(bus, "Use_T2")
        time.sleep(1.0)  # the chart's last steps are now 1 s old: long flushed
        before = [m for m in seen if m.stamp < time.time() - 0.5]
        deploy.send_signal(signal.SIGKILL)
        deploy.wait(10)
    finally:
        sub.undeclare()
        bus.close()
    records = list(read_recording(record))
    chart = {(round(d["stamp"], 6), d["kind"]) for t, _, d in records if t == "/fw/chart"}
    missing = [m for m in before if (round(m.stamp, 6), m.name) not in chart]
    assert before and not missing, f"{len(missing)} of {len(before)} chart steps lost"
    assert any(t == "/fw/samples/t1/out" for t, _, _ in records)
    log = fw("log", str(record))
    assert log.returncode == 0 and "transition Use_T1 -> Use_T2" in log.stdout
    replay = fw("replay", str(record))
    assert replay.returncode == 0 and replay.stdout.strip().endswith("active: Use_T2")


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.mark.parametrize(
    "how",
    ["sigterm", "sighup", "sigint_of_a_background_job"],
)
def test_a_service_stop_a_closed_terminal_or_a_background_ctrl_c_stop_in_order(
    how, topology, bus_config, tmp_path
):
    """SIGTERM (a service manager's stop) and SIGHUP (the terminal closed) shut fw deploy
    down as Ctrl-C does: the components stopped, the flight recording closed whole; and
    a Ctrl-C sent to fw counts though the shell started it with SIGINT ignored (its
    background jobs are), where it used to be ignored and the robot side kept running."""
    record = tmp_path / "run.mcap"
    deploy = deploy_in_background(
        topology,
        "--record",
        str(record),
        **({"preexec_fn": _ignore_sigint} if how == "sigint_of_a_background_job" else {}),
    )
    bus = join_deployment(bus_config)
    try:
        assert settled(bus, "Use_T1")
    finally:
        bus.close()
        sent = {"sigterm": signal.SIGTERM, "sighup": signal.SIGHUP}.get(how, signal.SIGINT)
        _, err = interrupt(deploy, sig=sent)
    assert deploy.returncode == 0 and "fw: stopped" in err, err
    assert "shutting down (robot side first)" in err
    stopped = [
        d["component"]
        for t, _, d in read_recording(record)
        if t == "/fw/components" and (d.get("old"), d.get("new")) == ("Running", "Stopped")
    ]
    assert {"supervisor", "t1", "t2"} <= set(stopped), f"every component stopped: {stopped}"


def test_a_keystore_made_beforehand_is_used_and_kept(topology, tmp_path):
    """Several hosts share one keystore (`fw keys`); fw deploy --keys uses it, the
    clients need it too, and it outlives the run (it was not fw deploy's to delete)."""
    keys = tmp_path / "keys"
    made = fw("keys", str(topology), "-o", str(keys))
    assert made.returncode == 0 and "control, control_side, operator, trackers" in made.stdout
    deploy = deploy_in_background(topology, "--keys", str(keys))
    try:
        status = None
        for _ in range(60):
            status = fw("status", "--topology", str(topology), "--keys", str(keys), "--json")
            if status.returncode == 0 and "Use_T1" in status.stdout:
                break
        assert status is not None and json.loads(status.stdout)["chart"]["active"] == ["Use_T1"]
        without = fw("status", "--topology", str(topology))
        assert without.returncode == 1 and "no keystore at" in without.stderr
        assert "Traceback" not in without.stderr
    finally:
        interrupt(deploy)
    assert (keys / "operator.key").is_file(), "a keystore given to fw deploy is kept"


def test_an_invariant_never_checked_says_whether_its_state_came_or_not_past_its_grace():
    """One clear verdict: 'Target_Reached never held' beside 'PASS state Target_Reached'
    read as a contradiction; the state came, but the run ended within the grace."""
    import threading
    from types import SimpleNamespace

    from framework.scenario import Invariant, ScenarioRunner

    runner = SimpleNamespace(
        _changed=threading.Condition(), entries=[(1.0, "Root.Task.Target_Reached")]
    )
    reached = Invariant("robot.report", state="Target_Reached", grace=0.5)
    assert ScenarioRunner._unrun(runner, reached) == (
        "Target_Reached was entered but never held past its 0.5s grace "
        "(left first, or the run ended): nothing checked"
    )
    assert ScenarioRunner._unrun(runner, Invariant("robot.report", state="Fault")) == (
        "Fault was never active: nothing checked"
    )
    assert ScenarioRunner._unrun(runner, Invariant("robot.report", grace=2.0)) == (
        "the run ended within its 2s grace: nothing checked"
    )


def test_the_scenario_report_keeps_invariants_never_exercised_apart(capsys):
    from types import SimpleNamespace

    from framework.cli_deploy import scenario_report
    from framework.scenario import Verdict

    outcomes = [
        Verdict(True, "state Moving"),
        Verdict(True, "while Stopped: robot.report braked == True", "12 samples"),
        Verdict(
            True, "while No_Tracker: robot.report braked == True", "No_Tracker never held", False
        ),
    ]
    runner = SimpleNamespace(report=lambda: outcomes, scenario=SimpleNamespace(name="toy"))
    assert scenario_report(runner) == 0, "nothing failed"
    out = capsys.readouterr().out
    assert "NOT RUN while No_Tracker" in out and "PASS    while Stopped" in out
    assert "PASSED: 2 passed, 0 failed, 1 not run (nothing to check: see each)" in out
    outcomes.append(Verdict(False, "never event e_STOP", "at 3s"))
    assert scenario_report(runner) == 1
    assert "FAILED: 2 passed, 1 failed, 1 not run" in capsys.readouterr().out


def test_operator_commands_need_not_import_the_projects_components(topology, bus_config):
    """The components live in the project's own module next to the topology; once the
    deployment runs, `fw send/status/ls/call` work where that module cannot be imported
    (here: deleted), since they ask the running deployment instead of the classes."""
    project = topology.parent
    (project / "mycomps.py").write_text(
        '"""A project\'s own components."""\n'
        "from components.demo import Counter as _Counter, Sink as _Sink\n\n\n"
        "class Counter(_Counter):\n    pass\n\n\n"
        "class Sink(_Sink):\n    pass\n"
    )
    topology.write_text(
        topology.read_text()
        .replace("components.demo:Counter", "mycomps:Counter")
        .replace("components.demo:Sink", "mycomps:Sink")
    )
    deploy = deploy_in_background(topology)
    bus = join_deployment(bus_config)
    try:
        assert settled(bus, "Use_T1"), deploy.stderr.read() if deploy.poll() else "no chart"
        (project / "mycomps.py").unlink()
        status = fw("status", "--topology", str(topology), "--json")
        assert status.returncode == 0, status.stderr
        assert json.loads(status.stdout)["containers"]["trackers"] == ["t1", "t2"]
        listing = fw("ls", "--topology", str(topology))
        assert "t1 (mycomps:Counter)" in listing.stdout, listing.stdout + listing.stderr
        called = fw("call", "supervisor.stats", "--topology", str(topology))
        assert called.returncode == 0 and json.loads(called.stdout)["received"] > 0
        refused = fw("call", "t1.reset", "--topology", str(topology))
        assert refused.returncode == 1 and "t1.reset changes state" in refused.stderr
        typo = fw("call", "t1.rest", "--topology", str(topology))
        assert "t1 has no operation 'rest'; did you mean 'reset'?" in typo.stderr
        sent = fw("send", "e_SWAP", "--topology", str(topology))
        assert sent.returncode == 0 and sent.stdout.strip() == "accepted e_SWAP", sent.stderr
        watch = fw("status", "--topology", str(topology), "--watch", "--frames", "2")
        assert watch.returncode == 0 and "can send" in watch.stdout, watch.stderr
        for run in (status, listing, called, sent, watch):
            assert "mycomps" not in run.stderr and "Traceback" not in run.stderr
    finally:
        bus.close()
        interrupt(deploy)


def test_without_a_terminal_the_console_is_served_and_its_link_kept_for_its_owner(
    topology, tmp_path
):
    """A deployment started by a service or nohup (no terminal, not --headless) serves
    the console (here on any free port); the link with its login goes to the log and to
    console.url, mode 0600."""
    import stat

    workdir = tmp_path / "work"
    done = fw(
        "deploy", str(topology), "--duration", "3", "--console-port", "0",
        "--workdir", str(workdir),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    said = re.search(r"operator console on (\S+) \(.*also in (\S+), readable", done.stderr)
    assert said, done.stderr
    saved = workdir / "console.url"
    assert said.group(2) == str(saved) and saved.read_text().strip() == said.group(1)
    assert "token=" in said.group(1)
    assert stat.S_IMODE(saved.stat().st_mode) == 0o600


def test_without_a_terminal_a_taken_console_port_leaves_the_deployment_running(topology):
    """On the default port, taken (another deployment's console, anything): said in one
    line, and the deployment runs on (a service must not fail for want of its page)."""
    import socket

    from framework.console.server import DEFAULT_PORT

    with socket.socket() as taken:
        try:
            taken.bind(("127.0.0.1", DEFAULT_PORT))
            taken.listen()
        except OSError:
            pass  # someone else holds it: taken all the same
        done = fw("deploy", str(topology), "--duration", "3")
    assert done.returncode == 0, done.stderr
    assert f"fw: no operator console: cannot serve the console on 127.0.0.1:{DEFAULT_PORT}" in (
        done.stderr
    )
    assert "the deployment runs on without it" in done.stderr and "Traceback" not in done.stderr


def test_a_stop_signal_during_the_shutdown_at_a_runs_end_changes_nothing(topology):
    """A run that ends by itself (its `--duration`, its scenario) shuts down in order,
    and a Ctrl-C or a service manager's stop that comes meanwhile is ignored, as one
    during a Ctrl-C's shutdown is: it used to cut the shutdown short, leaving fw
    waiting forever for threads nobody stopped and the robot side's processes running."""
    deploy = deploy_in_background(topology, "--duration", "4")
    err = []
    try:
        for line in deploy.stderr:  # until the run's own end begins
            err.append(line)
            if "the run is over" in line:
                break
        for _ in range(500):  # a signal every 20 ms until fw has stopped (10 s at most)
            if deploy.poll() is not None:
                break
            deploy.send_signal(signal.SIGTERM)
            time.sleep(0.02)
        _, rest = interrupt(deploy, sig=signal.SIGTERM)
    finally:
        if deploy.poll() is None:
            deploy.kill()
    err.append(rest or "")
    text = "".join(err)
    assert deploy.returncode == 0 and "fw: stopped" in text, text[-2000:]
