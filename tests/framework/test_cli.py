"""Spec: the `fw` command teaches, answers in one line per problem, and sets exit codes."""

import json
import shutil
import subprocess
import sys

import pytest

from framework.cli import main
from tests.conftest import REPO

SEEG = str(REPO / "statecharts" / "seeg.yaml")


def test_validate_ok(capsys):
    assert main(["validate", SEEG]) == 0
    assert "ok: 1 file(s), 0 error(s)" in capsys.readouterr().err


def test_validate_reports_every_error_and_exits_1(write, capsys):
    path = write(
        "statechart: s\ninitial: Idel\nstates:\n  - {name: Idle, transitions: "
        "[{event: e, target: Movng}]}\n"
    )
    assert main(["validate", str(path)]) == 1
    out = capsys.readouterr().out.strip().splitlines()
    assert any(line.startswith(f"{path}:2:") and "Idel" in line for line in out)
    assert any(("Movng" in line and "did you mean" not in line) or "Movng" in line for line in out)


def test_validate_json_is_machine_readable(write, capsys):
    path = write(
        "statechart: s\ninitial: A\nstates:\n  - {name: A, transitions: [{event: e, target: A}]}\n"
    )
    assert main(["validate", str(path), "--json"]) == 1
    findings = json.loads(capsys.readouterr().out)
    assert findings[0]["code"] == "undeclared-event" and findings[0]["line"] == 4


def test_strict_fails_on_warnings(write, capsys):
    path = write(
        "statechart: s\nevents: {e: null, unused: null}\ninitial: A\nstates:\n"
        "  - {name: A, transitions: [{event: e, target: A}]}\n"
    )
    assert main(["validate", str(path)]) == 0
    assert main(["validate", "--strict", str(path)]) == 1


def test_validate_against_a_topology(write, capsys):
    topo = write(
        "topology: t\ncomponents: {}\nconfigurations:\n  setup_components: {}\n", "topo.yaml"
    )
    assert main(["validate", SEEG, "--topology", str(topo)]) == 1
    assert "unknown-tag" in capsys.readouterr().out


def test_yaml_syntax_errors_are_one_line(write, capsys):
    path = write("statechart: s\nstates: [\n")
    assert main(["validate", str(path)]) == 1
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith(f"{path}:") and "YAML syntax" in out[0]


def test_graph_writes_the_requested_format(tmp_path, capsys):
    out = tmp_path / "seeg.mmd"
    assert main(["graph", SEEG, "-o", str(out), "--active", "Stopped"]) == 0
    assert "class s_System_OK_Task_Stopped active" in out.read_text()
    assert main(["graph", SEEG, "-o", str(out), "--active", "Nope"]) == 1
    assert "unknown state 'Nope'" in capsys.readouterr().err


def test_run_prints_the_trace_and_the_final_state(capsys):
    code = main(
        ["run", SEEG, "--auto-ack", "-e", 'e_START,e_TOK{"tracker": "vicra"},e_CRITICAL_AREA,+2s']
    )
    out = capsys.readouterr().out
    assert code == 0 and "configure tracker_2_up" in out
    assert out.strip().splitlines()[-1] == (
        "active: System_OK.Area.Critical, System_OK.Task.Navigating.Moving.Moving_Slow"
    )


