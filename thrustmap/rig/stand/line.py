"""Configurable text-line thrust stands (DIY stands on a serial port) as a ``Stand``.

``LineStand(port, clock, spec)`` reads the stand's lines through
:class:`~thrustmap.protocols.stands.line.LineStandDecoder` and turns them into timestamped
:class:`~thrustmap.rig.interfaces.StandSample` s:

- Timestamps come from the injected clock. Lines arrive in bursts (a 250 Hz stand read at
  50 Hz gives five lines per read); when the spec has a ``time_s`` column the newest line of a
  burst is stamped "now" and the older ones keep the stand's own spacing (never earlier than
  the previous sample, never later than now). Without a device time every line of a burst is
  stamped "now".
- ``tare()`` zeroes the thrust field on the mean of readings at rest (the offset is subtracted
  from every later sample); it refuses when the stand reports the rotor turning.
- When the spec has a keep-alive line it is sent every ``keepalive_interval_s`` from
  ``read_samples``/``service`` (any command also counts: the stand's watchdog is fed by any
  line).
- Bad lines never raise: they are counted (``error_count``) and logged with their line
  numbers (the first ``max_logged_errors`` in full, then every 100th). ``#WATCHDOG`` and
  ``#ERR`` comments from the stand are counted and logged as warnings.
- Until the stand prints its ``#COLS``-style header (it does so after reset, so a host that
  connects mid-stream misses it), named columns are looked up in the spec's ``header_names``.

``LineStandEscOutput(stand)`` is the stand's own ESC output as a ``ThrottleOutput`` when the
spec has a throttle-command template (like ``TytoEscOutput``): the stop is verified from the
stand's throttle column when it has one, else from the link (the stand keeps streaming and
does not answer ``#ERR`` to the stop command).

``load_line_spec(path)`` reads a user's own stand description (JSON, see
``line_spec_from_dict``) with errors that name the file, the key and, where it can, the line;
that reader lives in ``rig.stand.line_spec``.
"""

from __future__ import annotations

import logging
import math
import re
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, SafetyError, ThrustmapError
from thrustmap.core.units import ThrottleScale
from thrustmap.core.units import scale as lookup_scale
from thrustmap.protocols.stands.line import (
    LineComment,
    LineError,
    LineHeader,
    LineSample,
    LineStandDecoder,
    LineStandSpec,
)
from thrustmap.protocols.transport import SerialLike
from thrustmap.rig.interfaces import DeviceIdentity, Stand, StandSample, Telemetry, ThrottleOutput

__all__ = [
    "MAX_PENDING_SAMPLES",
    "STOP_TOLERANCE_PCT",
    "TARE_MAX_RPM",
    "LineStand",
    "LineStandError",
    "LineStandEscOutput",
    "LineStandTimeout",
]

log = logging.getLogger(__name__)

#: rpm above which ``tare`` refuses (the rotor is turning)
TARE_MAX_RPM = 300.0
#: a throttle reading within this many percent of 0 counts as "stopped"
STOP_TOLERANCE_PCT = 0.5
MAX_PENDING_SAMPLES = 100_000


class LineStandError(ThrustmapError):
    """The line stand did something that prevents the requested operation."""


class LineStandTimeout(LineStandError):
    """The line stand sent no usable data within the time allowed."""


@dataclass(frozen=True)
class _Raw:
    """A decoded line with its host timestamp (before the tare is applied)."""

    time_s: float
    sample: LineSample


