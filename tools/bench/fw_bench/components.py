"""Components only the benchmarks deploy (never part of a procedure)."""

from __future__ import annotations

import time

from framework.component import Component, Out
from framework.messages import Scalar


class Pinger(Component):
    """Writes `Scalar(time.perf_counter(), n)` each update: the stamp is the monotonic
    clock shared by every process on the machine, so receivers can measure latency."""

    out = Out(Scalar, doc="stamped counter")

    def configure_hook(self) -> bool:
        self.n = 0
        return True

    def update_hook(self) -> None:
        self.n += 1
        self.out.write(Scalar(time.perf_counter(), float(self.n)))
