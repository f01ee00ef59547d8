"""A chart file checked whole, for `fw validate`: built, validated, and with its
topology, cross-checked against the configurations it names.

This sits above the loader, the validator and the topology checks, which each stay
free of the others' files (the loader builds, the validator proves, the topology
checks its own chart with both): no import circle between them.
"""

from __future__ import annotations

from pathlib import Path

from framework.errors import Finding, Location
from framework.statechart.loader import build_statechart
from framework.statechart.validator import validate_chart
from framework.topology import check_topology


def topology_tags(path: str | Path) -> tuple[dict[str, Location], list[Finding]]:
    """Configuration names a topology defines, and the topology's own findings (its
    schema and every cross-check, see `framework.topology`)."""
    topology, findings = check_topology(path)
    if topology is None:
        return {}, findings
    tags = {name: c.location for name, c in topology.configurations.items()}
    return tags, findings


def validate_file(path: str | Path, topology: str | Path | None = None) -> list[Finding]:
    """Load and check a chart file (and its includes); every finding, sorted."""
    chart, findings = build_statechart(path)
    tags = None
    if topology is not None:
        tags, problems = topology_tags(topology)
        findings = findings + problems
    if chart is None:
        return findings
    # Run the static checks even after build errors (an unresolved name is simply
    # skipped by them), so one run reports everything that is wrong.
    seen = {(f.code, f.location) for f in findings}
    extra = [f for f in validate_chart(chart, tags) if (f.code, f.location) not in seen]
    return sorted(
        findings + extra, key=lambda f: (f.location.file, f.location.line, f.location.column)
    )