class LineStand(Stand):
    def __init__(
        self,
        port: SerialLike,
        clock: Clock,
        spec: LineStandSpec,
        *,
        max_logged_errors: int = 20,
        read_size: int = 65536,
    ) -> None:
        self.port = port
        self.clock = clock
        self.spec = spec
        self.max_logged_errors = max_logged_errors
        self.read_size = read_size
        self.decoder = LineStandDecoder(spec)
        if spec.header_prefix is not None and spec.header_names:
            # Assume the documented column order until the stand prints its own header.
            header = spec.header_line()
            assert header is not None
            self.decoder.feed_events((header + "\n").encode())
            self.decoder.line_no = 0
        self.port.timeout = 0.0
        self.tare_offset_n = 0.0
        self.drives_esc = False
        self.banner: list[str] = []
        self.header_seen: tuple[str, ...] | None = None
        self.watchdog_trips = 0
        self.command_errors = 0
        self.lines_received = 0
        self.last_sample: LineSample | None = None
        self.last_sample_time_s: float | None = None
        self._pending: deque[_Raw] = deque(maxlen=MAX_PENDING_SAMPLES)
        self._last_time_s = -math.inf
        self._last_tx_s = -math.inf
        self._closed = False
        self._errors_seen = 0
        self.sequence_started = False
        self.sequence_ended = False
        self.resets = 0
        self._watchdog_re = re.compile(spec.watchdog_match, re.IGNORECASE)
        self._error_re = re.compile(spec.error_match, re.IGNORECASE)
        self._confirm_re = None if spec.stop_confirm is None else re.compile(spec.stop_confirm)
        #: the line number of the latest line confirming a stop (``spec.stop_confirm``)
        self.stop_confirmed_line = 0
        #: how ``close`` confirmed the stop of a running firmware program (None: it did not)
        self.stop_confirmation: str | None = None
        self.reset_verified = False  # the board fell silent after its reset
        self.opened_s = clock.now_s()  # a board that resets on open boots from here

    # -- counters ---------------------------------------------------------------------------
    @property
    def error_count(self) -> int:
        """Lines that could not be read (bad numbers, missing columns, overlong lines)."""
        return self.decoder.error_count

    # -- host -> stand ----------------------------------------------------------------------
    def send(self, data: bytes) -> None:
        """Write one whole command line (any line feeds the stand's watchdog)."""
        self.port.write(data)
        self._last_tx_s = self.clock.now_s()

    def send_stop(self) -> None:
        self.send(self.spec.stop_bytes())

    def _keepalive_due(self, now_s: float) -> bool:
        return (
            self.spec.keepalive is not None
            and now_s - self._last_tx_s >= self.spec.keepalive_interval_s
        )

    def service(self) -> None:
        """Send the keep-alive if it is due and take in whatever the stand has sent."""
        now = self.clock.now_s()
        if self._keepalive_due(now):
            data = self.spec.keepalive_bytes()
            assert data is not None
            self.send(data)
        self._pump()

    # -- stand -> host ----------------------------------------------------------------------
    def _read_available(self) -> bytes:
        chunks: list[bytes] = []
        for _ in range(64):  # bounded: a fast stand can never keep us here forever
            waiting = self.port.in_waiting
            if waiting <= 0:
                break
            data = self.port.read(min(waiting, self.read_size))
            if not data:
                break
            chunks.append(data)
        return b"".join(chunks)

    def _pump(self) -> int:
        """Read and decode what has arrived; returns the number of new samples."""
        data = self._read_available()
        if not data:
            return 0
        now = self.clock.now_s()
        samples: list[LineSample] = []
        for event in self.decoder.feed_events(data):
            if isinstance(event, LineSample):
                samples.append(event)
            elif isinstance(event, LineError):
                self._log_error(event)
            elif isinstance(event, LineComment):
                self._comment(event)
            elif isinstance(event, LineHeader):
                self.header_seen = event.names
                log.info("%s: header at line %d: %s", self.spec.name, event.line_no, event.names)
        self.lines_received = self.decoder.line_no
        for sample, time_s in zip(samples, self._stamp(samples, now), strict=True):
            self._pending.append(_Raw(time_s, sample))
        if samples:
            self.last_sample = samples[-1]
            self.last_sample_time_s = self._last_time_s
        return len(samples)

    def _stamp(self, samples: list[LineSample], now_s: float) -> list[float]:
        if not samples:
            return []
        times = [now_s] * len(samples)
        device = [s.time_s for s in samples]
        last = device[-1]
        if last is not None and all(t is not None for t in device):
            back = [last - t for t in device if t is not None]
            # Spacing from the stand's clock, unless it went backwards (a reset or a wrap).
            if all(b >= 0 for b in back) and all(
                a >= b for a, b in zip(back, back[1:], strict=False)
            ):
                times = [now_s - b for b in back]
        out: list[float] = []
        for t in times:
            t = min(max(t, self._last_time_s), now_s)
            out.append(t)
            self._last_time_s = t
        return out

    def _log_error(self, error: LineError) -> None:
        self._errors_seen += 1
        n = self._errors_seen
        if n <= self.max_logged_errors:
            log.warning("%s (line %r)", error, error.text[:80])
            if n == self.max_logged_errors:
                log.warning("%s: further bad lines are counted, not logged", self.spec.name)
        elif n % 100 == 0:
            log.warning("%s: %d bad lines so far (latest: %s)", self.spec.name, n, error)

    def _comment(self, comment: LineComment) -> None:
        text = comment.text
        if self._confirm_re is not None and self._confirm_re.match(text):
            self.stop_confirmed_line = comment.line_no
        if self.spec.sequence_end is not None and text == self.spec.sequence_end:
            self.sequence_ended = True
            log.info("%s: the firmware's sequence ended (line %d)", self.spec.name, comment.line_no)
            return
        if self._watchdog_re.match(text):
            self.watchdog_trips += 1
            log.warning(
                "%s: the stand's watchdog stopped the motor (line %d)",
                self.spec.name,
                comment.line_no,
            )
        elif self._error_re.match(text):
            self.command_errors += 1
            log.warning(
                "%s: the stand did not understand a command: %s (line %d)",
                self.spec.name,
                text,
                comment.line_no,
            )
        else:
            if len(self.banner) < 32:
                self.banner.append(text)
            log.info("%s: %s", self.spec.name, text)

    # -- Stand ------------------------------------------------------------------------------
    def identify(self) -> DeviceIdentity:
        details = {"spec": self.spec.name}
        if self.banner:
            details["banner"] = " | ".join(self.banner[:4])
        if self.header_seen is not None:
            details["columns"] = ",".join(self.header_seen)
        if self.spec.takes_throttle:
            details["throttle_scale"] = self.spec.throttle_scale
        if self.spec.source:
            details["firmware_source"] = self.spec.source
        if self.spec.verified:
            details["verified"] = self.spec.verified
        if not self.spec.drives_esc:
            details["motor"] = "driven and stopped by the flight controller (--throttle)"
        return DeviceIdentity(kind="line-stand", details=details)

    def _to_stand_sample(self, raw: _Raw) -> StandSample:
        s = raw.sample
        return StandSample(
            time_s=raw.time_s,
            thrust_n=s.thrust_n - self.tare_offset_n,
            torque_nm=s.torque_nm,
            voltage_v=s.voltage_v,
            current_a=s.current_a,
            rpm=s.rpm,
            throttle_native=s.throttle if self.drives_esc else None,
        )

    def read_samples(self) -> list[StandSample]:
        self.service()
        out = [self._to_stand_sample(raw) for raw in self._pending]
        self._pending.clear()
        return out

    def wait_for_data(self, timeout_s: float = 2.0) -> None:
        """Return once a sample has arrived (kept for ``read_samples``); raise
        ``LineStandTimeout`` naming the likely cause if none comes within ``timeout_s``."""
        deadline = self.clock.now_s() + timeout_s
        while True:
            self.service()
            if self._pending:
                return
            if self.clock.now_s() >= deadline:
                raise LineStandTimeout(self._silence_message(timeout_s))
            self.clock.sleep_s(0.005)

    def _silence_message(self, timeout_s: float) -> str:
        why = f"no data from line stand '{self.spec.name}' within {timeout_s:g} s"
        if self.error_count:
            last = self.decoder.errors[-1] if self.decoder.errors else None
            why += f"; {self.error_count} lines could not be read"
            if last is not None:
                why += f" (latest: {last})"
            why += " — wrong preset or spec file?"
        elif self.lines_received:
            why += f"; {self.lines_received} lines were only comments or headers"
        else:
            why += " (wrong port or baud rate?)"
        return why

    def tare(
        self,
        service: Callable[[], None] | None = None,
        samples: int = 50,
        timeout_s: float = 3.0,
    ) -> None:
        """Zero the thrust reading on the mean of ``samples`` readings at rest (``service`` is
        called while waiting for them)."""
        deadline = self.clock.now_s() + timeout_s
        raws: list[LineSample] = []
        while len(raws) < samples:
            self.service()
            raws += [r.sample for r in self._pending]
            self._pending.clear()
            if len(raws) >= samples or self.clock.now_s() >= deadline:
                break
            if service is not None:
                service()
            self.clock.sleep_s(0.005)
        if not raws:
            raise LineStandTimeout("cannot tare: " + self._silence_message(timeout_s))
        turning = [s.rpm for s in raws if s.rpm is not None and abs(s.rpm) > TARE_MAX_RPM]
        if turning:
            raise LineStandError(
                f"cannot tare line stand '{self.spec.name}': the rotor is turning "
                f"({max(turning):.0f} rpm); stop the motor first"
            )
        if len(raws) < samples:
            log.warning("%s: tared on %d of %d samples", self.spec.name, len(raws), samples)
        self.tare_offset_n = math.fsum(s.thrust_n for s in raws) / len(raws)
        log.info(
            "%s: tared on %d samples, thrust offset %.4f N",
            self.spec.name,
            len(raws),
            self.tare_offset_n,
        )

    # -- the firmware's own sequence --------------------------------------------------------
    def start_sequence(self) -> None:
        """Send the line that starts the firmware's own sweep (the motor will spin)."""
        if self.spec.sequence_start is None:
            raise ConfigError(f"line stand '{self.spec.name}' runs no sequence of its own")
        while self.clock.now_s() < self.opened_s + self.spec.boot_s:
            self._pump()  # its bootloader would swallow the start command
            self.clock.sleep_s(0.02)
        self._pump()
        self.sequence_started = True
        self.sequence_ended = False
        self.send(self.spec.sequence_start.encode())

    @property
    def sequence_running(self) -> bool:
        return self.sequence_started and not self.sequence_ended

    def reset_board(self) -> bool:
        """Reset the board with a DTR pulse (an Arduino's auto-reset line): its outputs stop.
        False when the port cannot drive DTR (a pseudo-terminal, a network port)."""
        try:
            port: Any = self.port
            port.dtr = False
            self.clock.sleep_s(0.05)
            port.dtr = True  # asserting DTR pulls RESET low through the board's capacitor
            self.clock.sleep_s(0.05)
            self.opened_s = self.clock.now_s()  # booting again
        except (OSError, AttributeError, ValueError) as exc:
            log.error("%s: could not reset the board by DTR: %s", self.spec.name, exc)
            return False
        self.resets += 1
        self.sequence_started = False
        log.warning("%s: board reset by a DTR pulse (its outputs stop)", self.spec.name)
        return True

    def stop_and_confirm(self, timeout_s: float = 0.5) -> str | None:
        """Send the stand's stop and wait up to ``timeout_s`` plus the firmware's own stop time
        (``spec.stop_time_s``) for it to confirm: a ``stop_confirm`` line, or a row with the
        throttle at stop. How it was confirmed, or None (not confirmed)."""
        self._pump()  # lines already here were sent before the stop
        after_line = self.decoder.line_no
        self.send_stop()
        deadline = self.clock.now_s() + timeout_s + self.spec.stop_time_s
        scale = lookup_scale(self.spec.throttle_scale)
        while True:
            self.service()
            if self.stop_confirmed_line > after_line:
                return "stop line"
            for raw in self._pending:
                s = raw.sample
                stopped = s.throttle is not None and scale.to_pct(s.throttle) <= STOP_TOLERANCE_PCT
                if s.line_no > after_line and stopped:
                    return "throttle column"
            if self.clock.now_s() >= deadline:
                return None
            self.clock.sleep_s(0.005)

    def confirm_silent(self, settle_s: float = 0.3, watch_s: float = 1.0) -> bool:
        """After a reset: True when the board prints no data row for ``watch_s`` (what it
        sent before the reset, in the first ``settle_s``, is dropped). A firmware back at its
        start waits silently; one still running its sweep prints a row at least every
        ``sequence_row_period_s``."""
        end = self.clock.now_s() + settle_s
        while self.clock.now_s() < end:
            self._read_available()
            self.clock.sleep_s(0.02)
        self.decoder = LineStandDecoder(self.spec)  # no half line from before the reset
        end = self.clock.now_s() + watch_s
        while self.clock.now_s() < end:
            events = self.decoder.feed_events(self._read_available())
            if any(isinstance(e, LineSample) for e in events):
                log.error("%s: still printing rows after the reset", self.spec.name)
                return False
            self.clock.sleep_s(0.02)
        return True

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            if self.sequence_running and self.spec.stop_command is not None:
                # the firmware's own program: its stop, confirmed (``stop_confirm``, the rows)
                self.stop_confirmation = self.stop_and_confirm()
                if self.stop_confirmation is None:
                    log.error("%s: the stop was sent but NOT confirmed", self.spec.name)
            elif self.spec.takes_throttle or self.spec.stop_command is not None:
                self.send_stop()
            # no stop command: only a reset ends the firmware's own sweep early
            if self.spec.reset_stops and self.sequence_running:
                self.reset_verified = self.reset_board() and self.confirm_silent()
                if not self.reset_verified:
                    log.error(
                        "%s: the firmware's sequence may still be running: it ends by itself "
                        "(no stop command, no watchdog) — cut the motor's power if needed",
                        self.spec.name,
                    )
        except Exception as exc:  # the port may be gone; closing must not raise
            log.warning("%s: could not send the stop command on close: %s", self.spec.name, exc)
        finally:
            self.port.close()


