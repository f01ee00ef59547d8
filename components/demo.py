"""Small components that show the component contract (topologies/demo.yaml runs them).

They are real components (no mocks): a counter that publishes at its rate, a doubler
that reacts to data, and a sink that remembers what it received. Components that fail
on purpose for the runtime's specs live with the tests (tests/support/components.py).
"""

from __future__ import annotations

import time
from typing import Any

from framework.component import Component, In, Out, operation
from framework.messages import Pose, Scalar
from framework.ports import ReadStatus
from framework.properties import prop


class Counter(Component):
    """Publishes 1, 2, 3... on `out` once per update (stamped with the wall clock)."""

    step = prop(float, 1.0, doc="increment per update")
    out = Out(Scalar, doc="the running count")

    def configure_hook(self) -> bool:
        self.value = 0.0
        return True

    def update_hook(self) -> None:
        self.value += self.step
        self.out.write(Scalar(time.time(), self.value))

    @operation
    def reset(self, to: float = 0.0) -> float:
        """Restart counting from `to`."""
        self.value = float(to)
        return self.value


class Doubler(Component):
    """Writes `gain` times every number it reads."""

    gain = prop(float, 2.0, min=0.0, max=1000.0, doc="multiplier")
    inp = In(Scalar, doc="numbers")
    out = Out(Scalar, doc="multiplied numbers")

    def update_hook(self) -> None:
        status, sample = self.inp.read()
        if status is ReadStatus.NEW:
            self.out.write(Scalar(sample.stamp, self.gain * sample.value))


class Sink(Component):
    """Remembers every sample it reads (buffer port), for inspection by operations."""

    needs_configuration = False
    inp = In(Scalar, doc="anything numeric", policy={"type": "buffer", "size": 1000})
    pose = In(Pose, doc="a pose input, to test type checks")

    def __init__(self, name: str):
        super().__init__(name)
        self.seen: list[float] = []

    def start_hook(self) -> bool:
        self.seen = []
        return True

    def update_hook(self) -> None:
        while True:
            status, sample = self.inp.read()
            if status is not ReadStatus.NEW:
                return
            self.seen.append(sample.value)

    @operation(readonly=True)
    def received(self) -> list[float]:
        """Every value read since start."""
        return list(self.seen)

    @operation(readonly=True)
    def stats(self) -> dict[str, Any]:
        """Counters of the input port."""
        return self.inp.stats.to_dict()

    @operation
    def slow(self, seconds: float = 1.0) -> str:
        """Sleeps (to test operation timeouts)."""
        time.sleep(seconds)
        return "done"

    @operation
    def fail(self) -> None:
        """Raises (to test error replies)."""
        raise ValueError("asked to fail")
