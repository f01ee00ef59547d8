"""A process whose wall clock is set apart, as on a host that is not synchronised: a
small library of the tests' own (`clock_apart.c`, built here with the C compiler the
test extras install for SPIN) preloaded, moving only the wall clock; the monotonic
clock, sleeps and timed waits run true."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from functools import cache
from pathlib import Path

SOURCE = Path(__file__).with_suffix(".c")

MISSING = "no C compiler to build the clock shim (tools/install.sh --test installs gcc)"


@cache
def library() -> Path | None:
    """The shim, built once per source (None without a C compiler)."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        return None
    digest = hashlib.sha256(SOURCE.read_bytes()).hexdigest()[:12]
    built = Path(tempfile.gettempdir()) / f"fw-clock-apart-{digest}.so"
    if not built.exists():
        # a name of this process's own: the suite's two workers collect at once, and one
        # renaming a shared partial file under the other failed its collection
        partial = built.with_suffix(f".{os.getpid()}.tmp")
        subprocess.run(
            [compiler, "-shared", "-fPIC", "-O2", "-o", str(partial), str(SOURCE), "-ldl"],
            check=True,
        )
        partial.replace(built)
    return built


def environment(offset: float) -> dict[str, str]:
    """The environment that sets a process's wall clock `offset` seconds ahead (negative:
    behind) of the host's."""
    shim = library()
    if shim is None:
        raise RuntimeError(MISSING)
    return {"LD_PRELOAD": str(shim), "FW_TEST_CLOCK_OFFSET": f"{offset:+}"}
