"""A deployment on several hosts of one machine (framework/netns.py): every host's
`fw deploy --host` in its namespace, the control host's with a scenario."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

from framework.netns import KRC, Hosts

FW = [sys.executable, "-m", "framework.cli"]


def run_on_hosts(
    hosts: Hosts,
    topology: Path,
    keys: Path,
    scenario: Path,
    cwd: Path,
    timeout: float = 180,
    environment: dict[str, dict[str, str]] | None = None,
) -> subprocess.CompletedProcess[str]:
    """Start each host's part (all but control), then control's with `scenario`; the
    control run's output once it ends; every host's part stopped afterwards.
    `environment`: variables for a host's part, by host (a clock set apart:
    tests/support/clock_apart.py)."""
    others = []
    deploy = [*FW, "deploy", str(topology), "--keys", str(keys), "--headless"]
    try:
        for host in (*[h for h in hosts.names if h != "control"], KRC):
            variables = [f"{k}={v}" for k, v in (environment or {}).get(host, {}).items()]
            others.append(
                subprocess.Popen(
                    hosts.command(host, "env", *variables, *deploy, "--host", host),
                    cwd=cwd,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    start_new_session=True,
                )
            )
        try:
            return subprocess.run(
                hosts.command("control", *deploy, "--scenario", str(scenario)),
                cwd=cwd,
                capture_output=True,
                text=True,
                timeout=timeout,
            )
        except subprocess.TimeoutExpired as exc:
            raise AssertionError(
                f"control's run of {scenario.name} did not end in {timeout:.0f} s; it printed:\n"
                + _tail(exc.stdout)
                + "\nand on stderr:\n"
                + _tail(exc.stderr)
            ) from None
    finally:
        for proc in others:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGINT)
        for proc in others:
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)
        _empty(hosts)


def _tail(output: bytes | str | None, lines: int = 80) -> str:
    """The last `lines` lines of a timed-out run's output."""
    text = output.decode(errors="replace") if isinstance(output, bytes) else output or ""
    return "\n".join(text.splitlines()[-lines:])


def _empty(hosts: Hosts) -> None:
    """No process of this run outlives it in any host (the next run's hub port, FRI
    port and component names are the same)."""
    for host in (*hosts.names, KRC):
        pids = subprocess.run(
            ["ip", "netns", "pids", hosts.namespace(host)], capture_output=True, text=True
        ).stdout.split()
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(int(pid), signal.SIGKILL)
