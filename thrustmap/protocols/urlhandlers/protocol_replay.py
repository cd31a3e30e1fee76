"""``replay://x.jsonl`` — serve a recorded transcript back to the same driver code.

URL: ``replay://<path>?strict=1&match=messages`` — the path is percent-decoded;
``replay://fixtures/a.jsonl`` is relative to the working directory, ``replay:///abs/a.jsonl`` is
absolute. Keyword arguments: ``strict=`` (default True), ``match=`` (default ``auto``),
``clock=`` (see below), plus ordinary pyserial settings.

Semantics:
- ``match=messages`` (the default for a recording of MAVLink or MSP, recognised from its bytes):
  the recording is replayed message by message, so it outlives the driver that made it — the
  rules are in ``replay_matching``. A real divergence raises ``ReplayDivergenceError`` in
  message terms ("expected PARAM_REQUEST_READ MOT_SPIN_ARM, driver sent COMMAND_LONG 209 ...")
  with the transcript line of the expected message.
- ``match=bytes`` (the default for anything else, e.g. a stand's protocol): writes are matched
  byte for byte against the recorded writes (as one stream: chunking may differ). Strict mode
  raises ``ReplayMismatchError`` at the first differing byte, naming the offset in the write
  stream, both bytes and the transcript line; writing past the end of the recording raises
  too. Non-strict mode logs, counts and carries on.
- Reads return only bytes recorded before the next recorded write, so the order of reads and
  writes is preserved. When the driver asks for more than that, it gets fewer bytes, as a serial
  port does at its timeout. Unread bytes stay readable after a write (like an input buffer);
  ``reset_input_buffer`` discards nothing, because a transcript holds only bytes the driver read.
- With ``clock=`` (a ``SimClock`` in tests) the recording's timeline is kept: a recorded read's
  bytes become readable when the clock reaches the time they arrived (relative to opening), so a
  driver polling on the clock sees exactly what it saw when recording, and a short read with a
  timeout advances the clock by the timeout. Without a clock, replay runs as fast as the driver
  goes and every byte up to the next recorded write is readable at once.
- ``close()`` logs whether the transcript was fully consumed; ``report()`` returns the numbers
  and ``assert_consumed()`` raises ``ReplayIncompleteError`` if writes or reads were left over.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass
from typing import Any
from urllib.parse import unquote, urlsplit

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from thrustmap.core.clock import Clock
from thrustmap.protocols.transcript import (
    Transcript,
    TranscriptEvent,
    TransportError,
    read_transcript,
)
from thrustmap.protocols.urlhandlers.replay_matching import Divergence, MessageReplay
from thrustmap.protocols.urlhandlers.transcript_messages import detect_protocol

log = logging.getLogger(__name__)


class ReplayMismatchError(TransportError):
    """The driver wrote something the transcript did not record."""

    def __init__(
        self,
        message: str,
        *,
        file: str,
        line: int | None,
        offset: int,
        expected: int | None,
        actual: int,
    ) -> None:
        super().__init__(message, file=file, line=line)
        self.offset = offset
        self.expected = expected
        self.actual = actual


class ReplayDivergenceError(ReplayMismatchError):
    """The driver sent a message the recording cannot answer (message-level replay)."""

    def __init__(
        self, message: str, *, file: str, line: int | None, offset: int, actual: int
    ) -> None:
        super().__init__(message, file=file, line=line, offset=offset, expected=None, actual=actual)


MATCH_MODES = ("auto", "messages", "bytes")


class ReplayIncompleteError(TransportError):
    """The driver stopped before the transcript's recorded traffic was used up."""


@dataclass(frozen=True)
class ReplayReport:
    path: str
    write_bytes_matched: int
    write_bytes_remaining: int
    read_bytes_served: int
    read_bytes_remaining: int  # recorded reads never delivered (incl. ones still buffered)
    mismatches: int  # only non-strict mode counts; strict raises on the first
    match: str = "bytes"  # "messages" or "bytes"
    unused: str = ""  # message mode: recorded messages the driver did not send (a summary)
    unanswered: str = ""  # message mode: requests the recording has no answer for
    repeats: int = 0  # message mode: requests answered with a copy of a recorded answer

    @property
    def fully_consumed(self) -> bool:
        return self.write_bytes_remaining == 0 and self.read_bytes_remaining == 0


#: transcripts store times to the nanosecond; compare with that slack
_TIME_EPS_S = 2e-9


def _truthy(text: str) -> bool:
    return text.strip().lower() not in ("0", "false", "no", "off", "")


def _byte(value: int | None) -> str:
    return "end of recording" if value is None else f"0x{value:02x}"


