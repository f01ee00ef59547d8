"""The one way fw reads a file a user names: a regular file, bounded in size.

A path in a topology, a statechart's `include:`, a tools file's `rom:` is text a
user (or an attacker who can write a file fw reads) chooses. Opened naively, a named
pipe blocks the reader forever, `/dev/zero` is read until memory runs out, and a
directory fails with the operating system's words and no place. `read_file` opens
without blocking, asks the open descriptor (not the path: no race with a rename)
what it is, refuses anything but a regular file, and reads at most `max_bytes`.
Its refusal is an `UnreadableFile` whose message says what the path is instead of
a file; loaders turn it into an error located where the path was written.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from framework.errors import FwError

KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)
"""What a path can be instead of a regular file, as a message names it."""


class UnreadableFile(FwError):
    """A named file cannot be read as one: missing, not a regular file, too large,
    or refused by the operating system. `missing` tells a file that is not there
    from one that is there and wrong (a loader may only warn about the first)."""

    def __init__(self, path: str | Path, reason: str, missing: bool = False):
        self.path = str(path)
        self.reason = reason
        self.missing = missing
        super().__init__(f"{self.path!r}: {reason}")


def read_file(path: str | Path, max_bytes: int) -> bytes:
    """The bytes of the regular file at `path`, at most `max_bytes` of them.

    Raises `UnreadableFile` for a path that is missing, is no regular file (a folder,
    a FIFO, a device, a socket: never opened for a blocking read), holds more than
    `max_bytes`, or cannot be opened."""
    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise UnreadableFile(path, "file not found", missing=True) from None
    except OSError as exc:
        if exc.errno == errno.ENXIO:  # a FIFO with no writer, a socket
            raise UnreadableFile(path, "not a regular file (a socket or device)") from None
        raise UnreadableFile(path, f"cannot open: {exc.strerror or exc}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            kind = next((name for test, name in KINDS if test(info.st_mode)), "not a file")
            raise UnreadableFile(path, f"{kind}, not a regular file")
        if info.st_size > max_bytes:
            raise UnreadableFile(path, f"{info.st_size:,} bytes, larger than {max_bytes:,} bytes")
        os.set_blocking(fd, True)
        chunks, size = [], 0
        while size <= max_bytes:  # the size may have grown since fstat: read one past
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > max_bytes:
            raise UnreadableFile(path, f"larger than {max_bytes:,} bytes")
        return b"".join(chunks)
    except OSError as exc:
        raise UnreadableFile(path, f"cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
