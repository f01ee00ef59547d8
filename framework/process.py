"""One process of a deployment: what the deployer spawned and the watch looks after."""

from __future__ import annotations

import subprocess
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Process:
    """One spawned container process."""

    name: str
    components: list[str]
    shutdown: str
    popen: subprocess.Popen[bytes] | None = None
    stderr: Path | None = None

    def tail(self, lines: int = 5) -> str:
        """The last lines the process wrote to stderr (for error messages)."""
        if self.stderr is None or not self.stderr.exists():
            return ""
        text = self.stderr.read_text(errors="replace").strip().splitlines()
        return " | ".join(text[-lines:])
