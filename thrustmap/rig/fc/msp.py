"""Betaflight / INAV flight controller over MSP, as a ``ThrottleOutput``.

Motor test semantics (docs/msp.md): SET_MOTOR values (external 1000..2000) apply
only while disarmed and the firmware keeps the last value FOREVER, even after the host dies.
So this driver:
- refuses to run when the FC reports ARMED, and disables arming (SET_ARMING_DISABLED 1) while
  testing, as Betaflight Configurator's motor tab does;
- always sends all 8 motor values (newer firmware answers ``!`` to shorter; INAV wants 16 bytes);
- on stop sends 1000 for every motor and confirms with MSP_MOTOR that the stop took;
- as a context manager, stops and verifies on every way out (see ``ThrottleOutput``), and
  re-enables arming only after a verified stop.

The throttle scale it exposes is the ESC's own (DShot 48..2047, PWM 1000..2000 µs, Oneshot...),
from ADVANCED_CONFIG's motor protocol; MSP's external units stay inside this driver.

MSP_MOTOR reads 0 for a motor the FC reports nothing about: its motor output is off, or (a SITL
with no simulator attached) its control loop is not running, so the values SET_MOTOR asked for
never reach ``motor[]``. 0 is "no information", never "stopped": such a stop is sent and
acknowledged but cannot be verified (``verify_stopped()`` is False and ``stop_unverifiable``
says why). Real motors read at least the stop value (1000) when the output is live.

Because the firmware never times a motor value out, the preflight (before arming is disabled
and any motor command) starts a watchdog process (:mod:`thrustmap.rig.watchdog`) when the
driver knows the port's URL: if this process dies without a clean stop, the watchdog reopens
the port and stops the motors. A clean close disarms it.

Timing comes from the link itself (issue 20): a SITL on a busy machine answers in 10..680 ms,
a radio bridge slower still. Each request's wait is learned from the measured round trip
(:class:`~thrustmap.rig.fc.link_timing.ReplyTimer`, 50 ms..1.5 s per try, doubled per retry),
and a late answer to an earlier try is the answer too. Replies are matched to requests by
command in send order (an FC answers in order); replies to nothing still waiting — the late
twins of a retried request, an earlier connection's leftovers — are dropped and counted
(``stale_replies``). Motor commands and telemetry requests do not wait for their replies (a
slow link would hold a run's loop up); the stop goes out at once and is re-sent every
``stop_resend_s`` while the MSP_MOTOR read that verifies it waits. A session that commanded no
motor sends no stop at all.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, SafetyError, ThrustmapError
from thrustmap.protocols.msp.framing import (
    MspCommand,
    MspDecoder,
    MspFrame,
    MspVersion,
    encode_request,
)
from thrustmap.protocols.msp.messages import (
    ApiVersion,
    BatteryState,
    BoardInfo,
    FcVariant,
    FcVersion,
    SetArmingDisabled,
    Status,
)
from thrustmap.protocols.msp.motor import (
    MSP_MOTOR_STOP,
    AdvancedConfig,
    Motor,
    MotorConfig,
    MotorProtocol,
    MotorTelemetry,
    SetMotor,
    native_to_external,
    throttle_scale_for,
)
from thrustmap.protocols.transport import SerialLike
from thrustmap.rig.fc.link_lock import IntruderWatch
from thrustmap.rig.fc.link_timing import ReplyTimer
from thrustmap.rig.interfaces import DeviceIdentity, Telemetry, ThrottleOutput

if TYPE_CHECKING:
    from thrustmap.rig.watchdog_handle import Watchdog

log = logging.getLogger(__name__)

MSP_MOTOR_SLOTS = 8
#: the outcome of reading MSP_MOTOR after a stop
StopCheck = Literal["verified", "running", "unverifiable"]
VARIANTS = {"BTFL": "betaflight", "INAV": "inav", "CLFL": "cleanflight", "EMUF": "emuflight"}


class MspTimeout(ThrustmapError):
    """The FC did not answer an MSP request (it ignores bad frames silently)."""


class MspLinkLost(MspTimeout):
    """The port itself failed (a socket closed, a USB adapter unplugged): no reply can come."""


class MspRefused(ThrustmapError):
    """The FC answered with an MSP error frame (``!``): unknown or refused command."""


@dataclass
class _Sent:
    """A request on the wire whose reply has not been read yet."""

    cmd: int
    sent_s: float
    request_id: int | None  # None: sent without waiting for its reply (the re-sent stop)
    on_reply: Callable[[MspFrame], None] | None = None  # for a reply nobody waits for


class MspThrottleOutput(ThrottleOutput):
    def __init__(
        self,
        port: SerialLike,
        clock: Clock,
        *,
        timeout_s: float | None = None,
        retries: int = 3,
        max_timeout_s: float = 1.5,
        stop_resend_s: float = 0.1,
        version: MspVersion = MspVersion.V1,
        url: str | None = None,
        baudrate: int | None = None,
        watchdog: bool = True,
        watchdog_log: str | None = None,
    ) -> None:
        """``timeout_s``: None (the default) learns the wait for each reply from the link's
        measured round trip (:class:`ReplyTimer`, at most ``max_timeout_s`` per try, doubled
        per retry); a number fixes it (every try waits exactly that long). ``retries``: tries
        after the first before a request fails. ``stop_resend_s``: while a stop waits for its
        verifying MSP_MOTOR, the stop is re-sent this often.

        ``url``/``baudrate``: how ``port`` was opened. With them (and ``watchdog``), the
        preflight starts the motor-stop watchdog on the same port (not for simulated or
        replayed ports, which end with this process)."""
        if retries < 0:
            raise ConfigError(f"retries must be >= 0, got {retries}")
        self.port = port
        self.clock = clock
        self.timeout_s = timeout_s
        self.retries = retries
        self.stop_resend_s = stop_resend_s
        #: motor commands sent and not yet answered before the next one waits for a reply
        self.max_motor_commands_in_flight = 3
        self._motor_refused = False
        self._esc_telemetry = True  # False once the FC refused MOTOR_TELEMETRY
        self._battery: tuple[float, BatteryState] | None = None  # latest reply, when it came
        self._esc: tuple[float, MotorTelemetry] | None = None
        self.timer = ReplyTimer(max_s=max_timeout_s, min_s=min(0.05, max_timeout_s))
        self.version = version
        self._decoder = MspDecoder()
        self._sent: deque[_Sent] = deque(maxlen=256)  # bounded: a dead FC answers nothing
        self._next_request_id = 0
        self._drained = False
        #: replies that answered no request still waiting (late answers to a request already
        #: answered or given up, or left over from an earlier connection): dropped
        self.stale_replies = 0
        #: requests the FC never answered (a later request was answered first)
        self.lost_requests = 0
        self._identity: DeviceIdentity | None = None
        self.motor_protocol = MotorProtocol.DSHOT600
        self.throttle_scale = throttle_scale_for(self.motor_protocol)
        self._arming_disabled = False
        self._motor_count: int | None = None
        self._last_motor_values: tuple[int, ...] = ()
        self._motors_may_run = False  # a motor command went out since the last confirmed stop
        #: why the last stop could not be verified on this FC (None: verified, or not known yet)
        self.stop_unverifiable: str | None = None
        self.watchdog_url = watchdog_target(url) if (url is not None and watchdog) else None
        self.baudrate = baudrate
        self.watchdog_log = watchdog_log
        self._watchdog: Watchdog | None = None
        self.port.timeout = 0.0  # we poll with our own clock-driven deadline
        #: MSP over UDP/TCP: the endpoint is locked to its peer (``rig.fc.link_lock``)
        self.intruders = IntruderWatch(port)

    # -- MSP request/response -------------------------------------------------------------
    def request(
        self, cmd: int, payload: bytes = b"", *, while_waiting: Callable[[], None] | None = None
    ) -> bytes:
        """Send one request and return its reply payload, re-sending it on silence.

        Each try waits as long as the link needs (see ``ReplyTimer``); a late reply to an
        earlier try of the same request is its answer too. Replies to anything else are
        dropped (``stale_replies``). ``while_waiting`` is called on every poll of the wait."""
        self._next_request_id += 1
        request_id = self._next_request_id
        frame = encode_request(cmd, payload, self.version)
        waited_s = 0.0
        attempt = 0
        while True:
            attempt += 1
            sent_s = self._send(cmd, frame, request_id)
            wait_s = self._wait_for_try(attempt)
            reply = self._await(cmd, request_id, sent_s + wait_s, while_waiting)
            if reply is not None:
                if attempt == 1 and self.timeout_s is None:
                    self.timer.sample(self.clock.now_s() - sent_s)
                return self._payload(reply)
            waited_s += wait_s
            log.debug("MSP cmd %d: no reply within %.0f ms (try %d)", cmd, wait_s * 1000, attempt)
            # The round trip decides when to re-send; giving up takes at least the longest
            # wait of one reply too (a link that answers in 15 ms can stall for a second).
            if attempt > self.retries and (
                self.timeout_s is not None or waited_s >= self.timer.max_s
            ):
                break
        self._forget(request_id)
        raise MspTimeout(
            f"no MSP reply to command {cmd} after {attempt} tries over {waited_s * 1000:.0f} ms"
            + ("" if self.timeout_s is not None else f" ({self.timer.describe()})")
        )

    def _wait_for_try(self, attempt: int) -> float:
        if self.timeout_s is not None:
            return self.timeout_s
        return self.timer.timeout_for_try(attempt)

    def _send(
        self,
        cmd: int,
        frame: bytes,
        request_id: int | None,
        on_reply: Callable[[MspFrame], None] | None = None,
    ) -> float:
        if not self._drained:
            # Whatever the port holds before our first request answers nothing of ours (a
            # reply to an earlier connection's request): drop it before it can pass for ours.
            self._drained = True
            leftovers, _ = self._read_frames()
            for old in leftovers:
                self.stale_replies += 1
                log.debug("MSP: dropped a reply to cmd %d left from before", old.cmd)
        try:
            self.port.write(frame)
        except OSError as exc:  # serial.SerialException is an OSError
            raise MspLinkLost(f"MSP link lost: {exc}") from exc
        now_s = self.clock.now_s()
        self._sent.append(_Sent(cmd, now_s, request_id, on_reply))
        return now_s

    def _read_frames(self) -> tuple[list[MspFrame], bool]:
        try:
            data = self.port.read(max(1, self.port.in_waiting))
        except OSError as exc:  # serial.SerialException is an OSError
            raise MspLinkLost(f"MSP link lost: {exc}") from exc
        return self._decoder.feed(data), bool(data)

    def _await(
        self,
        cmd: int,
        request_id: int,
        deadline_s: float,
        while_waiting: Callable[[], None] | None,
    ) -> MspFrame | None:
        while True:
            frames, got_data = self._read_frames()
            for frame in frames:
                if self._dispatch(frame, request_id):
                    return frame
            if self.clock.now_s() >= deadline_s:
                return None
            if while_waiting is not None:
                while_waiting()
            if not got_data:
                self.clock.sleep_s(0.001)

    def _dispatch(self, frame: MspFrame, request_id: int | None) -> bool:
        """True when ``frame`` answers ``request_id``; otherwise it is taken in: an answer to
        a request nobody waits for, or a stale reply (dropped and counted)."""
        sent = self._match(frame)
        if sent is not None and request_id is not None and sent.request_id == request_id:
            return True
        if sent is not None and sent.request_id is None:
            if sent.on_reply is not None:
                sent.on_reply(frame)
            elif frame.is_error:
                log.warning("FC refused MSP command %d (error reply)", frame.cmd)
                if frame.cmd == MspCommand.SET_MOTOR:
                    self._motor_refused = True
            return False
        self.stale_replies += 1
        log.debug("MSP: dropped a stale reply to cmd %d (%d so far)", frame.cmd, self.stale_replies)
        return False

    def _match(self, frame: MspFrame) -> _Sent | None:
        """The request ``frame`` answers: the oldest one on the wire with its command (an FC
        answers in order, so requests sent before it and still unanswered were lost)."""
        for index, sent in enumerate(self._sent):
            if sent.cmd == frame.cmd:
                for _ in range(index):
                    lost = self._sent.popleft()
                    if lost.request_id is not None:
                        self.lost_requests += 1
                self._sent.popleft()
                return sent
        return None

    def _forget(self, request_id: int) -> None:
        """A request given up: its copies stay on record (their late replies are stale), but
        anything sent longer ago than the longest wait is taken as lost, so the record stays
        bounded."""
        horizon_s = self.clock.now_s() - 2 * self.timer.max_s * (self.retries + 1)
        while self._sent and self._sent[0].sent_s < horizon_s:
            self._sent.popleft()
            self.lost_requests += 1

    def _send_stop(self) -> None:
        """The stop, without waiting for its reply (what waits is the MSP_MOTOR read after it)."""
        self._send(MspCommand.SET_MOTOR, self._stop_frame(), None)

    def _stop_frame(self) -> bytes:
        return encode_request(
            MspCommand.SET_MOTOR, SetMotor.stop_all(MSP_MOTOR_SLOTS).encode(), self.version
        )

    @staticmethod
    def _payload(frame: MspFrame) -> bytes:
        if frame.is_error:
            raise MspRefused(f"FC refused MSP command {frame.cmd} (error reply)")
        return frame.payload

    # -- ThrottleOutput -------------------------------------------------------------------
    def identify(self) -> DeviceIdentity:
        if self._identity is not None:
            return self._identity
        api = ApiVersion.decode(self.request(MspCommand.API_VERSION))
        variant = FcVariant.decode(self.request(MspCommand.FC_VARIANT)).identifier
        version = FcVersion.decode(self.request(MspCommand.FC_VERSION))
        board = BoardInfo.decode(self.request(MspCommand.BOARD_INFO)).board_id
        adv = AdvancedConfig.decode(self.request(MspCommand.ADVANCED_CONFIG))
        protocol = adv.protocol
        if protocol is None or protocol is MotorProtocol.DISABLED:
            raise SafetyError(
                f"FC motor protocol is {adv.motor_protocol} (disabled/unknown): no motor output"
            )
        self.motor_protocol = protocol
        self.throttle_scale = throttle_scale_for(protocol)
        motors = MotorConfig.decode(self.request(MspCommand.MOTOR_CONFIG)).motor_count
        cells = None
        try:
            cells = BatteryState.decode(self.request(MspCommand.BATTERY_STATE)).cell_count or None
        except MspRefused:
            log.info("FC has no BATTERY_STATE")
        self._identity = DeviceIdentity(
            kind=VARIANTS.get(variant, variant.lower()),
            firmware_version=str(version),
            board=board,
            motor_protocol=protocol.name,
            motor_count=motors,
            battery_cells=cells,
            details={
                "msp_api": f"{api.major}.{api.minor}",
                "idle_pct": f"{adv.digital_idle_pct:g}",
            },
        )
        self._preflight()
        return self._identity

    def _preflight(self) -> None:
        status = Status.decode(self.request(MspCommand.STATUS))
        if status.armed:
            raise SafetyError("the flight controller is ARMED: disarm it before a motor test")
        # The watchdog is ready before the first motor command (and before a spin's ramp clock).
        self._ensure_watchdog()
        self.request(MspCommand.SET_ARMING_DISABLED, SetArmingDisabled(True).encode())
        self._arming_disabled = True

    def _ext(self, native: float) -> int:
        return int(round(native_to_external(native, self.motor_protocol)))

    def set_throttle(self, values: Mapping[int, float]) -> None:
        if self._identity is None:
            self.identify()
        ext = [MSP_MOTOR_STOP] * MSP_MOTOR_SLOTS
        for motor, native in values.items():
            if not 0 <= motor < MSP_MOTOR_SLOTS:
                raise SafetyError(f"motor {motor} out of range 0..{MSP_MOTOR_SLOTS - 1}")
            ext[motor] = self._ext(native)
        if any(v > MSP_MOTOR_STOP for v in ext):
            self._pump(wait=False)
            # never start, or go on, with an intruder on the link
            self.intruders.check(commanded=True, starting=not self._motors_may_run)
            self._ensure_watchdog()
            self._motors_may_run = True
        self._command_motors(SetMotor(tuple(ext)).encode())

    def _command_motors(self, payload: bytes) -> None:
        """SET_MOTOR without waiting for its reply (a slow link would hold a run's loop up one
        round trip per command): at most ``max_motor_commands_in_flight`` unanswered, and an
        FC that refuses one (``!``) fails the next."""
        if self._motor_refused:
            self._motor_refused = False
            raise MspRefused(f"FC refused MSP command {MspCommand.SET_MOTOR} (error reply)")
        give_up_s = self._give_up_s()
        deadline_s = self.clock.now_s() + give_up_s
        while self._unanswered(MspCommand.SET_MOTOR) >= self.max_motor_commands_in_flight:
            if self.clock.now_s() >= deadline_s:
                raise MspTimeout(
                    f"no MSP reply to {self._unanswered(MspCommand.SET_MOTOR)} motor commands "
                    f"within {give_up_s * 1000:.0f} ms ({self.timer.describe()})"
                )
            self._pump()
        self._send(MspCommand.SET_MOTOR, encode_request(MspCommand.SET_MOTOR, payload), None)
        self._pump()

    def _unanswered(self, cmd: int) -> int:
        return sum(1 for sent in self._sent if sent.cmd == cmd and sent.request_id is None)

    def _pump(self, *, wait: bool = True) -> None:
        """Take in every reply that arrived (answers to requests nobody waits for). Some
        ports report nothing ``in_waiting`` (pyserial's ``socket://``) and give a byte a read:
        read until they have nothing more (bounded)."""
        for _ in range(4096):
            frames, got_data = self._read_frames()
            for frame in frames:
                self._dispatch(frame, None)
            if not got_data:
                break
        else:
            return
        if wait:
            self.clock.sleep_s(0.001)

    def _give_up_s(self) -> float:
        """How long a request is tried before it fails (every try's wait)."""
        return sum(self._wait_for_try(a) for a in range(1, self.retries + 2))

    def _ask_ahead(self, cmd: int, on_reply: Callable[[MspFrame], None]) -> None:
        """Keep one request for ``cmd`` on the wire without waiting for it; re-send it when
        its reply is overdue (at most ``retries`` + 1 copies)."""
        copies = [s for s in self._sent if s.cmd == cmd and s.on_reply is not None]
        now_s = self.clock.now_s()
        if copies and (
            len(copies) > self.retries
            or now_s - copies[-1].sent_s < self._wait_for_try(len(copies))
        ):
            return
        self._send(cmd, encode_request(cmd, b"", self.version), None, on_reply)

    def stop(self) -> None:
        self.request(MspCommand.SET_MOTOR, SetMotor.stop_all(MSP_MOTOR_SLOTS).encode())

    def motor_values(self) -> tuple[int, ...]:
        return Motor.decode(self.request(MspCommand.MOTOR)).values

    def motor_count(self) -> int | None:
        """Motors the FC drives (identity, else MOTOR_CONFIG); None when it will not say."""
        if self._identity is not None and self._identity.motor_count:
            return self._identity.motor_count
        if self._motor_count is None:
            try:
                count = MotorConfig.decode(self.request(MspCommand.MOTOR_CONFIG)).motor_count
            except MspRefused:
                return None
            self._motor_count = count or None
        return self._motor_count

    def check_stopped(self) -> StopCheck:
        """Read MSP_MOTOR: ``verified`` (every motor at the stop value or below), ``running``
        (some motor above it) or ``unverifiable`` (the FC reports 0 = nothing for a motor it
        drives; ``stop_unverifiable`` says which)."""
        outcome = self._judge(self.motor_values())
        if outcome == "running":
            log.warning("MSP_MOTOR: motor(s) above the stop value: %s", self._last_motor_values)
        return outcome

    def _judge(self, values: tuple[int, ...]) -> StopCheck:
        self.stop_unverifiable = None
        self._last_motor_values = values
        running = [i + 1 for i, v in enumerate(values) if v > MSP_MOTOR_STOP]
        if running:
            return "running"
        count = self.motor_count()
        driven = values[:count] if count is not None else values
        blind = [i + 1 for i, v in enumerate(driven) if v == 0]
        if count is None and len(blind) < len(driven):
            blind = []  # unknown motor count: 0s beside real values are absent motors
        if blind:
            self.stop_unverifiable = (
                f"MSP_MOTOR reads 0 for motor(s) {', '.join(map(str, blind))}: this FC reports "
                "no motor values (its motor output or control loop is not running), so the "
                "stop was sent but cannot be verified"
            )
            return "unverifiable"
        return "verified"

    def verify_stopped(self) -> bool:
        return self.check_stopped() == "verified"

    def _stop_and_check(self) -> StopCheck:
        """One stop attempt, as fast as the link allows: the stop goes out at once, then the
        MSP_MOTOR read that verifies it (the FC answers in order, so its answer already
        reflects the stop); while that read waits, the stop is re-sent every
        ``stop_resend_s``, so a lost frame costs that long and not a reply timeout. A read
        that still shows a motor running (the FC's control loop applies a stop on its next
        run) sends the stop again and reads again, for up to half a second or two reply
        timeouts. Raises ``MspTimeout`` when MSP_MOTOR never answers."""
        window_s = max(0.5, 2 * self.timer.timeout_s)
        start_s = self.clock.now_s()
        while True:
            self._send_stop()
            last_s = self.clock.now_s()

            def resend() -> None:
                nonlocal last_s
                now_s = self.clock.now_s()
                if now_s - last_s >= self.stop_resend_s:
                    self._send_stop()
                    last_s = now_s

            values = Motor.decode(self.request(MspCommand.MOTOR, while_waiting=resend)).values
            outcome = self._judge(values)
            if outcome != "running":
                return outcome
            if self.clock.now_s() - start_s >= window_s:
                log.warning("MSP_MOTOR: motor(s) above the stop value: %s", values)
                return outcome
            log.debug("MSP_MOTOR still shows %s after the stop: stopping again", values)

    def read_telemetry(self) -> Telemetry:
        """Battery (and ESC telemetry where the FC has it). The first call waits for the
        replies; later calls return the latest ones and keep the next requests on the wire,
        so a slow link never holds a run's loop up. Raises ``MspTimeout`` when the latest
        battery reply is older than a request's whole retry budget (the link is gone)."""
        if self._battery is None:
            now = self.clock.now_s()
            self._battery = (now, BatteryState.decode(self.request(MspCommand.BATTERY_STATE)))
            if self._esc_telemetry:
                # optional: asked ahead, never waited for (an FC, bridge or recording without
                # ESC telemetry must not hold the first reading up, nor fail it)
                self._ask_ahead(MspCommand.MOTOR_TELEMETRY, self._took_esc)
        else:
            self._pump(wait=False)
            self._ask_ahead(MspCommand.BATTERY_STATE, self._took_battery)
            if self._esc_telemetry:
                self._ask_ahead(MspCommand.MOTOR_TELEMETRY, self._took_esc)
            # the link is judged by the request it has not answered (the oldest one on the
            # wire), not by the age of the last reply: a caller that did not ask for a while
            # (the stand's tare, a fit between holds) has not lost its link
            now_s = self.clock.now_s()
            asked = [
                s.sent_s
                for s in self._sent
                if s.cmd == MspCommand.BATTERY_STATE and s.on_reply is not None
            ]
            age_s = now_s - max(self._battery[0], min(asked)) if asked else 0.0
            if age_s > self._give_up_s():
                raise MspTimeout(
                    f"no MSP reply to BATTERY_STATE for {age_s:.2f} s ({self.timer.describe()})"
                )
        self.intruders.check(commanded=self._motors_may_run)
        time_s, batt = self._battery
        rpm = temp = None
        if self._esc is not None:
            rpm = tuple(m.rpm for m in self._esc[1].motors)
            temp = tuple(m.temperature_c for m in self._esc[1].motors)
        return Telemetry(time_s, batt.voltage_v, batt.current_a, rpm, temp)

    def _took_battery(self, frame: MspFrame) -> None:
        if frame.is_error:
            log.debug("FC refused BATTERY_STATE")
            return
        try:
            self._battery = (self.clock.now_s(), BatteryState.decode(frame.payload))
        except ThrustmapError as exc:
            log.warning("bad BATTERY_STATE reply: %s", exc)

    def _took_esc(self, frame: MspFrame) -> None:
        if frame.is_error:
            self._esc_telemetry = False  # no ESC telemetry on this build: not asked again
            return
        try:
            self._esc = (self.clock.now_s(), MotorTelemetry.decode(frame.payload))
        except ThrustmapError as exc:
            log.warning("bad MOTOR_TELEMETRY reply: %s", exc)

    def stop_and_verify(self, attempts: int = 3, *, alarm: bool = True) -> bool:
        """Send the stop and confirm it with MSP_MOTOR; retry. Never raises.

        A session that commanded no motor (a probe; a run refused before its first command)
        sends no stop: nothing of ours can turn, so it re-enables arming and reports True
        without an alarm. An FC that reports no motor values (see module) gets one
        acknowledged stop and a warning, not retries and a CRITICAL alarm: nothing says a
        motor turns, and nothing can say it stopped. The result is False all the same: such
        a stop is never "verified"."""
        if not self._motors_may_run:
            log.info("no motor was commanded in this session: no stop to send")
            self._enable_arming()
            return True
        for attempt in range(1, attempts + 1):
            try:
                outcome = self._stop_and_check()
            except Exception as exc:  # the link may be gone; keep trying, then report
                log.warning("stop attempt %d of %d not confirmed: %s", attempt, attempts, exc)
                continue
            if outcome == "verified":
                log.info("motors stopped (verified, attempt %d)", attempt)
                self._motors_may_run = False
                self._enable_arming()
                return True
            if outcome == "unverifiable":
                # The FC acknowledged the stop and reports driving nothing: arming goes back
                # as Configurator leaves it, but the result stays "not verified".
                log.warning("motor stop sent and acknowledged; %s", self.stop_unverifiable)
                self._motors_may_run = False
                self._enable_arming()
                return False
            log.warning("stop not confirmed (attempt %d of %d)", attempt, attempts)
        if alarm:
            log.critical("COULD NOT VERIFY MOTOR STOP - disconnect the battery now")
        return False

    def _enable_arming(self) -> None:
        if not self._arming_disabled:
            return
        try:
            self.request(MspCommand.SET_ARMING_DISABLED, SetArmingDisabled(False).encode())
            self._arming_disabled = False
        except ThrustmapError as exc:
            log.warning("could not re-enable arming: %s", exc)

    def watchdog_stop(self) -> StopCheck:
        """The watchdog's stop: all motors to the stop value, MSP_MOTOR check, and arming
        re-enabled as :meth:`stop_and_verify` does after the driver disabled it. Sends
        nothing that can start a motor, and no identification or preflight."""
        outcome = self._stop_and_check()
        if outcome != "running":
            self._arming_disabled = True  # the dead session left it disabled
            self._enable_arming()
        return outcome

    # -- the watchdog ----------------------------------------------------------------------
    def _ensure_watchdog(self) -> None:
        if self._watchdog is not None or self.watchdog_url is None:
            return
        from thrustmap.rig.watchdog_handle import start_watchdog

        self._watchdog = start_watchdog(
            self.watchdog_url, baudrate=self.baudrate, log_path=self.watchdog_log
        )

    @property
    def watchdog(self) -> Watchdog | None:
        return self._watchdog

    def close(self) -> None:
        try:
            self.port.close()
        finally:
            watchdog, self._watchdog = self._watchdog, None
            if watchdog is not None:
                if self._motors_may_run:
                    watchdog.hand_over()  # the port is free now: it retries the stop
                else:
                    watchdog.disarm()


def watchdog_target(url: str) -> str | None:
    """The URL a watchdog reopens for a driver opened on ``url``: the innermost real port of a
    ``record://`` chain; None for ``sim://`` and ``replay://`` (they end with this process)."""
    from thrustmap.protocols.urlhandlers.protocol_record import split_record_url

    inner = url
    for _ in range(8):
        if not inner.lower().startswith("record://"):
            break
        try:
            inner, _own = split_record_url(inner)
        except Exception:
            return None
    scheme = inner.partition("://")[0].lower() if "://" in inner else ""
    if scheme in ("sim", "replay", "record", "loop"):
        return None
    return msp_port_url(inner)


def msp_port_url(url: str) -> str:
    """The pyserial URL of an MSP port: ``tcp://host:port`` and ``tcp:host:port`` (the forms
    SITL users type) are ``socket://host:port``; anything else is returned unchanged."""
    lower = url.lower()
    if lower.startswith("tcp://"):
        return "socket://" + url[len("tcp://") :]
    if lower.startswith("tcp:"):
        return "socket://" + url[len("tcp:") :]
    return url
