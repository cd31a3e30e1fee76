"""How long to wait for a flight controller's answer, learned from the link itself.

A fixed reply timeout is wrong both ways: 100 ms fails a Betaflight SITL on a busy 2-core
machine (it answers MSP in 10..680 ms) or a radio/Bluetooth bridge, and 1.5 s makes every lost
frame on a USB cable cost 1.5 s. :class:`ReplyTimer` measures the round trip as the session goes
and derives the wait the way TCP derives its retransmission timeout (RFC 6298, Jacobson/Karels):
a smoothed round trip plus four times its mean deviation, within ``[min_s, max_s]``; each retry
of one request waits twice as long as the one before (bounded by ``max_s``), and a round trip is
sampled only from requests answered at their first try (Karn: the answer to a retried request
could be the answer to any of its copies).

Pure arithmetic on times the caller measures: no clock, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

from thrustmap.core.errors import ConfigError

#: RFC 6298 gains: 1/8 for the mean, 1/4 for the deviation, and the wait is mean + 4 x deviation
ALPHA = 0.125
BETA = 0.25
K = 4.0


@dataclass
class ReplyTimer:
    """Adaptive reply timeout for one link.

    ``initial_s``: the wait before any round trip was measured. ``min_s``/``max_s``: bounds of
    every wait (``max_s`` also bounds the backed-off waits of retries).
    """

    initial_s: float = 0.5
    min_s: float = 0.05
    max_s: float = 1.5
    srtt_s: float | None = None
    rttvar_s: float = 0.0
    samples: int = 0
    #: the longest round trip measured so far (for reports and benchmarks)
    max_rtt_s: float = 0.0
    #: waits doubled this many times since the last sample (see :meth:`timed_out`)
    backoff: int = 0

    def __post_init__(self) -> None:
        if not 0 < self.min_s <= self.max_s:
            raise ConfigError(f"reply timer bounds must satisfy 0 < min <= max, got {self}")
        if self.initial_s <= 0:
            raise ConfigError(f"reply timer initial wait must be > 0, got {self.initial_s}")

    def sample(self, rtt_s: float) -> None:
        """A round trip measured on a request answered at its first try."""
        rtt_s = max(0.0, rtt_s)
        if self.srtt_s is None:
            self.srtt_s = rtt_s
            self.rttvar_s = rtt_s / 2
        else:
            self.rttvar_s = (1 - BETA) * self.rttvar_s + BETA * abs(self.srtt_s - rtt_s)
            self.srtt_s = (1 - ALPHA) * self.srtt_s + ALPHA * rtt_s
        self.samples += 1
        self.max_rtt_s = max(self.max_rtt_s, rtt_s)
        self.backoff = 0

    def timed_out(self) -> None:
        """A first try went unanswered: later requests start with a doubled wait until a
        round trip is measured again (RFC 6298 5.5). Without it a link slower than the
        current wait would never be measured, since only first-try answers are sampled."""
        self.backoff = min(self.backoff + 1, 5)

    @property
    def timeout_s(self) -> float:
        """The wait for a first try: smoothed round trip + 4 deviations, within the bounds."""
        raw = self.initial_s if self.srtt_s is None else self.srtt_s + K * self.rttvar_s
        raw *= 2.0**self.backoff
        return min(self.max_s, max(self.min_s, raw))

    def timeout_for_try(self, attempt: int) -> float:
        """The wait for try ``attempt`` (1-based) of one request: doubled per retry, bounded."""
        return min(self.max_s, self.timeout_s * (2.0 ** max(0, attempt - 1)))

    def describe(self) -> str:
        if self.srtt_s is None:
            return f"no round trip measured yet (waiting {self.timeout_s * 1000:.0f} ms)"
        return (
            f"round trip {self.srtt_s * 1000:.0f} ms (deviation {self.rttvar_s * 1000:.0f} ms, "
            f"longest {self.max_rtt_s * 1000:.0f} ms, {self.samples} samples): waiting "
            f"{self.timeout_s * 1000:.0f} ms"
        )
