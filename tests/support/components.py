"""Components that misbehave on purpose, for the runtime's specs (never shipped).

`Flaky` fails the hook it is told to; `Broken` cannot be constructed; `Sleepy` takes a
minute to construct. Deployments started by tests name them as
`tests.support.components:Broken` (tests/conftest.py puts the checkout on the
subprocesses' PYTHONPATH).
"""

from __future__ import annotations

import time

from framework.component import Component, ConfigureError
from framework.properties import prop


class Flaky(Component):
    """A component whose hooks fail on demand (to test the lifecycle contract)."""

    fail_in = prop(
        str,
        "",
        choices=["", "configure", "start", "update", "stop", "cleanup", "exception"],
        doc="which hook fails",
    )
    how = prop(
        str,
        "raise",
        choices=["raise", "false", "refuse"],
        doc="raise (a bug), return False, or refuse (ConfigureError)",
    )

    def _maybe(self, hook: str) -> bool:
        if self.fail_in == hook:
            if self.how == "raise":
                raise RuntimeError(f"{hook} failed on purpose")
            if self.how == "refuse":
                raise ConfigureError(f"{hook} refused on purpose")
            return False
        return True

    def configure_hook(self) -> bool:
        return self._maybe("configure")

    def start_hook(self) -> bool:
        return self._maybe("start")

    def update_hook(self) -> None:
        self._maybe("update")

    def stop_hook(self) -> None:
        if self.fail_in == "stop":
            raise RuntimeError("stop failed on purpose")

    def cleanup_hook(self) -> None:
        if self.fail_in == "cleanup":
            raise RuntimeError("cleanup failed on purpose")

    def exception_hook(self) -> None:
        if self.fail_in == "exception":
            raise RuntimeError("exception hook failed on purpose")


class Broken(Component):
    """Cannot even be constructed (to test how a deployment reports a dead process)."""

    def __init__(self, name: str):
        raise RuntimeError("the device driver is missing")


class Sleepy(Component):
    """Takes a minute to construct (to test the deployer's liveliness timeout)."""

    def __init__(self, name: str):
        time.sleep(60)
        super().__init__(name)
