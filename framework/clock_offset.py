"""Another host's wall clock, measured: how far it may be from this host's, as an
interval that holds the truth, from request/answer round trips.

Stamps are wall-clock times of the host that made them, and an operating room's hosts
disagree by milliseconds unless synchronised. fw never trusts another host's clock
blindly: a peer's answer `T` to a question asked at this host's `t0` and answered at
`t1` was read in between, so its offset (peer minus local) lies in `[T - t1, T - t0]`,
an interval as wide as the round trip (NTP's on-wire reasoning, without its filters).
Between measurements each interval widens by the clocks' drift bound (`DRIFT`); the
intervals of the last few exchanges are intersected, each being true, so the result is
true and as narrow as the best of them. If they do not meet, a clock was stepped: only
the newest counts (a step smaller than the newest round trip is not seen as one: for at
most `KEEP` exchanges the interval may then be off by up to that round trip).

What follows for a peer's stamp `s` read at local time `now`:
- its **age** is at most `(now - s + hi) / (1 - DRIFT)`: an offset can make data look older, never
  fresher (a stop decided on age errs towards stopping);
- the local time it names is `s - mid`, off by at most half the interval's width
  (for matching it with this host's own samples, where neither error side is safer).
Unmeasured (no exchange yet), there is no bound: `age` returns None and the caller
treats the data as of unknown age.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

DRIFT = 200e-6
"""How fast two hosts' clocks may drift apart (s/s): two quartz oscillators at their
usual +-100 ppm, without any synchronisation."""

KEEP = 8
"""Exchanges intersected (the last ones; at one per second, the last 8 s)."""


UNMEASURED = "stamped by a host whose clock offset is not measured yet"
"""Why a sample from another host cannot be timed: that host's clock has not answered
yet (framework/peer_clocks.py asks at once, then every second)."""


@dataclass(frozen=True)
class Exchange:
    """One question and answer: local wall times `asked` and `answered`, the peer's
    wall time `answer` read in between."""

    asked: float
    answer: float
    answered: float

    @property
    def low(self) -> float:
        """The smallest offset (peer minus local) this exchange allows."""
        return self.answer - self.answered

    @property
    def high(self) -> float:
        """The largest offset this exchange allows."""
        return self.answer - self.asked


class OffsetEstimate:
    """The offset of one peer's clock from this host's, as a true interval (module
    docstring). One measuring thread adds; any thread reads: the exchanges are a tuple
    replaced whole, never changed while a reader goes through it."""

    def __init__(self, drift: float = DRIFT, keep: int = KEEP):
        self.drift = drift
        self.keep = keep
        self._exchanges: tuple[Exchange, ...] = ()
        self.refused = 0  # exchanges not taken (not finite, or answered before asked)

    def add(self, exchange: Exchange) -> bool:
        """Take one exchange; False (and counted) for one that cannot be true."""
        values = (exchange.asked, exchange.answer, exchange.answered)
        if not all(math.isfinite(v) for v in values) or exchange.answered < exchange.asked:
            self.refused += 1
            return False
        kept = (*self._exchanges, exchange)[-self.keep :]
        low, high = self._intersection(kept, exchange.answered)
        if low > high:  # they do not meet: a clock was stepped; the newest is the truth
            kept = (exchange,)
        self._exchanges = kept
        return True

    @property
    def measured(self) -> bool:
        """Whether any exchange was taken."""
        return bool(self._exchanges)

    def interval(self, now: float) -> tuple[float, float] | None:
        """(low, high) offset at local wall time `now`, or None if unmeasured."""
        exchanges = self._exchanges
        if not exchanges:
            return None
        return self._intersection(exchanges, now)

    def _intersection(self, exchanges: tuple[Exchange, ...], now: float) -> tuple[float, float]:
        low, high = -math.inf, math.inf
        for e in exchanges:
            widen = self.drift * max(0.0, now - e.asked)
            low = max(low, e.low - widen)
            high = min(high, e.high + widen)
        return low, high

    def age(self, stamp: float, now: float) -> float | None:
        """The most a peer's `stamp` can be old at local wall time `now` (never less
        than its true age), or None if unmeasured."""
        bounds = self.interval(now)
        if bounds is None:
            return None
        # the offset when the stamp was made may exceed today's by the drift over the
        # stamp's own age a: a <= now - stamp + high + drift * a
        return (now - stamp + bounds[1]) / (1.0 - self.drift)

    def local_time(self, stamp: float, now: float) -> float | None:
        """The local wall time a peer's `stamp` names (best estimate), or None."""
        bounds = self.interval(now)
        if bounds is None:
            return None
        return stamp - (bounds[0] + bounds[1]) / 2

    def peer_now(self, now: float) -> float | None:
        """The latest the peer's clock can read at local wall time `now`, or None if
        unmeasured: a deadline the peer set, judged by it, is never found later than it
        is (a request run after its deadline is one its requester gave up on)."""
        bounds = self.interval(now)
        if bounds is None:
            return None
        return now + bounds[1]
