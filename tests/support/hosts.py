"""A deployment on several hosts of one machine (framework/netns.py): every host's
`fw deploy --host` in its namespace, the control host's with a scenario."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from framework.netns import Hosts

FW = [sys.executable, "-m", "framework.cli"]


def stretched(topology: Path, margin: float, folder: Path) -> Path:
    """A topology file laid over `topology` (`extends:`) with every safety deadline,
    watchdog, reply timeout and tracker staleness limit x `margin`, as
    `tests.conftest.with_deadlines_stretched` does to a loaded one: for runs that test
    the procedure across the hosts, not the watches, on a shared 2-core host where
    five hosts' processes starve each other (a process heartbeat 100 ms late was seen).
    test_seeg_faults.py proves the watches at the shipped deadlines."""
    import yaml

    from framework.topology import load_topology
    from tests.conftest import with_deadlines_stretched

    loaded = load_topology(topology)
    before = {name: dict(spec.properties) for name, spec in loaded.components.items()}
    loaded = with_deadlines_stretched(loaded, margin)
    assert loaded.safety is not None
    overlay: dict = {
        "extends": str(topology.resolve()),
        "safety": {
            "process_deadline": f"{loaded.safety.process_deadline * 1e3:g}ms",
            "watch": {  # those the file declares (a process's own follows process_deadline)
                w.name: f"{w.deadline * 1e3:g}ms"
                for w in loaded.safety.watches
                if not w.name.startswith("process ")
            },
        },
        "components": {},
    }
    for name, spec in loaded.components.items():
        changed = {k: v for k, v in spec.properties.items() if before[name].get(k) != v}
        if changed:
            overlay["components"][name] = {"properties": changed}
    path = folder / f"{topology.stem}_x{margin:g}.yaml"
    path.write_text(yaml.safe_dump(overlay, sort_keys=False))
    return path


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
        others = hosts.deploy_others(topology, keys, cwd, environment)
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
        hosts.end(others)


def _tail(output: bytes | str | None, lines: int = 80) -> str:
    """The last `lines` lines of a timed-out run's output."""
    text = output.decode(errors="replace") if isinstance(output, bytes) else output or ""
    return "\n".join(text.splitlines()[-lines:])
