"""Where the experiment harness finds the SEEG deployment it measures.

`fw bench` runs the thesis experiments on `topologies/seeg.yaml` with its charts and
procedure files: a folder laid out as this repository is. From a checkout that is the
checkout; from an installed package, the folder `FW_HOME` names, or the current folder
if it holds `topologies/seeg.yaml`.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from framework.errors import FwError
from framework.topology import Topology, load_topology

CHECKOUT = Path(__file__).resolve().parents[3]


def seeg_home() -> Path:
    """The folder holding topologies/seeg.yaml, statecharts/ and procedures/; `FwError`
    saying where it looked and what to do otherwise."""
    candidates = []
    if os.environ.get("FW_HOME"):
        candidates.append(("FW_HOME", Path(os.environ["FW_HOME"])))
    candidates += [("the current folder", Path.cwd()), ("fw's checkout", CHECKOUT)]
    for _, folder in candidates:
        if (folder / "topologies" / "seeg.yaml").is_file():
            return folder.resolve()
    looked = ", ".join(f"{what} ({folder})" for what, folder in candidates)
    raise FwError(
        "this experiment runs the SEEG deployment, and no topologies/seeg.yaml was found "
        f"in {looked}: run fw bench in an fw checkout, or set FW_HOME to one"
    )


def seeg_file(*parts: str) -> Path:
    """A file of the SEEG deployment, e.g. seeg_file('procedures', 'seeg.yaml')."""
    return seeg_home().joinpath(*parts)


def toy_topology(namespace: str, hub_port: int) -> Topology:
    """The runtime's own specs' toy deployment (two trackers, a supervisor, the swap
    chart: tests/data/toy) on a bus of its own, for the micro-benchmarks."""
    topology = load_topology(seeg_file("tests", "data", "toy", "toy.yaml"))
    topology.bus = dataclasses.replace(topology.bus, namespace=namespace, hub_port=hub_port)
    return topology
