"""Injected clocks: the runner, drivers and simulator never call time.sleep directly.

``MonotonicClock`` is real time. ``SimClock`` advances only when asked, so tests run faster
than real time and never sleep for real.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    def now_s(self) -> float:
        """Seconds on a monotonic timeline (the origin is arbitrary)."""
        ...

    def sleep_s(self, duration_s: float) -> None:
        """Wait ``duration_s`` seconds (a simulated clock just advances)."""
        ...


class MonotonicClock:
    def now_s(self) -> float:
        return time.monotonic()

    def sleep_s(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s)


class SimClock:
    """A clock that only moves when told to (``sleep_s`` or ``advance_s``)."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._now_s = start_s

    def now_s(self) -> float:
        return self._now_s

    def sleep_s(self, duration_s: float) -> None:
        self.advance_s(duration_s)

    def advance_s(self, duration_s: float) -> None:
        if duration_s > 0:
            self._now_s += duration_s