class LineStandEscOutput(ThrottleOutput):
    """The line stand's own ESC output (its throttle-command template) as a throttle output."""

    def __init__(self, stand: LineStand, motor: int = 0, *, verify_timeout_s: float = 0.5) -> None:
        spec = stand.spec
        if not spec.takes_throttle:
            raise ConfigError(
                f"line stand '{spec.name}' has no throttle command: it cannot drive the ESC"
            )
        self.stand = stand
        self.motor = motor
        self.verify_timeout_s = verify_timeout_s
        self.throttle_scale: ThrottleScale = lookup_scale(spec.throttle_scale)
        self.commanded_native = self.throttle_scale.lo
        self.last_verification = ""
        self._stop_sent_at_line: int | None = None
        self._errors_at_stop = 0
        stand.drives_esc = True

    def identify(self) -> DeviceIdentity:
        spec = self.stand.spec
        return DeviceIdentity(
            kind="line-stand-esc",
            motor_protocol=spec.throttle_scale,
            motor_count=1,
            details={"spec": spec.name},
        )

    def set_throttle(self, values: Mapping[int, float]) -> None:
        if set(values) - {self.motor}:
            raise SafetyError(
                f"the stand's ESC output drives one motor ({self.motor}), asked {sorted(values)}"
            )
        scale = self.throttle_scale
        native = values.get(self.motor, scale.lo)
        if not math.isfinite(native):
            raise SafetyError(f"throttle {native!r} is not a finite number")
        native = min(max(native, scale.lo), scale.hi)
        self.stand.send(self.stand.spec.command_for(native))
        self.commanded_native = native

    def keepalive(self) -> None:
        if self.stand.spec.keepalive is None:
            # No keep-alive line: refreshing the command itself is harmless.
            self.stand.send(self.stand.spec.command_for(self.commanded_native))
        self.stand.service()

    def stop(self) -> None:
        self.stand._pump()  # lines already here were sent before the stop
        errors_before = self.stand.command_errors
        self.stand.send_stop()
        self.commanded_native = self.throttle_scale.lo
        self._stop_sent_at_line = self.stand.decoder.line_no
        self._errors_at_stop = errors_before

    def verify_stopped(self) -> bool:
        """True when the stand reports its throttle at stop (or, without a throttle column,
        keeps streaming after the stop without answering ``#ERR``)."""
        stand = self.stand
        if self._stop_sent_at_line is None:
            self.stop()
        assert self._stop_sent_at_line is not None
        after_line = self._stop_sent_at_line
        has_throttle = "throttle" in stand.spec.columns
        deadline = stand.clock.now_s() + self.verify_timeout_s + stand.spec.stop_time_s
        while True:
            stand.service()
            if stand.command_errors > self._errors_at_stop:
                self.last_verification = "refused"
                log.error("%s: the stand answered #ERR to the stop command", stand.spec.name)
                return False
            fresh = [r.sample for r in stand._pending if r.sample.line_no > after_line]
            if stand.stop_confirmed_line > after_line:
                self.last_verification = "stop line"
                return True
            if has_throttle:
                for s in fresh:
                    if s.throttle is not None and self._is_stop(s.throttle):
                        self.last_verification = "throttle column"
                        return True
            elif fresh:
                self.last_verification = "link only"
                log.info(
                    "%s: stop sent and the stand is streaming; it does not report its "
                    "throttle, so the stop is confirmed by the link only",
                    stand.spec.name,
                )
                return True
            if stand.clock.now_s() >= deadline:
                self.last_verification = "timeout"
                return False
            stand.clock.sleep_s(0.005)

    def _is_stop(self, native: float) -> bool:
        pct = float(self.throttle_scale.to_pct(native))
        return pct <= STOP_TOLERANCE_PCT

    def read_telemetry(self) -> Telemetry:
        self.stand.service()
        now = self.stand.clock.now_s()
        s = self.stand.last_sample
        if s is None:
            return Telemetry(now)
        return Telemetry(
            now,
            voltage_v=s.voltage_v,
            current_a=s.current_a,
            rpm=None if s.rpm is None else (s.rpm,),
        )

    def close(self) -> None:
        pass  # the stand owns the port
