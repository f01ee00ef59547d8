"""A process whose wall clock is set apart, as on a host that is not synchronised:
libfaketime (Debian's `faketime`, installed by `tools/install.sh --test`) preloaded,
the wall clock moved, the monotonic clock left alone (deadlines and sleeps run true)."""

from __future__ import annotations

from pathlib import Path

LIBRARY = next(
    (p for p in Path("/usr/lib").glob("*/faketime/libfaketimeMT.so.1") if p.exists()), None
)
"""libfaketime's multi-threaded build, or None where it is not installed."""

MISSING = "libfaketime is not installed (Debian: faketime)"


def clock_apart(offset: float) -> dict[str, str]:
    """The environment that sets a process's wall clock `offset` seconds ahead (negative:
    behind) of the host's."""
    if LIBRARY is None:
        raise RuntimeError(MISSING)
    return {
        "LD_PRELOAD": str(LIBRARY),
        "FAKETIME": f"{offset:+}",
        "FAKETIME_DONT_FAKE_MONOTONIC": "1",
    }