def test_run_fail_injects_configuration_failures(capsys):
    assert main(["run", SEEG, "--auto-ack", "--fail", "setup_people", "--json"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert any(x.get("state") == "Setup_Aborted" for x in lines)


def test_run_rejects_bad_tokens(capsys):
    assert main(["run", SEEG, "-e", "e_TOK{bad json"]) == 1
    assert "bad JSON payload" in capsys.readouterr().err


def test_run_names_an_event_the_chart_does_not_know_and_the_one_meant(capsys):
    assert main(["run", SEEG, "-e", "e_STRAT"]) == 1
    assert "'e_STRAT' is not an event of chart 'seeg'; did you mean 'e_START'?" in (
        capsys.readouterr().err
    )


def test_run_refuses_a_payload_the_event_does_not_declare(capsys):
    assert main(["run", SEEG, "-e", 'e_START{"speed": 2}']) == 1
    assert "e_START has no payload field 'speed'" in capsys.readouterr().err


def test_missing_files_are_reported_not_raised(capsys, tmp_path):
    assert main(["run", str(tmp_path / "none.yaml")]) == 1
    assert "file not found" in capsys.readouterr().err


def test_help_teaches_with_examples_for_every_command(capsys):
    from framework.cli import build_parser

    commands = build_parser()._subparsers._group_actions[0].choices
    missing = []
    for name in commands:
        with pytest.raises(SystemExit) as exc:
            main([name, "--help"])
        assert exc.value.code == 0
        if "examples:" not in capsys.readouterr().out:
            missing.append(name)
    assert missing == []


@pytest.mark.skipif(shutil.which("fw") is None, reason="needs `pip install -e .`")
def test_the_installed_console_script_runs_as_a_real_process(tmp_path):
    done = subprocess.run(
        ["fw", "run", SEEG, "--auto-ack", "-i"],
        input="e_START\n?\nq\n",
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert "events:" in done.stdout and "Tracker_Selection" in done.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "framework.cli", "validate", str(tmp_path / "x.yaml")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 1 and "Traceback" not in bad.stderr + bad.stdout


def test_commands_come_from_installed_packages_and_a_broken_one_only_warns(monkeypatch, capsys):
    from importlib import metadata

    from framework import cli

    installed = {e.name: e.value for e in metadata.entry_points(group=cli.COMMANDS_GROUP)}
    assert installed["bench"] == "fw_bench.cli:add_commands", "declared by the package"
    broken = metadata.EntryPoint("broken", "no_such_package.cli:add_commands", cli.COMMANDS_GROUP)
    real = list(metadata.entry_points(group=cli.COMMANDS_GROUP))
    monkeypatch.setattr(
        cli.metadata,
        "entry_points",
        lambda group: [*real, broken] if group == cli.COMMANDS_GROUP else [],
    )
    assert main(["validate", str(REPO / "statecharts" / "seeg.yaml")]) == 0
    assert "not loaded" not in capsys.readouterr().err, "fw's own command loads no plugin"
    with pytest.raises(SystemExit):
        main(["broken"])
    assert (
        "commands of 'broken' (no_such_package.cli:add_commands) not loaded"
        in capsys.readouterr().err
    )
    parser = cli.build_parser()
    assert parser.parse_args(["bench", "--quick"]).func, "the installed commands are there"


def test_only_the_command_named_is_loaded_and_one_of_another_api_is_refused(monkeypatch, capsys):
    """As ros2cli loads only the verb asked for: `fw bench` imports the bench's plugin
    and no other; a plugin written for another extension API is not loaded, and says so."""
    import sys
    import types
    from importlib import metadata

    from framework import cli

    loaded = []
    for name, api in (("alpha", 1), ("beta", 1), ("gamma", 2)):
        module = types.ModuleType(f"fw_test_plugin_{name}")
        module.FW_EXTENSION_API = api

        def add(sub, name=name):
            loaded.append(name)
            sub.add_parser(name).set_defaults(func=lambda args: 0)

        add.__module__ = module.__name__
        module.add_commands = add
        monkeypatch.setitem(sys.modules, module.__name__, module)
    entries = [
        metadata.EntryPoint(n, f"fw_test_plugin_{n}:add_commands", cli.COMMANDS_GROUP)
        for n in ("alpha", "beta", "gamma")
    ]
    monkeypatch.setattr(
        cli.metadata, "entry_points", lambda group: entries if group == cli.COMMANDS_GROUP else []
    )
    assert main(["beta"]) == 0 and loaded == ["beta"]
    loaded.clear()
    cli.build_parser([])
    assert loaded == ["alpha", "beta"], "fw --help lists every compatible one"
    assert (
        "'gamma' (fw_test_plugin_gamma:add_commands) not loaded: FwError: it is written for "
        "extension API 2, fw has 1" in capsys.readouterr().err
    )


def test_send_list_shows_each_operator_event_with_its_fields_and_a_command_that_works(capsys):
    """`fw send --list` needs no deployment: every event the topology lets an operator
    send, its doc, its payload fields (allowed values, limits, units) and a command whose
    payload the chart takes as it stands."""
    import shlex

    from framework.statechart.loader import load_statechart

    assert main(["send", "--list", "--topology", "topologies/seeg.yaml"]) == 0
    out = capsys.readouterr().out
    assert "(statecharts/seeg.yaml)" in out
    assert "where (one of target, home)" in out
    assert "x (number, -0.5..0.5 m): on the patient" in out
    chart = load_statechart(REPO / "statecharts" / "seeg.yaml", validate=False)
    commands = [line.split() for line in out.splitlines() if line.strip().startswith("fw send")]
    sent = [shlex.split(" ".join(c)) for c in commands]
    assert [c[2] for c in sent] == ["e_START", "e_GOTO", "e_RELEASE", "e_STOP", "e_DEFINE_TARGET"]
    for command in sent:
        payload = json.loads(command[4]) if command[3] == "--payload" else {}
        assert chart.events[command[2]].problem(payload) == "", command


def test_send_without_an_event_says_how_to_find_one(capsys):
    assert main(["send", "--topology", "topologies/seeg.yaml"]) == 1
    assert "name the EVENT to send (fw send --list shows them)" in capsys.readouterr().err


def test_send_help_shows_events_sent_with_their_payloads(capsys):
    with pytest.raises(SystemExit):
        main(["send", "--help"])
    out = capsys.readouterr().out
    assert """fw send e_STOP --payload '{"reason": "operator"}'""" in out
    assert """fw send e_GOTO --payload '{"where": "home"}'""" in out


def test_version_is_the_installed_packages(capsys):
    import tomllib

    with pytest.raises(SystemExit) as exit:
        main(["--version"])
    assert exit.value.code == 0
    declared = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    assert capsys.readouterr().out.strip() == f"fw {declared}"


@pytest.mark.parametrize("content", [b"# fw\n\n```sh\n", b"", b"\x89MC"])
def test_log_of_a_file_that_is_no_recording_says_so_in_words(tmp_path, capsys, content):
    """Not the MCAP reader's 'invalid magic: (35, 32, 102, ...)': what the file is not
    and what writes one."""
    notes = tmp_path / "README.md"
    notes.write_bytes(content)
    assert main(["log", str(notes)]) == 1
    err = capsys.readouterr().err
    assert f"{notes}: not a flight recording: it is no MCAP file" in err
    assert "--record run.mcap" in err and "(35, 32" not in err


def test_log_shows_lifecycle_lines_only_for_changes_or_what_was_said(hub, tmp_path, capsys):
    """A component state record with no change and no reason is no line of the
    timeline; one with a reason reads 'still Stopped (why)', not 'Stopped -> Stopped'."""
    from framework.recorder import FlightRecorder

    recorder = FlightRecorder(tmp_path / "run.mcap", hub)
    for old, new, reason in [
        ("PreOperational", "Stopped", ""),
        ("Stopped", "Stopped", ""),
        ("Stopped", "Stopped", "configure refused: no device"),
    ]:
        record = {"component": "vicra", "old": old, "new": new, "reason": reason}
        recorder.write("/fw/components", "fw.ComponentState", record)
    recorder.close()
    assert main(["log", str(tmp_path / "run.mcap"), "--topic", "/fw/components"]) == 0
    lines = [line.split("] ", 1)[1] for line in capsys.readouterr().out.splitlines()]
    assert lines == [
        "component  vicra: PreOperational -> Stopped",
        "component  vicra: still Stopped (configure refused: no device)",
    ]


def test_a_recording_closed_twice_stays_whole(hub, tmp_path):
    """Whoever closes a flight recorder last (its owner, a shutdown path) finds nothing
    to do: no error, and the file reads back."""
    from framework.recorder import FlightRecorder, read_recording

    recorder = FlightRecorder(tmp_path / "run.mcap", hub)
    recorder.write(
        "/fw/components", "fw.ComponentState", {"component": "c", "old": "a", "new": "b"}
    )
    recorder.close()
    recorder.close()
    assert [topic for topic, _, _ in read_recording(tmp_path / "run.mcap")] == ["/fw/components"]
