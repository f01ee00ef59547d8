"""Spec: docs/tutorial.md works as written. Every `$` command of its console blocks runs
in a fresh folder, in order, as real processes, and every line shown under a command
appears in what it printed. Two liberties, both for running beside other tests: the
procedure gets this test's own bus port (`fw new procedure ... --port`), and `fw
deploy` runs headless in the background (the tutorial's "second terminal") until the
last command, then Ctrl-C (SIGINT) stops it, as a user would."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time

from tests.conftest import REPO, interrupt

TUTORIAL = REPO / "docs" / "tutorial.md"


def commands() -> list[tuple[str, list[str]]]:
    """(command, the lines shown under it) of every console block, in order."""
    out: list[tuple[str, list[str]]] = []
    for block in re.findall(r"```console\n(.*?)```", TUTORIAL.read_text(), re.S):
        for line in block.splitlines():
            if line.startswith("$ "):
                out.append((line[2:].strip(), []))
            elif line.strip() and out:
                out[-1][1].append(line.strip())
    return out


def _fw(command: str) -> list[str]:
    """The command as an argv: `fw` is this interpreter's fw, `python` this Python."""
    argv = shlex.split(command)
    if argv[0] == "fw":
        return [sys.executable, "-m", "framework.cli", *argv[1:]]
    if argv[0] == "python":
        return [sys.executable, *argv[1:]]
    return argv


def _until_answered(argv: list[str], shown: list[str], cwd, env, timeout: float = 60.0):
    """Run a command against the running deployment until it succeeds and prints what
    the tutorial shows (a person in the second terminal would wait for the start, and
    for the rewire, just the same); the last attempt after `timeout`."""
    deadline = time.monotonic() + timeout
    while True:
        done = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=60)
        said = done.stdout + done.stderr
        if done.returncode == 0 and all(line in said for line in shown):
            return done
        if time.monotonic() > deadline:
            return done
        time.sleep(0.5)


def test_the_tutorial_runs_as_written(tmp_path, bus_config):
    steps = commands()
    assert [c.split()[:2] for c, _ in steps][:1] == [["fw", "new"]], "it starts from nothing"
    assert any(c.startswith("fw deploy") for c, _ in steps)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["XDG_RUNTIME_DIR"] = str(tmp_path / "run")  # this deployment's keys, apart
    (tmp_path / "run").mkdir()
    deploy = None
    try:
        for command, shown in steps:
            argv = _fw(command)
            if command.startswith("fw new procedure"):
                argv += ["--port", str(bus_config.hub_port)]
            if command.startswith("fw deploy"):
                deploy = subprocess.Popen(
                    [*argv, "--headless", "--duration", "120"],
                    cwd=tmp_path,
                    env=env,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.PIPE,
                    text=True,
                )
                continue
            if deploy is not None:
                done = _until_answered(argv, shown, tmp_path, env)
            else:
                done = subprocess.run(
                    argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
                )
            said = done.stdout + done.stderr
            expect_failure = any("did you mean" in line for line in shown)
            assert (done.returncode != 0) == expect_failure, f"$ {command}\n{said}"
            for line in shown:
                assert line in said, f"$ {command}\nexpected {line!r} in:\n{said}"
    finally:
        if deploy is not None:
            _, err = interrupt(deploy)
            assert deploy.returncode == 0, err
