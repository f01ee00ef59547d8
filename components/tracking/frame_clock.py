"""When a tracker captured a frame, on the host's clock, from the device's frame counter.

An NDI device numbers its frames at a known rate but sends no capture time, and its
replies reach the host after a delay that varies: the device's own, the serial line's,
and a busy host's, which can hold a tty's bytes for seconds. Stamping a sample when it
arrives makes a held reply look younger than it is; stamping it when it was asked for
makes a reply held on the way out look older. Both shift the robot pose the sample is
checked against (at 10 cm/s, 50 ms is 5 mm, the calibration check's tolerance).

Frame k arriving at host time a_k bounds the counter's origin from above:
origin <= a_k - k / rate, with equality for a reply that took no time. The tightest
bound of a recent window is the estimate: its error is the quickest reply's delay
(about a millisecond on a quiet line), whatever the other replies went through. A
window, not the whole history, follows a device clock that drifts against the host's.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field


@dataclass
class FrameClock:
    """Capture times of a device's numbered frames (s, the host's wall clock)."""

    rate: float
    """How fast the device's frame counter counts (Hz)."""
    window: float = 10.0
    """How far back arrivals bound the origin (s)."""
    _bounds: deque = field(default_factory=deque, repr=False)  # (arrived, bound), rising
    _last_frame: int = -1

    def reset(self) -> None:
        """Forget the origin: the device's counter starts again (INIT, TSTART)."""
        self._bounds.clear()
        self._last_frame = -1

    def stamp(self, frame: int, asked: float, arrived: float) -> float:
        """When frame number `frame` was captured, for a reply asked for at `asked` and
        received at `arrived`: never after its arrival, nor earlier than one frame
        before it was asked for (the newest frame then), whatever the estimate says
        (a counter at another rate than `rate` is bounded, not trusted)."""
        if frame < self._last_frame:  # the counter started again
            self.reset()
        self._last_frame = frame
        bound = arrived - frame / self.rate
        bounds = self._bounds
        while bounds and bounds[-1][1] >= bound:
            bounds.pop()
        bounds.append((arrived, bound))
        while bounds[0][0] < arrived - self.window:
            bounds.popleft()
        captured = bounds[0][1] + frame / self.rate
        return min(max(captured, asked - 1.0 / self.rate), arrived)
