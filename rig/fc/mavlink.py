"""PX4 and ArduPilot flight controllers over MAVLink, as ``ThrottleOutput`` drivers.

Both drivers take a pymavlink ``mavfile`` (normally ``protocols.mavlink_link.MavlinkSerialLink``
over a serial port, ``sim://``, ``record://`` or ``replay://``; a stock ``mavutil`` connection
works too) and an injected clock. They never know whether the vehicle is real, simulated or a
replayed transcript. ``open_mavlink_output(url_or_link, clock)`` waits for a HEARTBEAT and picks
the driver from its autopilot field (3 ArduPilot, 12 PX4).

Common behaviour (facts in reference/mavlink.md):
- ``identify()`` waits for the vehicle's HEARTBEAT (the command target is its system and
  component), refuses an ARMED vehicle, asks for telemetry rates with SET_MESSAGE_INTERVAL,
  asks for AUTOPILOT_VERSION (MAV_CMD_REQUEST_MESSAGE; optional), reads parameters, and counts
  battery cells (BATTERY_STATUS with per-cell entries) and motors (a parameter, else the
  non-zero outputs of SERVO_OUTPUT_RAW, else the ``motor_count=`` you pass).
- Every COMMAND_LONG waits for its COMMAND_ACK. Not ACCEPTED -> ``MotorTestRefused`` (a
  ``SafetyError``) with the result and any STATUSTEXT the vehicle sent; no ACK after
  ``command_attempts`` tries, or no HEARTBEAT for ``heartbeat_timeout_s`` -> ``MavlinkLinkLost``,
  so the runner aborts. Transport failures (port gone) become ``MavlinkLinkLost`` too.
- Motor tests time out in the firmware (``test_timeout_s``, 2 s by default). ``keepalive()``
  re-sends the current command every time it is called (the runner calls it at least every
  0.5 s); ``maintain()`` re-sends only when ``keepalive_interval_s`` has passed, for scripts
  that poll. If the host dies the motor stops by itself within ``test_timeout_s``.
- ``stop()`` puts the stop for every motor on the wire before waiting for any ACK, so a dead
  link cannot keep one motor's stop from being sent; no ACK -> ``MavlinkLinkLost``. A refused
  stop (PX4 with the safety on, ArduPilot not landed: nothing of ours can be running) is
  logged, and left to the evidence: without any output telemetry it counts as not verified.
  ``verify_stopped()`` waits (up to ``verify_timeout_s``) for evidence that arrived after the
  stop's ACK (in stream order, not by clock time: a HEARTBEAT sent before the stop may be read
  in the same instant as the ACK): SERVO_OUTPUT_RAW motor outputs at the stopped level,
  HEARTBEAT not armed, and ESC rpm at rest (``rest_rpm``) or coasting down (below
  ``coast_fraction`` of the rpm at the stop command: unpowered). Evidence a vehicle never
  sends is not waited for.
- ``read_telemetry()`` processes what has arrived (never blocks) and reports battery voltage
  and current (BATTERY_STATUS, else SYS_STATUS), ESC rpm and temperature (ESC_STATUS on PX4,
  ESC_TELEMETRY_1_TO_4.. on ArduPilot); values older than ``telemetry_max_age_s`` are None.

PX4 (``Px4ThrottleOutput``): MAV_CMD_ACTUATOR_TEST (310), value 0..1 to MOTOR``n+1`` for 0-based
motor ``n``, NaN stops; timeout capped at 3 s by PX4. **Throttle scale: ``SCALES["norm"]``, the
0..1 actuator-test value itself** — that is what PX4 takes, independent of its output protocol
(PWM, Oneshot or DShot); PWM_MAIN_MIN/MAX/DIS are recorded in ``identify().details`` when the
vehicle has them, so a µs calibration can be derived later. The value passes through
THR_MDL_FAC before reaching the ESC: the driver reads it, records it in ``details`` and warns
unless it is 0 (set THR_MDL_FAC=0 for raw stand data). COM_MOT_TEST_EN != 1 is refused at
``identify()`` with the fix named; PX4 DENIES the test while armed or with the safety on.

ArduPilot (``ArduPilotThrottleOutput``): MAV_CMD_DO_MOTOR_TEST (209) in PWM mode (throttle type
1, value µs). **Motor mapping: 0-based motor ``n`` is ArduCopter test-order instance ``n + 1``**
(test order A, B, C, ... — for a quad X, A is front-right and the order runs clockwise; it is
NOT the output channel); pass ``instances=`` to map differently. One motor at a time (a new
command overwrites the running test), so ``set_throttle`` with two motors is refused.
**Throttle scale: PWM µs** over MOT_PWM_MIN..MOT_PWM_MAX (both 0 means "use RC3_MIN/RC3_MAX",
as ArduCopter does; else 1000..2000). Stop = PWM 0 with timeout 0. While a test runs ArduPilot
reports ARMED: that is expected and is never taken for a pilot-armed vehicle; an ARMED
HEARTBEAT counts only when no test of ours runs and it arrived after our last stop's ACK.
Refusals come as COMMAND_ACK FAILED plus STATUSTEXT "Motor Test: ..."; the text is in the
``MotorTestRefused`` message.
"""

from __future__ import annotations

import logging
import math
from abc import abstractmethod
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from serial import SerialException

from thrustmap.clock import Clock
from thrustmap.errors import ConfigError, SafetyError, ThrustmapError
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink.link import open_mavlink
from thrustmap.rig.interfaces import DeviceIdentity, Telemetry, ThrottleOutput
from thrustmap.units import SCALES, ThrottleScale

