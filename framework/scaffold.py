"""`fw new procedure NAME`: a new procedure to start from, in a folder of its own.

What it writes is the smallest whole procedure: two components of the integrator's own
(a source of numbers and a reader), a topology that puts them in two processes with a
configuration per source, a chart that rewires the reader live on an operator's event,
and the specs that check both (docs/tutorial.md walks through it). Everything is plain
files the integrator owns: nothing refers back to this module.
"""

from __future__ import annotations

import keyword
import re
import zlib
from pathlib import Path

from framework.errors import FwError

FIRST_PORT, PORTS = 7470, 500
"""A new procedure's bus port is FIRST_PORT + a hash of its name modulo PORTS: two
procedures made on one machine rarely share one (and `--port` chooses)."""

COMPONENTS = '''\
"""The components of the {name} procedure: a source of numbers and a reader that
follows one source at a time (the chart chooses which). Make them your own."""

from __future__ import annotations

import time
from typing import Any

from framework.component import Component, In, Out, operation
from framework.messages import Scalar
from framework.ports import ReadStatus
from framework.properties import prop


class Source(Component):
    """Publishes its `level` on `out` once per update."""

    level = prop(float, 1.0, doc="the value it publishes")
    out = Out(Scalar, doc="its level, stamped with the wall clock")

    def update_hook(self) -> None:
        self.out.write(Scalar(time.time(), self.level))


class Reader(Component):
    """Reads whichever source it is connected to; says what it read last."""

    needs_configuration = False
    inp = In(Scalar, doc="the source in use")

    def __init__(self, name: str):
        super().__init__(name)
        self.value: float | None = None
        self.count = 0

    def update_hook(self) -> None:
        while True:
            status, sample = self.inp.read()
            if status is not ReadStatus.NEW:
                return
            self.value, self.count = sample.value, self.count + 1

    @operation(readonly=True)
    def last(self) -> dict[str, Any]:
        """The last value read and how many were read."""
        return {{"value": self.value, "count": self.count}}
'''

TOPOLOGY = """\
# The {name} procedure: two sources and a reader the chart rewires live.
#   fw deploy {name}.yaml
#   fw send e_SWAP --topology {name}.yaml          (in another terminal)
#   fw call reader.last --topology {name}.yaml
topology: {name}
description: Two sources and a reader that the chart moves from one to the other.
bus: {{namespace: {name}, hub_port: {port}}}
statechart: {name}_chart.yaml
external_events: [e_SWAP, e_STOP, e_RELEASE]
processes:
  sources: {{}}
  reading: {{shutdown: first}}
components:
  left:
    class: {name}_components:Source   # found next to this file: no PYTHONPATH
    process: sources
    activity: {{periodic: 50}}
    properties: {{level: 1.0}}
  right:
    class: {name}_components:Source
    process: sources
    activity: {{periodic: 50}}
    properties: {{level: 2.0}}
  reader:
    class: {name}_components:Reader
    process: reading
    activity: {{event: inp}}
prepare:
  reader.inp: [left/out, right/out]   # standby subscriptions: a swap is a local switch
configurations:
  setup:
    doc: Start both sources.
    post: {{left: running, right: running}}
  left_up:
    doc: The reader follows the left source.
    pre: {{reader: stopped}}
    do:
      - disconnect: reader.inp
      - connect: {{port: reader.inp, from: left.out}}
    post: {{reader: running}}
  right_up:
    doc: The reader follows the right source.
    pre: {{reader: stopped}}
    do:
      - disconnect: reader.inp
      - connect: {{port: reader.inp, from: right.out}}
    post: {{reader: running}}
  all_stop:
    doc: Stop reading.
    pre: {{reader: stopped}}
"""

CHART = """\
# The {name} procedure's chart: read the left source, swap on e_SWAP, stop on e_STOP.
statechart: {name}
safe_state: Stopped
events:
  e_SWAP: Read the other source.
  e_STOP: Stop reading.
  e_RELEASE: Read again after a stop.
initial: Setup
states:
  - name: Setup
    configure: setup
    transitions:
      - target: Reading
      - event: config.failed
        target: Stopped
  - name: Reading
    initial: Left
    states:
      - name: Left
        configure: left_up
        transitions:
          - event: e_SWAP
            target: Right
      - name: Right
        configure: right_up
        transitions:
          - event: e_SWAP
            target: Left
    transitions:
      - event: e_STOP
        target: Stopped
      - event: config.failed
        target: Stopped
  - name: Stopped
    configure: all_stop
    transitions:
      - event: e_RELEASE
        target: Reading
      - event: config.failed   # could not stop it: try again
        target: Stopped
"""

SPECS = '''\
"""Specs of the {name} procedure: its files are valid, and the chart moves the reader
from one source to the other on e_SWAP (on a simulated clock: no processes)."""

from pathlib import Path

from framework.clock import SimulatedClock
from framework.statechart.interpreter import Interpreter
from framework.statechart.loader import load_statechart
from framework.statechart.model import CONFIG_DONE
from framework.topology import load_topology

HERE = Path(__file__).parent


def test_the_topology_and_its_chart_are_valid():
    topology = load_topology(HERE / "{name}.yaml")  # raises, naming every error
    assert set(topology.configurations) >= {{"left_up", "right_up"}}


def test_e_swap_moves_the_reader_to_the_other_source_and_back():
    requested = []

    def acknowledge(output):
        if output.kind == "configure":
            requested.append(output.tag)
            chart.queue(CONFIG_DONE, {{"tag": output.tag}})

    chart = Interpreter(
        load_statechart(HERE / "{name}_chart.yaml"), SimulatedClock(), [], on_output=acknowledge
    )
    chart.start()
    chart.run()
    assert requested == ["setup", "left_up"]
    chart.dispatch("e_SWAP")
    assert requested[-1] == "right_up" and chart.leaves == ["Reading.Right"]
    chart.dispatch("e_SWAP")
    assert requested[-1] == "left_up"
'''


def new_procedure(name: str, where: Path, port: int | None = None) -> list[Path]:
    """Write the `name` procedure's files into `where`/`name`; the files written. Refuses
    a name that cannot be a Python module and a folder that already exists (nothing of
    the integrator's is ever overwritten)."""
    if not re.fullmatch(r"[a-z][a-z0-9_]*", name) or keyword.iskeyword(name):
        raise FwError(
            f"procedure name {name!r}: use lower-case letters, digits and _ (a Python "
            "module name), starting with a letter"
        )
    folder = where / name
    if folder.exists():
        raise FwError(f"{folder} already exists: choose another name or --dir")
    port = port if port is not None else FIRST_PORT + zlib.crc32(name.encode()) % PORTS
    files = {
        f"{name}_components.py": COMPONENTS,
        f"{name}.yaml": TOPOLOGY,
        f"{name}_chart.yaml": CHART,
        f"test_{name}.py": SPECS,
    }
    folder.mkdir(parents=True)
    written = []
    for filename, template in files.items():
        path = folder / filename
        path.write_text(template.format(name=name, port=port), encoding="utf-8")
        written.append(path)
    return written
