"""People's envelopes in the form the robot's separation check computes on: capsule
arrays, decoded straight from the wire by the robot interface's `envelopes` port (a
`framework.ports.TypeAdapter`), checked once where they are taken.

The detector's `Envelopes` sample holds its capsules as flat tuples of floats, right for
every other reader (the recorder, the console's scene). The robot's loop takes a new one
30 times a second, in a cycle that must also answer the KRC: decoding ~200 floats into
Python objects and then copying them into arrays cost ~40 us there (code that runs that
seldom meets cold caches). `EnvelopeCapsules` decodes the sample's bytes into float64
arrays in one call of the compiled kernel (`_fwkernel.envelopes_decode`) and judges what
the Python check `envelope_arrays` judges; without the kernel it is that check on the
decoded message, which is also what a spec holds the kernel's to.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from components.domain.kernel import _fwkernel
from framework import messages
from framework.messages import Envelopes

NOBODY = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
"""The capsules of an empty room (and of a refused sample)."""
for _empty in NOBODY:
    _empty.flags.writeable = False


class PeopleCapsules(NamedTuple):
    """An envelopes sample as capsules: `a`, `b` (n, 3) and `radius` (n,) float64 arrays
    (read-only: never change what a port gave), the camera frame's `stamp`, and `wrong`:
    why it is not a set of capsules ("" when it is; else the arrays are `NOBODY`'s). A
    named tuple: made in the loop's cycle, where a frozen dataclass costs microseconds."""

    stamp: float
    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray
    wrong: str = ""

    @property
    def capsules(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(a, b, radius)."""
        return self.a, self.b, self.radius


def envelope_arrays(
    message: Envelopes,
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray] | None, str]:
    """The capsules (a, b as (n, 3), radius as (n,)) of an envelopes sample, or why it
    is not one: lengths that do not match, or a value that is not finite (a NaN
    distance would compare as "far"), or a negative radius."""
    a, b, radius = message.a, message.b, message.radius
    if not (len(a) == len(b) == 3 * len(radius)):
        return None, _mismatch(len(a), len(b), len(radius))
    # one sum for all: a NaN or an infinity anywhere makes it so (and so do numbers too
    # large to be metres); checked on the tuples, in the cycle that took them
    if not math.isfinite(sum(a) + sum(b) + sum(radius)):
        return None, NOT_FINITE
    if (radius and min(radius) < 0.0) or not math.isfinite(message.stamp):
        return None, NEGATIVE_OR_NO_STAMP
    ends = np.array((a, b), dtype=float).reshape(2, -1, 3)
    return (ends[0], ends[1], np.array(radius, dtype=float)), ""


NOT_FINITE = "a coordinate or radius that is not finite"
NEGATIVE_OR_NO_STAMP = "a negative radius or a stamp that is not finite"


def _mismatch(na: int, nb: int, nr: int) -> str:
    return f"{na}/{nb} coordinates for {nr} capsules"


def people_capsules(message: Envelopes) -> PeopleCapsules:
    """`envelope_arrays` of a decoded sample, as `PeopleCapsules`."""
    arrays, wrong = envelope_arrays(message)
    if arrays is None:
        return PeopleCapsules(message.stamp, *NOBODY, wrong=wrong)
    a, b, radius = arrays
    for values in arrays:
        values.flags.writeable = False
    return PeopleCapsules(message.stamp, a, b, radius)


class EnvelopeCapsules:
    """The robot's `envelopes` port's adapter (framework/ports.py `TypeAdapter`):
    `Envelopes` samples read as `PeopleCapsules`. Runs in the robot loop's thread,
    which polls the port."""

    def __init__(self, compiled: bool = True):
        """`compiled`: decode with the kernel where it was built (False: the Python
        reference, for the specs that compare them)."""
        self.compiled = compiled and _fwkernel is not None
        self._prefix = messages.encode(Envelopes(), Envelopes)[:8]  # magic, version, type id
        if not self.compiled:
            self.from_bytes = self._decoded  # type: ignore[method-assign]

    def from_bytes(self, data: bytes) -> tuple[PeopleCapsules, int, int]:
        """(capsules, publisher, seq) of an encoded sample; `messages.CodecError`, as
        the message's own decoding says it, if it is not a whole `Envelopes` sample."""
        got = _fwkernel.envelopes_decode(data, self._prefix)
        if got is None:  # not a sample: the codec says why (and would it not, its value)
            return self._decoded(data)
        publisher, seq, stamp, raw, na, nb, nr, finite, radii_ok = got
        if not (na == nb == 3 * nr):
            wrong = _mismatch(na, nb, nr)
        elif not finite:
            wrong = NOT_FINITE
        elif not radii_ok or not math.isfinite(stamp):
            wrong = NEGATIVE_OR_NO_STAMP
        else:
            values = np.frombuffer(raw, dtype=float)  # read-only: bytes
            a, b = values[:na].reshape(nr, 3), values[na : na + nb].reshape(nr, 3)
            return PeopleCapsules(stamp, a, b, values[na + nb :]), publisher, seq
        return PeopleCapsules(stamp, *NOBODY, wrong=wrong), publisher, seq

    @staticmethod
    def _decoded(data: bytes) -> tuple[PeopleCapsules, int, int]:
        """`from_bytes` by the message's own decoding and `envelope_arrays`."""
        value, publisher, seq = messages.decode(data, Envelopes)
        return people_capsules(value), publisher, seq

    def from_value(self, value: Envelopes) -> PeopleCapsules:
        """A sample written in this process (a test's detector, a composite)."""
        return people_capsules(value)