log = logging.getLogger(__name__)

MAV_CMD_REQUEST_MESSAGE = 512
MSG_HEARTBEAT = 0
MSG_SYS_STATUS = 1
MSG_SERVO_OUTPUT_RAW = 36
MSG_BATTERY_STATUS = 147
MSG_AUTOPILOT_VERSION = 148
MSG_ESC_STATUS = 291
MSG_ESC_TELEMETRY_1_TO_4 = 11030
MSG_ESC_TELEMETRY_5_TO_8 = 11031
FIRMWARE_TYPES = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: "official"}


class MavlinkLinkLost(ThrustmapError):
    """No HEARTBEAT or no COMMAND_ACK in time, or the transport failed: the link is gone."""


class MotorTestRefused(SafetyError):
    """The vehicle answered a motor command with something other than ACCEPTED."""

    def __init__(self, message: str, *, result: int, statustext: Sequence[str] = ()) -> None:
        super().__init__(message)
        self.result = result
        self.statustext = tuple(statustext)


class UnsupportedAutopilot(ConfigError):
    """The HEARTBEAT names an autopilot this module has no driver for."""


@dataclass(frozen=True)
class _Stamped:
    value: Any
    time_s: float  # clock reading when processed (for telemetry age)
    seq: int = 0  # position in the received stream (for "after the stop": order, not time)


def _command_name(command: int) -> str:
    names = {
        mav.MAV_CMD_DO_MOTOR_TEST: "DO_MOTOR_TEST",
        mav.MAV_CMD_ACTUATOR_TEST: "ACTUATOR_TEST",
        mav.MAV_CMD_SET_MESSAGE_INTERVAL: "SET_MESSAGE_INTERVAL",
        MAV_CMD_REQUEST_MESSAGE: "REQUEST_MESSAGE",
    }
    return names.get(command, f"command {command}")


def _result_name(result: int) -> str:
    try:
        return mav.MavResult(result).name
    except ValueError:
        return f"result {result}"