class ReplaySerial(SerialBase):
    """A pyserial-compatible port that plays a ``Transcript`` back."""

    def __init__(
        self,
        transcript: Transcript | None = None,
        *,
        strict: bool = True,
        clock: Clock | None = None,
        match: str = "auto",
        **serial_kwargs: Any,
    ) -> None:
        if match not in MATCH_MODES:
            raise TransportError(f"replay:// match={match!r}; expected one of {MATCH_MODES}")
        self.strict = strict
        self.match = match
        self._messages: MessageReplay | None = None
        self._clock = clock
        self._transcript: Transcript | None = None
        self._events: tuple[TranscriptEvent, ...] = ()
        self._next = 0  # index of the next event not yet released
        self._wpos = 0  # bytes of events[_next] (a write) already matched
        self._rx = bytearray()
        self._released = 0  # read-stream bytes made available so far
        self._rx_ends: deque[tuple[int, float]] = deque()  # (end offset, time) per read event
        self._origin_s = 0.0
        self._written = 0
        self._served = 0
        self._mismatches = 0
        serial_kwargs.pop("port", None)
        super().__init__(port=None, **serial_kwargs)
        if transcript is not None:
            self._load(transcript)
            self._port = f"replay://{transcript.path}"
            self.is_open = True

    def _load(self, transcript: Transcript) -> None:
        self._transcript = transcript
        self._events = tuple(e for e in transcript.events if e.direction is not None)
        self._next = 0
        self._wpos = 0
        self._rx.clear()
        self._rx_ends.clear()
        self._written = self._served = self._mismatches = self._released = 0
        self._origin_s = self._clock.now_s() if self._clock is not None else 0.0
        self._messages = None
        proto = detect_protocol(self._events) if self.match != "bytes" else None
        if proto is not None:
            self._messages = MessageReplay(self._events, proto)
        elif self.match == "messages":
            raise TransportError(
                "match=messages: the recording is neither MAVLink nor MSP", file=transcript.path
            )
        else:
            self._release()

    @property
    def transcript(self) -> Transcript:
        if self._transcript is None:
            raise PortNotOpenError()
        return self._transcript

    # -- pyserial plumbing ------------------------------------------------------------------
    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        parts = urlsplit(self._port)
        if parts.scheme.lower() != "replay":
            raise SerialException(f"expected replay://<transcript.jsonl>, got {self._port!r}")
        path = unquote(parts.netloc + parts.path)
        for key, value in (p.partition("=")[::2] for p in parts.query.split("&") if p):
            if key == "strict":
                self.strict = _truthy(unquote(value))
            elif key == "match" and unquote(value) in MATCH_MODES:
                self.match = unquote(value)
            else:
                raise TransportError(
                    f"unknown replay:// option {key}={value}; expected strict=0|1 or "
                    "match=auto|messages|bytes",
                    file=self._port,
                )
        self._load(read_transcript(path))
        self.is_open = True

    def _reconfigure_port(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def close(self) -> None:
        if not self.is_open:
            return
        self.is_open = False
        report = self.report()
        if report.fully_consumed:
            log.info("replay %s: transcript fully consumed", report.path)
        elif report.match == "messages":
            parts = []
            if report.unused:
                parts.append(f"the driver did not send {report.unused}")
            if report.unanswered:
                parts.append(f"the recording has no answer to {report.unanswered}")
            log.warning(
                "replay %s: replayed by message; %s",
                report.path,
                "; ".join(parts) or f"{report.read_bytes_remaining} recorded bytes not read",
            )
        else:
            log.warning(
                "replay %s: transcript not fully consumed (%d write bytes and %d read bytes left)",
                report.path,
                report.write_bytes_remaining,
                report.read_bytes_remaining,
            )

    # -- the replay machine ----------------------------------------------------------------
    def _advance_clock_to(self, time_s: float) -> None:
        if self._clock is not None:
            delta = self._origin_s + time_s - self._clock.now_s()
            if delta > 0:
                self._clock.sleep_s(delta)

    def _release(self) -> None:
        """Make every recorded read up to the next recorded write available."""
        while self._next < len(self._events) and self._events[self._next].direction == "r":
            event = self._events[self._next]
            self._rx += event.data
            self._released += len(event.data)
            self._rx_ends.append((self._released, event.time_s))
            self._next += 1

    def report(self) -> ReplayReport:
        path = self._transcript.path if self._transcript else str(self._port)
        replay = self._messages
        if replay is not None:
            return ReplayReport(
                path=path,
                write_bytes_matched=replay.written,
                write_bytes_remaining=replay.remaining_write_bytes(),
                read_bytes_served=self._served,
                read_bytes_remaining=replay.remaining_read_bytes() + len(self._rx),
                mismatches=replay.divergences if not self.strict else 0,
                match="messages",
                unused=replay.describe_unused(),
                unanswered=replay.describe_unanswered(),
                repeats=replay.repeats,
            )
        w_left = r_left = 0
        for index in range(self._next, len(self._events)):
            event = self._events[index]
            if event.direction == "w":
                w_left += len(event.data) - (self._wpos if index == self._next else 0)
            else:
                r_left += len(event.data)
        return ReplayReport(
            path=path,
            write_bytes_matched=self._written,
            write_bytes_remaining=w_left,
            read_bytes_served=self._served,
            read_bytes_remaining=r_left + len(self._rx),
            mismatches=self._mismatches,
        )

    def assert_consumed(self) -> ReplayReport:
        report = self.report()
        if not report.fully_consumed:
            raise ReplayIncompleteError(
                f"replay ended with {report.write_bytes_remaining} recorded write bytes and "
                f"{report.read_bytes_remaining} read bytes unused",
                file=report.path,
            )
        return report

    def _mismatch(self, offset: int, expected: int | None, actual: int, line: int | None) -> None:
        message = (
            f"driver wrote 0x{actual:02x} at write-stream byte {offset}, "
            f"transcript has {_byte(expected)}"
        )
        if self.strict:
            raise ReplayMismatchError(
                message,
                file=self.transcript.path,
                line=line,
                offset=offset,
                expected=expected,
                actual=actual,
            )
        self._mismatches += 1
        log.warning("replay %s:%s: %s", self.transcript.path, line, message)

    def _now_rel(self) -> float | None:
        return None if self._clock is None else self._clock.now_s() - self._origin_s

    def _consume_messages(self, replay: MessageReplay, data: bytes) -> None:
        start = self._written
        problems = replay.write(data, self._now_rel(), strict=self.strict)
        self._written += len(data)
        for problem in problems:
            self._diverged(problem, start)

    def _diverged(self, problem: Divergence, offset: int) -> None:
        line = problem.expected.line if problem.expected is not None else None
        message = str(problem)
        if self.strict:
            raise ReplayDivergenceError(
                message,
                file=self.transcript.path,
                line=line,
                offset=offset,
                actual=problem.actual_bytes[0] if problem.actual_bytes else 0,
            )
        self._mismatches += 1
        log.warning("replay %s:%s: %s", self.transcript.path, line, message)

    def _consume_write(self, data: bytes) -> None:
        if self._messages is not None:
            self._consume_messages(self._messages, data)
            return
        pos = 0
        while pos < len(data):
            if self._next >= len(self._events):
                self._mismatch(self._written, None, data[pos], None)
                return  # non-strict: the rest has nothing to match against
            event = self._events[self._next]
            take = min(len(event.data) - self._wpos, len(data) - pos)
            expected = event.data[self._wpos : self._wpos + take]
            actual = data[pos : pos + take]
            if expected != actual:
                i = next(k for k in range(take) if expected[k] != actual[k])
                self._mismatch(self._written + i, expected[i], actual[i], event.line)
            self._written += take
            self._wpos += take
            pos += take
            if self._wpos == len(event.data):
                self._next += 1
                self._wpos = 0
                self._release()

    # -- data ------------------------------------------------------------------------------
    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        return self._available()

    def _available(self) -> int:
        """Bytes readable now. With a clock, a recorded read's bytes arrive at its recorded time
        (as they did from the device), so the driver sees the same timeline it saw then."""
        if self._messages is not None:
            self._rx += self._messages.take_due(self._now_rel(), _TIME_EPS_S)
            return len(self._rx)
        if self._clock is None:
            return len(self._rx)
        now_rel = self._clock.now_s() - self._origin_s + _TIME_EPS_S
        ready = self._served
        for end, time_s in self._rx_ends:
            if time_s > now_rel:
                break
            ready = end
        return ready - self._served

    def _next_arrival_rel(self) -> float | None:
        """Recorded time of the first byte not yet readable (None: nothing before the next write)."""
        if self._clock is None:
            return None
        if self._messages is not None:
            return self._messages.next_due()
        pending = self._served + self._available()
        return next((t for end, t in self._rx_ends if end > pending), None)

    def read(self, size: int = 1, /) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        available = self._available()
        if size < 0:
            size = available
        if available < size and self.timeout and self._clock is not None:
            # Block like a serial port: until the bytes arrive (at their recorded time) or the
            # timeout passes, whichever comes first.
            deadline_rel = self._clock.now_s() - self._origin_s + float(self.timeout)
            arrival = self._next_arrival_rel()
            while arrival is not None and arrival <= deadline_rel and available < size:
                self._advance_clock_to(arrival)
                available = self._available()
                previous, arrival = arrival, self._next_arrival_rel()
                if arrival is not None and arrival <= previous:
                    break  # no progress (rounding): let the timeout below move the clock
            if available < size:
                self._advance_clock_to(deadline_rel)
        data = bytes(self._rx[: min(size, available)])
        del self._rx[: len(data)]
        self._served += len(data)
        while self._messages is None and self._rx_ends and self._rx_ends[0][0] <= self._served:
            self._rx_ends.popleft()
        return data

    def write(self, b: Any, /) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        data = bytes(b)
        self._consume_write(data)
        return len(data)

    def flush(self) -> None:
        pass

    def reset_input_buffer(self) -> None:
        """Discard nothing: every recorded read was read by the driver after its resets."""

    def reset_output_buffer(self) -> None:
        pass


class Serial(ReplaySerial):
    """The class pyserial instantiates for ``replay://`` URLs."""

    def __init__(
        self,
        port: str | None = None,
        *args: Any,
        strict: bool = True,
        clock: Clock | None = None,
        match: str = "auto",
        **kwargs: Any,
    ) -> None:
        if args:
            raise TypeError("replay:// takes keyword arguments only (timeout=..., strict=...)")
        super().__init__(None, strict=strict, clock=clock, match=match, **kwargs)
        if port is not None:
            self.port = port
            self.open()
