"""Topologies: which components run where, how they are wired, and the named
configurations the Configurator applies (see docs/topologies.md).

`model` is the checked topology (`Topology`, `Step`, `Configuration`...), `loader`
reads a file and checks it (`load_topology`, `check_topology`), `console` is what its
`console:` section asks of the operator console. Importing this package gives all
three's public names.
"""

from framework.topology.loader import check_topology, load_topology
from framework.topology.model import (
    CONTROL_PROCESS,
    DEFAULT_STEP_TIMEOUT,
    LIFECYCLE,
    RESERVED_PROCESSES,
    ClassInfo,
    ComponentSpec,
    Configuration,
    Step,
    StepKind,
    Topology,
    class_info,
)

__all__ = [
    "CONTROL_PROCESS",
    "DEFAULT_STEP_TIMEOUT",
    "LIFECYCLE",
    "RESERVED_PROCESSES",
    "ClassInfo",
    "ComponentSpec",
    "Configuration",
    "Step",
    "StepKind",
    "Topology",
    "check_topology",
    "class_info",
    "load_topology",
]