def request_message(
    message_id: int, *, target_system: int = 1, target_component: int = 1
) -> mav.CommandLong:
    """MAV_CMD_REQUEST_MESSAGE (512): ask the vehicle to send ``message_id`` once."""
    return mav.CommandLong(
        MAV_CMD_REQUEST_MESSAGE,
        (float(message_id), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        target_system,
        target_component,
    )


def decode_flight_sw_version(value: int) -> str:
    """AUTOPILOT_VERSION.flight_sw_version -> "1.14.3" (with "-beta"/"-rc"/"-dev" if not official)."""
    major, minor, patch = (value >> 24) & 0xFF, (value >> 16) & 0xFF, (value >> 8) & 0xFF
    text = f"{major}.{minor}.{patch}"
    label = FIRMWARE_TYPES.get(value & 0xFF, "")
    return text if label in ("official", "") else f"{text}-{label}"


def wait_for_vehicle_heartbeat(link: Any, clock: Clock, timeout_s: float) -> mav.Heartbeat:
    """The first HEARTBEAT from a vehicle (not a GCS, not autopilot INVALID) within ``timeout_s``."""
    deadline_s = clock.now_s() + timeout_s
    while True:
        remaining_s = deadline_s - clock.now_s()
        if remaining_s <= 0:
            raise MavlinkLinkLost(
                f"no HEARTBEAT from a vehicle within {timeout_s:g} s on {getattr(link, 'address', link)}"
                " (wrong port, baud rate or URL? is the flight controller powered?)"
            )
        try:
            msg = link.recv_match(type="HEARTBEAT", blocking=True, timeout=remaining_s)
        except (OSError, SerialException) as exc:
            raise MavlinkLinkLost(f"transport failed while waiting for a HEARTBEAT: {exc}") from exc
        if msg is None:
            continue
        hb = mav.decode_heartbeat(msg)
        if hb.is_vehicle:
            return hb


class MavlinkThrottleOutput(ThrottleOutput):
    """What the PX4 and ArduPilot drivers share; see the module docstring."""

    kind = "mavlink"
    #: telemetry message ids this firmware streams, asked for at ``telemetry_rate_hz``
    telemetry_messages: tuple[int, ...] = ()

    def __init__(
        self,
        link: Any,
        clock: Clock,
        *,
        heartbeat: mav.Heartbeat | None = None,
        motor_count: int | None = None,
        test_timeout_s: float = 2.0,
        keepalive_interval_s: float = 0.5,
        ack_timeout_s: float = 0.5,
        command_attempts: int = 2,
        heartbeat_timeout_s: float = 3.0,
        param_timeout_s: float = 0.3,
        telemetry_rate_hz: float = 10.0,
        telemetry_max_age_s: float = 1.0,
        verify_timeout_s: float = 2.0,
        rest_rpm: float = 300.0,
        coast_fraction: float = 0.5,
    ) -> None:
        if not 0 < keepalive_interval_s <= test_timeout_s / 2:
            raise ConfigError(
                f"keepalive interval {keepalive_interval_s:g} s must be > 0 and at most half the "
                f"motor-test timeout ({test_timeout_s:g} s), so one lost re-send cannot stop a sweep"
            )
        if command_attempts < 1:
            raise ConfigError(f"command_attempts must be >= 1, got {command_attempts}")
        if motor_count is not None and motor_count < 1:
            raise ConfigError(f"motor_count must be >= 1, got {motor_count}")
        self.link = link
        self.clock = clock
        self.test_timeout_s = test_timeout_s
        self.keepalive_interval_s = keepalive_interval_s
        self.ack_timeout_s = ack_timeout_s
        self.command_attempts = command_attempts
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.param_timeout_s = param_timeout_s
        self.telemetry_rate_hz = telemetry_rate_hz
        self.telemetry_max_age_s = telemetry_max_age_s
        self.verify_timeout_s = verify_timeout_s
        self.rest_rpm = rest_rpm
        self.coast_fraction = coast_fraction
        self._motor_count_arg = motor_count
        self.motor_count = motor_count or 0
        self.target_system = heartbeat.system_id if heartbeat is not None else 0
        self.target_component = heartbeat.component_id if heartbeat is not None else 0
        now_s = clock.now_s()
        self._heartbeat: _Stamped | None = None if heartbeat is None else _Stamped(heartbeat, now_s)
        self._sys_status: _Stamped | None = None
        self._battery: _Stamped | None = None
        self._servo: _Stamped | None = None
        self._esc_rpm: dict[int, _Stamped] = {}
        self._esc_temp: dict[int, _Stamped] = {}
        self._statustext: list[_Stamped] = []
        self._acks: list[mav.CommandAck] = []
        self._params: dict[str, float] = {}
        self._autopilot_version: Any = None
        self._seen: set[str] = set()
        self._identity: DeviceIdentity | None = None
        self._current: dict[int, float] = {}
        self._commanded: set[int] = set()
        self._last_sent_s: float | None = None
        self._stop_acked_s: float | None = None
        self._stop_acked_seq = 0  # received-message count when the last stop was acknowledged
        self._rx_seq = 0
        self._stop_rpm: dict[int, float] = {}
        self._stop_refused = False
        self.last_stop_verified: bool | None = None

    # -- receiving ----------------------------------------------------------------------------
    def _from_target(self, msg: Any) -> bool:
        if self.target_system == 0:
            return True
        return int(msg.get_srcSystem()) == self.target_system

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA" or not self._from_target(msg):
            return
        now_s = self.clock.now_s()
        self._rx_seq += 1
        if kind == "AUTOPILOT_VERSION":
            self._autopilot_version = msg
            self._seen.add(kind)
            return
        decoded = mav.decode(msg)
        if decoded is None:
            return
        if isinstance(decoded, mav.Heartbeat):
            if not decoded.is_vehicle or (
                self.target_component and decoded.component_id != self.target_component
            ):
                return
            self._heartbeat = _Stamped(decoded, now_s, self._rx_seq)
        elif isinstance(decoded, mav.CommandAck):
            target = int(getattr(msg, "target_system", 0) or 0)
            if target not in (0, int(self.link.mav.srcSystem)):
                return  # an ACK for another ground station
            self._acks.append(decoded)
        elif isinstance(decoded, mav.StatusText):
            log.info("vehicle: %s", decoded.text)
            self._statustext.append(_Stamped(decoded.text, now_s, self._rx_seq))
        elif isinstance(decoded, mav.ParamValue):
            self._params[decoded.name] = decoded.value
        elif isinstance(decoded, mav.SysStatus):
            self._sys_status = _Stamped(decoded, now_s, self._rx_seq)
        elif isinstance(decoded, mav.BatteryStatus):
            if decoded.battery_id == 0:
                self._battery = _Stamped(decoded, now_s, self._rx_seq)
        elif isinstance(decoded, mav.ServoOutputRaw):
            if decoded.port == 0:
                self._servo = _Stamped(decoded, now_s, self._rx_seq)
        elif isinstance(decoded, mav.EscStatus):
            for i, rpm in enumerate(decoded.rpm):
                self._esc_rpm[decoded.first_index + i] = _Stamped(rpm, now_s, self._rx_seq)
        elif isinstance(decoded, mav.EscTelemetry):
            for i, rpm in enumerate(decoded.rpm):
                self._esc_rpm[decoded.first_index + i] = _Stamped(rpm, now_s, self._rx_seq)
                self._esc_temp[decoded.first_index + i] = _Stamped(
                    decoded.temperature_c[i], now_s, self._rx_seq
                )
        self._seen.add(kind)

    def _recv_one(self, timeout_s: float) -> Any:
        try:
            if timeout_s > 0:
                msg = self.link.recv_match(blocking=True, timeout=timeout_s)
            else:  # a timeout of 0 would return before reading anything
                msg = self.link.recv_match(blocking=False)
        except (OSError, SerialException) as exc:
            raise MavlinkLinkLost(f"MAVLink transport failed: {exc}") from exc
        if msg is not None:
            self._handle(msg)
        return msg

    def poll(self) -> int:
        """Process every message already received, without waiting; returns how many."""
        count = 0
        while self._recv_one(0.0) is not None:
            count += 1
        return count

    def _wait_until(self, done: Any, timeout_s: float) -> bool:
        """Receive until ``done()`` is true (True) or ``timeout_s`` passes (False)."""
        deadline_s = self.clock.now_s() + timeout_s
        while not done():
            remaining_s = deadline_s - self.clock.now_s()
            if remaining_s <= 0:
                return False
            self._recv_one(remaining_s)
        return True

    def check_link(self) -> None:
        """Raise ``MavlinkLinkLost`` if the vehicle's HEARTBEAT is older than the timeout."""
        age_s = math.inf if self._heartbeat is None else self.clock.now_s() - self._heartbeat.time_s
        if age_s > self.heartbeat_timeout_s:
            raise MavlinkLinkLost(
                f"no HEARTBEAT from the vehicle for {age_s:.1f} s "
                f"(limit {self.heartbeat_timeout_s:g} s): link lost"
            )

    # -- sending -------------------------------------------------------------------------------
    def _send(self, msg: Any) -> None:
        try:
            self.link.mav.send(msg)
        except (OSError, SerialException) as exc:
            raise MavlinkLinkLost(f"MAVLink transport failed on send: {exc}") from exc

    def _target(self, cmd: mav.CommandLong) -> mav.CommandLong:
        return mav.CommandLong(
            cmd.command, cmd.params, self.target_system or 1, self.target_component or 1
        )

    def _take_ack(self, command: int) -> mav.CommandAck | None:
        for i, ack in enumerate(self._acks):
            if ack.command == command and ack.result != mav.MavResult.IN_PROGRESS:
                return self._acks.pop(i)
        return None

    def command(self, cmd: mav.CommandLong, *, attempts: int | None = None) -> mav.CommandAck:
        """Send a COMMAND_LONG to the vehicle and return its final COMMAND_ACK (any result)."""
        cmd = self._target(cmd)
        tries = self.command_attempts if attempts is None else attempts
        self._acks = [a for a in self._acks if a.command != cmd.command]
        for attempt in range(1, tries + 1):
            log.debug("-> %s %s (attempt %d)", _command_name(cmd.command), cmd.params, attempt)
            self._send(cmd.to_message())
            found: list[mav.CommandAck] = []

            def got_ack(command: int = cmd.command, out: list[mav.CommandAck] = found) -> bool:
                ack = self._take_ack(command)
                if ack is not None:
                    out.append(ack)
                return bool(out)

            if self._wait_until(got_ack, self.ack_timeout_s):
                return found[0]
        raise MavlinkLinkLost(
            f"no COMMAND_ACK for {_command_name(cmd.command)} after {tries} tries "
            f"({self.ack_timeout_s:g} s each): link lost"
        )

    def _texts_since(self, time_s: float) -> list[str]:
        return [s.value for s in self._statustext if s.time_s >= time_s]

    def _require_accepted(self, cmd: mav.CommandLong, what: str) -> mav.CommandAck:
        sent_s = self.clock.now_s()
        ack = self.command(cmd)
        if ack.accepted:
            return ack
        # A refusal's explanation may come just after the ACK: give it a moment.
        self._wait_until(lambda: bool(self._texts_since(sent_s)), 0.2)
        texts = self._texts_since(sent_s)
        raise MotorTestRefused(
            self._refusal_message(what, int(ack.result), texts),
            result=int(ack.result),
            statustext=texts,
        )

    def _refusal_message(self, what: str, result: int, texts: Sequence[str]) -> str:
        said = f": {'; '.join(repr(t) for t in texts)}" if texts else ""
        return f"{self.kind} refused {what} ({_result_name(result)}){said}"

    # -- parameters ------------------------------------------------------------------------------
    def read_params(self, names: Iterable[str], *, attempts: int = 2) -> dict[str, float]:
        """Read parameters by name (all requested at once); names the vehicle lacks are absent."""
        wanted = [n for n in names if n not in self._params]
        for _ in range(attempts):
            missing = [n for n in wanted if n not in self._params]
            if not missing:
                break
            for name in missing:
                self._send(
                    mav.param_request_read(
                        name,
                        target_system=self.target_system or 1,
                        target_component=self.target_component or 1,
                    )
                )
            self._wait_until(
                lambda m=missing: all(n in self._params for n in m), self.param_timeout_s
            )
        return {n: self._params[n] for n in names if n in self._params}

    # -- identify ------------------------------------------------------------------------------
    def _ensure_heartbeat(self) -> mav.Heartbeat:
        if self._heartbeat is None:
            hb = wait_for_vehicle_heartbeat(self.link, self.clock, self.heartbeat_timeout_s)
            self.target_system, self.target_component = hb.system_id, hb.component_id
            self._heartbeat = _Stamped(hb, self.clock.now_s())
        heartbeat: mav.Heartbeat = self._heartbeat.value
        return heartbeat

    def _request_rates(self) -> None:
        interval_s = 1.0 / self.telemetry_rate_hz if self.telemetry_rate_hz > 0 else 0.0
        for message_id in self.telemetry_messages:
            ack = self.command(mav.set_message_interval(message_id, interval_s))
            if not ack.accepted:
                log.info(
                    "vehicle did not accept a rate for message %d (%s)",
                    message_id,
                    _result_name(int(ack.result)),
                )

    def _request_version(self) -> str:
        ack = self.command(request_message(MSG_AUTOPILOT_VERSION))
        if ack.accepted:
            self._wait_until(lambda: self._autopilot_version is not None, self.param_timeout_s)
        if self._autopilot_version is None:
            log.info("vehicle sent no AUTOPILOT_VERSION: firmware version unknown")
            return ""
        return decode_flight_sw_version(int(self._autopilot_version.flight_sw_version))

    def _guess_motor_count(self) -> tuple[int, str]:
        if self._motor_count_arg:
            return self._motor_count_arg, "argument"
        counted = self._param_motor_count()
        if counted:
            return counted, "parameter"
        if self._servo is not None:
            outputs = self._servo.value.outputs_us
            n = 0
            while n < len(outputs) and outputs[n] != 0:
                n += 1
            if n:
                return n, "SERVO_OUTPUT_RAW"
        return 0, "unknown"

    def _param_motor_count(self) -> int:
        return 0

    def identify(self) -> DeviceIdentity:
        if self._identity is not None:
            return self._identity
        hb = self._ensure_heartbeat()
        self.poll()
        hb = self._heartbeat.value if self._heartbeat is not None else hb
        if hb.armed:
            raise SafetyError(
                f"the {self.kind} vehicle reports ARMED (HEARTBEAT base_mode {hb.base_mode}): "
                "disarm it before a motor test"
            )
        self._request_rates()
        version = self._request_version()
        details = self._read_firmware_params()
        wanted = {"SERVO_OUTPUT_RAW", "BATTERY_STATUS"}
        self._wait_until(lambda: wanted <= self._seen, 2.0 / max(self.telemetry_rate_hz, 1.0))
        self.motor_count, source = self._guess_motor_count()
        cells = None
        if self._battery is not None and self._battery.value.cell_voltages_v:
            cells = len(self._battery.value.cell_voltages_v)
        details.update(
            {
                "system_id": str(self.target_system),
                "component_id": str(self.target_component),
                "vehicle_type": str(hb.vehicle_type),
                "motor_count_source": source,
                "test_timeout_s": f"{self.test_timeout_s:g}",
            }
        )
        if self._autopilot_version is not None:
            details["board_version"] = str(int(self._autopilot_version.board_version))
        self._identity = DeviceIdentity(
            kind=self.kind,
            firmware_version=version,
            board="",
            motor_protocol=self.motor_protocol(),
            motor_count=self.motor_count,
            battery_cells=cells,
            details=details,
        )
        log.info("%s identified: %s", self.kind, self._identity.to_dict())
        return self._identity

    @abstractmethod
    def _read_firmware_params(self) -> dict[str, str]:
        """Read what this firmware needs (and check preconditions); return identity details."""

    def motor_protocol(self) -> str:
        return ""

    # -- throttle -------------------------------------------------------------------------------
    def _check_motor(self, motor: int) -> None:
        limit = self.motor_count or 16
        if not 0 <= motor < min(limit, 16):
            raise SafetyError(
                f"motor {motor} out of range 0..{min(limit, 16) - 1} for this vehicle"
            )

    def _check_value(self, motor: int, value: float) -> None:
        scale = self.throttle_scale
        if not (math.isfinite(value) and scale.lo <= value <= scale.hi):
            raise SafetyError(
                f"throttle {value!r} for motor {motor} is outside {scale.lo:g}..{scale.hi:g} "
                f"{scale.unit} ({scale.name})"
            )

    def set_throttle(self, values: Mapping[int, float]) -> None:
        if self._identity is None:
            self.identify()
        if not values:
            self.stop()
            return
        for motor, value in values.items():
            self._check_motor(motor)
            self._check_value(motor, value)
        self._before_start(values)
        self._send_throttle(dict(values))
        self._current = dict(values)
        self._commanded.update(values)
        self._last_sent_s = self.clock.now_s()

    def keepalive(self) -> None:
        """Re-send the current command (the firmware's test timeout restarts); check the link."""
        self.poll()
        self.check_link()
        if self._current:
            self._send_throttle(dict(self._current))
            self._last_sent_s = self.clock.now_s()

    def maintain(self) -> None:
        """``keepalive()`` if ``keepalive_interval_s`` has passed since the last send."""
        if self._last_sent_s is None or (
            self.clock.now_s() - self._last_sent_s >= self.keepalive_interval_s
        ):
            self.keepalive()
        else:
            self.poll()
            self.check_link()

    def _before_start(self, values: Mapping[int, float]) -> None:  # noqa: B027 - optional hook
        """Firmware-specific checks before a command goes out."""

    @abstractmethod
    def _send_throttle(self, values: dict[int, float]) -> None: ...

    @abstractmethod
    def _stop_commands(self) -> list[mav.CommandLong]: ...

    def stop(self) -> None:
        """Send the stop for every motor (all on the wire first), then check every ACK."""
        commands = [self._target(c) for c in self._stop_commands()]
        self._current = {}
        self._stop_rpm = {m: s.value for m, s in self._esc_rpm.items()}
        self._stop_acked_s = None
        for cmd in commands:  # all of them out before waiting for anything
            self._send(cmd.to_message())
        log.info("stop sent (%d command%s)", len(commands), "" if len(commands) == 1 else "s")
        self._acks = [a for a in self._acks if a.command not in {c.command for c in commands}]
        needed = len(commands)
        results: list[mav.CommandAck] = []

        def all_acked() -> bool:
            while len(results) < needed:
                ack = self._take_ack(commands[0].command) if commands else None
                if ack is None:
                    return False
                results.append(ack)
            return True

        if not self._wait_until(all_acked, self.ack_timeout_s):
            raise MavlinkLinkLost(
                f"stop sent, but only {len(results)} of {needed} COMMAND_ACKs arrived within "
                f"{self.ack_timeout_s:g} s"
            )
        refused = [a for a in results if not a.accepted]
        self._stop_refused = bool(refused)
        if refused:
            # Nothing of ours may be running (safety on, not landed, ...): verify_stopped
            # decides from what the vehicle reports, and fails without output evidence.
            texts = self._texts_since(self.clock.now_s() - self.ack_timeout_s)
            log.warning(
                "%s", self._refusal_message("the stop command", int(refused[0].result), texts)
            )
        self._stop_acked_s = self.clock.now_s()
        self._stop_acked_seq = self._rx_seq

    # -- verification ------------------------------------------------------------------------------
    def _motor_indices(self) -> list[int]:
        return sorted(set(range(self.motor_count)) | self._commanded)

    def _has_output_evidence(self) -> bool:
        return "SERVO_OUTPUT_RAW" in self._seen or bool(self._esc_rpm)

    @abstractmethod
    def _outputs_stopped(self, outputs_us: Sequence[int], motors: Sequence[int]) -> bool: ...

    def _heartbeat_required(self) -> bool:
        return False

    def _stop_evidence(self, since: int) -> tuple[bool, list[str]]:
        """(all available evidence says stopped, what is still missing or wrong)."""
        motors = self._motor_indices()
        missing: list[str] = []
        hb = self._heartbeat
        if self._heartbeat_required() and (hb is None or hb.seq <= since):
            missing.append("a HEARTBEAT after the stop")
        elif hb is not None and hb.seq > since and hb.value.armed:
            missing.append("HEARTBEAT still says ARMED")
        if "SERVO_OUTPUT_RAW" in self._seen:
            servo = self._servo
            if servo is None or servo.seq <= since:
                missing.append("a SERVO_OUTPUT_RAW after the stop")
            elif not self._outputs_stopped(servo.value.outputs_us, motors):
                missing.append(f"outputs not at stop: {servo.value.outputs_us[: len(motors) or 4]}")
        if self._esc_rpm:
            for m in motors:
                stamped = self._esc_rpm.get(m)
                if stamped is None:
                    continue
                if stamped.seq <= since:
                    missing.append(f"ESC rpm of motor {m} after the stop")
                    continue
                rpm, at_stop = stamped.value, self._stop_rpm.get(m, 0.0)
                coasting = at_stop > self.rest_rpm and rpm <= self.coast_fraction * at_stop
                if rpm > self.rest_rpm and not coasting:
                    missing.append(f"motor {m} at {rpm:.0f} rpm")
        return not missing, missing

    def verify_stopped(self) -> bool:
        if self._stop_acked_s is None:
            log.warning("verify_stopped: the last stop was not acknowledged")
            return False
        if self._stop_refused and not self._has_output_evidence():
            log.warning("verify_stopped: the stop was refused and the vehicle reports no outputs")
            return False
        outcome: list[str] = []

        def stopped() -> bool:
            ok, missing = self._stop_evidence(self._stop_acked_seq)
            outcome[:] = missing
            return ok

        ok = self._wait_until(stopped, self.verify_timeout_s)
        if ok:
            log.info("stop verified")
        else:
            log.warning("stop not verified: %s", "; ".join(outcome))
        return ok

    def stop_and_verify(self, attempts: int = 3) -> bool:
        ok = super().stop_and_verify(attempts)
        self.last_stop_verified = ok
        return ok

    # -- telemetry -------------------------------------------------------------------------------
    def _fresh(self, stamped: _Stamped | None, now_s: float) -> Any:
        if stamped is None or now_s - stamped.time_s > self.telemetry_max_age_s:
            return None
        return stamped.value

    def read_telemetry(self) -> Telemetry:
        self.poll()
        self.check_link()
        now_s = self.clock.now_s()
        voltage_v = current_a = None
        battery = self._fresh(self._battery, now_s)
        if battery is not None:
            voltage_v, current_a = battery.total_voltage_v, battery.current_a
        sys_status = self._fresh(self._sys_status, now_s)
        if sys_status is not None:
            voltage_v = voltage_v if voltage_v is not None else sys_status.voltage_v
            current_a = current_a if current_a is not None else sys_status.current_a
        count = self.motor_count or len(self._esc_rpm)
        rpm = tuple(self._fresh(self._esc_rpm.get(m), now_s) for m in range(count))
        temp = tuple(self._fresh(self._esc_temp.get(m), now_s) for m in range(count))
        return Telemetry(
            now_s,
            voltage_v,
            current_a,
            rpm if rpm and all(r is not None for r in rpm) else None,
            temp if temp and all(t is not None for t in temp) else None,
        )

    def close(self) -> None:
        try:
            self.link.close()
        except (OSError, SerialException) as exc:
            log.debug("closing the MAVLink link: %s", exc)


# ---------------------------------------------------------------------------------------------
# PX4
# ---------------------------------------------------------------------------------------------
PX4_PARAMS = (
    "COM_MOT_TEST_EN",
    "THR_MDL_FAC",
    "MC_BAT_SCALE_EN",
    "CA_ROTOR_COUNT",
    "PWM_MAIN_MIN",
    "PWM_MAIN_MAX",
    "PWM_MAIN_DIS",
)


class Px4ThrottleOutput(MavlinkThrottleOutput):
    """PX4 v1.14+ over MAVLink with MAV_CMD_ACTUATOR_TEST; see the module docstring."""

    kind = "px4"
    telemetry_messages = (MSG_SYS_STATUS, MSG_BATTERY_STATUS, MSG_ESC_STATUS, MSG_SERVO_OUTPUT_RAW)

    def __init__(self, link: Any, clock: Clock, **kwargs: Any) -> None:
        super().__init__(link, clock, **kwargs)
        if not 0 < self.test_timeout_s <= mav.PX4_ACTUATOR_TEST_MAX_TIMEOUT_S:
            raise ConfigError(
                f"PX4 actuator-test timeout must be in (0, 3] s, got {self.test_timeout_s:g}"
            )
        self.throttle_scale: ThrottleScale = SCALES["norm"]

    def _read_firmware_params(self) -> dict[str, str]:
        params = self.read_params(PX4_PARAMS)
        details = {name: f"{value:g}" for name, value in params.items()}
        enabled = params.get("COM_MOT_TEST_EN")
        if enabled is not None and enabled != 1.0:
            raise SafetyError(
                f"PX4 has COM_MOT_TEST_EN={enabled:g}: actuator tests are disabled; set "
                "COM_MOT_TEST_EN=1 (and reboot) to run a stand test"
            )
        fac = params.get("THR_MDL_FAC")
        if fac is None:
            log.warning("could not read THR_MDL_FAC: the thrust-model factor in use is unknown")
            details["THR_MDL_FAC"] = "unknown"
        elif fac != 0.0:
            log.warning(
                "THR_MDL_FAC=%g shapes every actuator-test value before it reaches the ESC; "
                "set THR_MDL_FAC=0 for raw stand data, or keep this value with the data",
                fac,
            )
        return details

    def _param_motor_count(self) -> int:
        return int(self._params.get("CA_ROTOR_COUNT", 0))

    def _send_throttle(self, values: dict[int, float]) -> None:
        for motor in sorted(self._current.keys() - values.keys()):  # no longer wanted: stop it
            self._require_accepted(
                mav.actuator_test_stop(motor + 1), f"ACTUATOR_TEST stop of motor {motor}"
            )
        for motor, value in sorted(values.items()):
            self._require_accepted(
                mav.actuator_test(motor + 1, value, timeout_s=self.test_timeout_s),
                f"ACTUATOR_TEST motor {motor} = {value:g}",
            )

    def _refusal_message(self, what: str, result: int, texts: Sequence[str]) -> str:
        text = super()._refusal_message(what, result, texts)
        if result == mav.MavResult.DENIED:
            hb = self._heartbeat.value if self._heartbeat is not None else None
            state = []
            if hb is not None and hb.armed:
                state.append("the vehicle reports ARMED")
            enabled = self._params.get("COM_MOT_TEST_EN")
            if enabled is not None and enabled != 1.0:
                state.append(f"COM_MOT_TEST_EN={enabled:g}")
            text += (
                ". PX4 denies actuator tests while armed, with the safety switch on, or when "
                "COM_MOT_TEST_EN != 1"
                + (f" (here: {', '.join(state)})" if state else " (check the safety switch)")
            )
        return text

    def _stop_commands(self) -> list[mav.CommandLong]:
        motors = self._motor_indices() or [0]
        return [mav.actuator_test_stop(m + 1) for m in motors if m < 16]

    def _outputs_stopped(self, outputs_us: Sequence[int], motors: Sequence[int]) -> bool:
        """Stopped = below the running minimum (PWM_MAIN_MIN): at the disarmed value, or 0."""
        minimum = self._params.get("PWM_MAIN_MIN", 1000.0)
        return all(outputs_us[m] < minimum for m in motors if m < len(outputs_us))


# ---------------------------------------------------------------------------------------------
# ArduPilot
# ---------------------------------------------------------------------------------------------
ARDUPILOT_PARAMS = ("MOT_PWM_MIN", "MOT_PWM_MAX", "MOT_PWM_TYPE", "MOT_SPIN_ARM", "MOT_THST_EXPO")
MOT_PWM_TYPES = {
    0: "PWM",
    1: "ONESHOT",
    2: "ONESHOT125",
    3: "BRUSHED",
    4: "DSHOT150",
    5: "DSHOT300",
    6: "DSHOT600",
    7: "DSHOT1200",
    8: "PWMRANGE",
}


class ArduPilotThrottleOutput(MavlinkThrottleOutput):
    """ArduCopter over MAVLink with MAV_CMD_DO_MOTOR_TEST in PWM mode; see the module docstring."""

    kind = "ardupilot"
    telemetry_messages = (
        MSG_SYS_STATUS,
        MSG_BATTERY_STATUS,
        MSG_ESC_TELEMETRY_1_TO_4,
        MSG_SERVO_OUTPUT_RAW,
    )

    def __init__(
        self, link: Any, clock: Clock, *, instances: Sequence[int] | None = None, **kwargs: Any
    ) -> None:
        super().__init__(link, clock, **kwargs)
        if not 0 < self.test_timeout_s <= mav.ARDUPILOT_MOTOR_TEST_MAX_TIMEOUT_S:
            raise ConfigError(
                f"ArduPilot motor-test timeout must be in (0, 600] s, got {self.test_timeout_s:g}"
            )
        if instances is not None and (
            any(i < 1 for i in instances) or len(set(instances)) != len(instances)
        ):
            raise ConfigError(
                f"instances must be distinct test-order numbers >= 1, got {instances}"
            )
        self.instances = list(instances) if instances is not None else None
        self.throttle_scale = SCALES["pwm"]
        self._pwm_type: int | None = None

    def instance_for_motor(self, motor: int) -> int:
        """ArduCopter test-order instance for 0-based ``motor`` (``motor + 1`` by default)."""
        if self.instances is None:
            return motor + 1
        if not 0 <= motor < len(self.instances):
            raise SafetyError(f"motor {motor} has no test-order instance in {self.instances}")
        return self.instances[motor]

    def _read_firmware_params(self) -> dict[str, str]:
        params = self.read_params(ARDUPILOT_PARAMS)
        details = {name: f"{value:g}" for name, value in params.items()}
        lo, hi = params.get("MOT_PWM_MIN", 0.0), params.get("MOT_PWM_MAX", 0.0)
        source = "MOT_PWM_MIN/MAX"
        if not (lo > 0 and hi > lo):
            rc = self.read_params(("RC3_MIN", "RC3_MAX"))
            lo, hi = rc.get("RC3_MIN", 0.0), rc.get("RC3_MAX", 0.0)
            source = "RC3_MIN/MAX"
            if not (lo > 0 and hi > lo):
                lo, hi, source = 1000.0, 2000.0, "default"
        lo_ok, hi_ok = mav.ARDUPILOT_MOTOR_TEST_PWM_RANGE_US
        if lo < lo_ok or hi > hi_ok:
            raise SafetyError(
                f"PWM range {lo:g}..{hi:g} µs ({source}) leaves ArduPilot's motor-test window "
                f"{lo_ok}..{hi_ok} µs: values outside it stop the test"
            )
        self.throttle_scale = SCALES["pwm"].with_range(lo, hi)
        details["pwm_range_source"] = source
        if "MOT_PWM_TYPE" in params:
            self._pwm_type = int(params["MOT_PWM_TYPE"])
        return details

    def motor_protocol(self) -> str:
        if self._pwm_type is None:
            return ""
        return MOT_PWM_TYPES.get(self._pwm_type, f"MOT_PWM_TYPE {self._pwm_type}")

    def _heartbeat_required(self) -> bool:
        return True  # ArduPilot disarms when the test ends: the HEARTBEAT confirms it

    def _before_start(self, values: Mapping[int, float]) -> None:
        if len(values) > 1:
            raise SafetyError(
                "ArduPilot's DO_MOTOR_TEST runs one motor at a time (a new command replaces the "
                f"running test); got {len(values)} motors. Use one motor, or PX4/MSP for several"
            )
        if self._current:
            return  # our own test is running: ARMED is expected
        self.poll()
        if self._stop_acked_s is not None:
            # HEARTBEATs from before our last stop's ACK still say ARMED: wait for a newer one.
            since = self._stop_acked_seq
            hb_ok = self._wait_until(
                lambda: self._heartbeat is not None and self._heartbeat.seq > since,
                self.heartbeat_timeout_s,
            )
            if not hb_ok:
                self.check_link()
        hb = self._heartbeat
        if hb is not None and hb.value.armed:
            raise SafetyError(
                "the ArduPilot vehicle reports ARMED and no motor test of ours is running: "
                "disarm it (or wait for a previous test to time out) before a motor test"
            )

    def _send_throttle(self, values: dict[int, float]) -> None:
        ((motor, value),) = values.items()
        instance = self.instance_for_motor(motor)
        self._require_accepted(
            mav.motor_test(
                instance,
                round(value, 1),
                timeout_s=self.test_timeout_s,
                throttle_type=mav.MotorTestThrottleType.PWM,
            ),
            f"DO_MOTOR_TEST motor {motor} (instance {instance}) = {value:g} µs",
        )

    def _stop_commands(self) -> list[mav.CommandLong]:
        running = sorted(self._current) or sorted(self._commanded) or [0]
        return [mav.motor_test_stop(self.instance_for_motor(running[0]))]

    def _outputs_stopped(self, outputs_us: Sequence[int], motors: Sequence[int]) -> bool:
        """Stopped = at or below the PWM minimum (ArduPilot outputs MOT_PWM_MIN disarmed), or 0."""
        minimum = self.throttle_scale.lo
        return all(outputs_us[m] <= minimum for m in motors if m < len(outputs_us))


# ---------------------------------------------------------------------------------------------
# Factory
# ---------------------------------------------------------------------------------------------
DRIVERS: dict[int, type[MavlinkThrottleOutput]] = {
    mav.Autopilot.PX4: Px4ThrottleOutput,
    mav.Autopilot.ARDUPILOT: ArduPilotThrottleOutput,
}
AUTOPILOT_NAMES = {"px4": mav.Autopilot.PX4, "ardupilot": mav.Autopilot.ARDUPILOT}


def _autopilot_id(autopilot: str | int) -> int:
    if isinstance(autopilot, str):
        key = autopilot.strip().lower()
        if key not in AUTOPILOT_NAMES:
            raise ConfigError(
                f"unknown autopilot {autopilot!r}; expected one of: {', '.join(AUTOPILOT_NAMES)}"
            )
        return int(AUTOPILOT_NAMES[key])
    return int(autopilot)


def open_mavlink_output(
    url_or_link: str | Any,
    clock: Clock,
    *,
    autopilot: str | int | None = None,
    heartbeat_timeout_s: float = 3.0,
    **driver_kwargs: Any,
) -> MavlinkThrottleOutput:
    """Wait for a vehicle HEARTBEAT and return the PX4 or ArduPilot driver for it.

    ``url_or_link``: a URL for ``open_mavlink`` (device path, ``sim://px4``, ``record://...``,
    ``replay://...``) or an open pymavlink connection. ``autopilot`` ("px4", "ardupilot", 12, 3)
    insists on one firmware: a vehicle of another kind is refused. A link this function opened
    is closed again if it fails.
    """
    opened = isinstance(url_or_link, str)
    link: Any = open_mavlink(url_or_link, clock=clock) if opened else url_or_link
    try:
        hb = wait_for_vehicle_heartbeat(link, clock, heartbeat_timeout_s)
        found = int(hb.autopilot)
        if autopilot is not None and _autopilot_id(autopilot) != found:
            raise ConfigError(
                f"expected a {autopilot} vehicle, but the HEARTBEAT says autopilot {found} "
                f"({hb.firmware})"
            )
        driver = DRIVERS.get(found)
        if driver is None:
            raise UnsupportedAutopilot(
                f"HEARTBEAT autopilot {found} has no motor-test driver; supported: "
                "3 (ArduPilot), 12 (PX4)"
            )
        return driver(
            link, clock, heartbeat=hb, heartbeat_timeout_s=heartbeat_timeout_s, **driver_kwargs
        )
    except BaseException:
        if opened:
            link.close()
        raise
