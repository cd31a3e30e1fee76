"""What the PX4 and ArduPilot throttle outputs share, on top of a ``MavlinkSession``.

Motors are the FC's own 0-based motor numbers everywhere (``--motor N`` is motor ``N-1`` here):
PX4's MOTOR``n+1``, ArduPilot's output function Motor``n+1``. Each driver translates to what
its command needs (ArduPilot: a test-order instance) and says so in ``motor_label``.

Behaviour (see the driver modules for what differs):
- ``identify()`` waits for the vehicle's HEARTBEAT (the command target is its system and
  component), refuses an ARMED vehicle, asks for telemetry rates with SET_MESSAGE_INTERVAL,
  asks for AUTOPILOT_VERSION (firmware version; capabilities decide how integer parameters are
  decoded), reads parameters, and counts battery cells and motors.
- Every COMMAND_LONG waits for its COMMAND_ACK; not ACCEPTED -> ``MotorTestRefused``.
- Motor tests time out in the firmware (``test_timeout_s``). ``keepalive()`` re-sends the
  current command; ``maintain()`` re-sends only when ``keepalive_interval_s`` has passed. A
  command re-sent later than ``max_command_gap_s`` (default: the firmware's test timeout, after
  which the motor has dropped) raises ``CommandsLate``: the run failed, it never "completed".
- ``stop()`` puts every stop on the wire before waiting for any ACK. ``verify_stopped()`` waits
  for evidence that arrived after the stop (SERVO_OUTPUT_RAW at the stopped level, HEARTBEAT
  not armed, ESC rpm at rest or coasting down). ``stop_and_verify()`` raises the CRITICAL alarm
  only when a motor command of ours was accepted: if the vehicle never started anything we
  asked for, nothing of ours can be turning.
- ``read_telemetry()`` reports battery voltage and current and the ESC rpm/temperature of each
  FC motor (from the ESC that drives it); values older than ``telemetry_max_age_s`` are None.
"""

from __future__ import annotations

import logging
import math
from abc import abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, SafetyError
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.rig.fc.mavlink_session import (
    CommandsLate,
    MavlinkLinkLost,
    MavlinkSession,
    MotorTestRefused,
    Stamped,
    result_name,
)
from thrustmap.rig.interfaces import DeviceIdentity, Telemetry, ThrottleOutput

log = logging.getLogger(__name__)


class MavlinkThrottleOutput(ThrottleOutput):
    """Shared logic of the MAVLink motor-test drivers; see the module docstring."""

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
        max_command_gap_s: float | None = None,
        ack_timeout_s: float | None = None,  # None: learned from the link's round trip
        command_attempts: int = 2,
        heartbeat_timeout_s: float = 3.0,
        param_timeout_s: float = 0.3,
        telemetry_rate_hz: float = 10.0,
        telemetry_max_age_s: float = 1.0,
        verify_timeout_s: float = 2.0,
        rest_rpm: float = 300.0,
        coast_fraction: float = 0.5,
        max_messages_per_poll: int = 200,
    ) -> None:
        if not 0 < keepalive_interval_s <= test_timeout_s / 2:
            raise ConfigError(
                f"keepalive interval {keepalive_interval_s:g} s must be > 0 and at most half the "
                f"motor-test timeout ({test_timeout_s:g} s), so one lost re-send cannot stop a sweep"
            )
        if motor_count is not None and motor_count < 1:
            raise ConfigError(f"motor_count must be >= 1, got {motor_count}")
        gap_s = test_timeout_s if max_command_gap_s is None else max_command_gap_s
        if not keepalive_interval_s < gap_s <= test_timeout_s:
            raise ConfigError(
                f"max_command_gap_s {gap_s:g} s must exceed the keepalive interval "
                f"({keepalive_interval_s:g} s) and not exceed the test timeout ({test_timeout_s:g} s)"
            )
        self.session = MavlinkSession(
            link,
            clock,
            heartbeat=heartbeat,
            ack_timeout_s=ack_timeout_s,
            command_attempts=command_attempts,
            heartbeat_timeout_s=heartbeat_timeout_s,
            param_timeout_s=param_timeout_s,
            max_messages_per_poll=max_messages_per_poll,
        )
        self.link = link
        self.clock = clock
        self.test_timeout_s = test_timeout_s
        self.keepalive_interval_s = keepalive_interval_s
        self.max_command_gap_s = gap_s
        self.telemetry_rate_hz = telemetry_rate_hz
        self.telemetry_max_age_s = telemetry_max_age_s
        self.verify_timeout_s = verify_timeout_s
        self.rest_rpm = rest_rpm
        self.coast_fraction = coast_fraction
        self._motor_count_arg = motor_count
        self.motor_count = motor_count or 0
        self._identity: DeviceIdentity | None = None
        self._current: dict[int, float] = {}
        self._commanded: set[int] = set()
        self._started = False  # a motor command of ours was ACCEPTED at least once
        self._last_sent_s: float | None = None
        self._stop_acked_s: float | None = None
        self._stop_acked_seq = 0  # received-message count when the last stop was acknowledged
        self._stop_rpm: dict[int, float] = {}
        self._stop_refused = False
        self._verified_since_sent = False  # a verified stop since our last motor command
        self.last_stop_verified: bool | None = None

    # -- session shortcuts ----------------------------------------------------------------------
    @property
    def target_system(self) -> int:
        return self.session.target_system

    @property
    def target_component(self) -> int:
        return self.session.target_component

    def poll(self) -> int:
        return self.session.poll()

    def check_link(self) -> None:
        """The vehicle's HEARTBEAT is fresh, and no other address sent to the link while a
        motor is commanded (``LinkIntruder``: the run stops the motor through the locked peer)."""
        self.session.check_link()
        self.session.check_intruders(commanded=bool(self._current))

    def command(self, cmd: mav.CommandLong, *, attempts: int | None = None) -> mav.CommandAck:
        return self.session.command(cmd, attempts=attempts)

    def read_params(self, names: Sequence[str], *, attempts: int = 2) -> dict[str, float]:
        return self.session.read_params(names, attempts=attempts)

    def _require_accepted(self, cmd: mav.CommandLong, what: str) -> mav.CommandAck:
        sent_s = self.clock.now_s()
        ack = self.session.command(cmd)
        if ack.accepted:
            self._started = True  # only motor commands come through here
            return ack
        # A refusal's explanation may come just after the ACK: give it a moment.
        self.session.wait_until(lambda: bool(self.session.texts_since(sent_s)), 0.2)
        texts = self.session.texts_since(sent_s)
        raise MotorTestRefused(
            self._refusal_message(what, int(ack.result), texts),
            result=int(ack.result),
            statustext=texts,
        )

    def _refusal_message(self, what: str, result: int, texts: Sequence[str]) -> str:
        said = f": {'; '.join(repr(t) for t in texts)}" if texts else ""
        return f"{self.kind} refused {what} ({result_name(result)}){said}"

    # -- identify ------------------------------------------------------------------------------
    def _request_rates(self) -> None:
        interval_s = 1.0 / self.telemetry_rate_hz if self.telemetry_rate_hz > 0 else 0.0
        for message_id in self.telemetry_messages:
            ack = self.command(mav.set_message_interval(message_id, interval_s))
            if not ack.accepted:
                log.info(
                    "vehicle did not accept a rate for message %d (%s)",
                    message_id,
                    result_name(int(ack.result)),
                )

    def _guess_motor_count(self) -> tuple[int, str]:
        if self._motor_count_arg:
            return self._motor_count_arg, "argument"
        counted = self._param_motor_count()
        if counted:
            return counted, "parameter"
        servo = self.session.servo
        if servo is not None:
            outputs = servo.value.outputs_us
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
        s = self.session
        hb = s.ensure_heartbeat()
        s.poll()
        hb = s.heartbeat.value if s.heartbeat is not None else hb
        if hb.armed:
            raise SafetyError(
                f"the {self.kind} vehicle reports ARMED (HEARTBEAT base_mode {hb.base_mode}): "
                "disarm it before a motor test"
            )
        self._request_rates()
        version = s.request_autopilot_version()
        details = self._read_firmware_params()
        wanted = {"SERVO_OUTPUT_RAW", "BATTERY_STATUS"}
        s.wait_until(lambda: wanted <= s.seen, 2.0 / max(self.telemetry_rate_hz, 1.0))
        self.motor_count, source = self._guess_motor_count()
        details.update(self._after_motor_count())
        cells = None
        if s.battery is not None and s.battery.value.cell_voltages_v:
            cells = len(s.battery.value.cell_voltages_v)
        details.update(
            {
                "system_id": str(self.target_system),
                "component_id": str(self.target_component),
                "vehicle_type": str(hb.vehicle_type),
                "motor_count_source": source,
                "test_timeout_s": f"{self.test_timeout_s:g}",
                "param_encoding": s.param_encoding.value,
            }
        )
        if self.motor_count:
            details["motors"] = ", ".join(self.motor_label(m) for m in range(self.motor_count))
        if version is not None:
            details["board_version"] = str(version.board_version)
            details["capabilities"] = str(version.capabilities)
        self._identity = DeviceIdentity(
            kind=self.kind,
            firmware_version=version.version_text if version is not None else "",
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

    def _after_motor_count(self) -> dict[str, str]:
        """Firmware-specific work once the motor count is known; returns identity details."""
        return {}

    def motor_protocol(self) -> str:
        return ""

    def motor_label(self, motor: int) -> str:
        """How the FC names 0-based ``motor`` (both numberings where they differ)."""
        return f"motor {motor + 1}"

    def esc_index(self, motor: int) -> int:
        """The ESC-telemetry index that reports 0-based FC ``motor``."""
        return motor

    # -- throttle -------------------------------------------------------------------------------
    def _check_motor(self, motor: int) -> None:
        limit = self.motor_count or 16
        if not 0 <= motor < min(limit, 16):
            raise SafetyError(
                f"motor {motor + 1} out of range 1..{min(limit, 16)} for this vehicle"
            )

    def _check_value(self, motor: int, value: float) -> None:
        scale = self.throttle_scale
        if not (math.isfinite(value) and scale.lo <= value <= scale.hi):
            raise SafetyError(
                f"throttle {value!r} for {self.motor_label(motor)} is outside "
                f"{scale.lo:g}..{scale.hi:g} {scale.unit_label} ({scale.name})"
            )

    def _check_schedule(self) -> None:
        """A running test must be re-commanded within ``max_command_gap_s``."""
        if not self._current or self._last_sent_s is None:
            return
        gap_s = self.clock.now_s() - self._last_sent_s
        if gap_s > self.max_command_gap_s:
            raise CommandsLate(
                f"motor command re-sent {gap_s:.2f} s after the previous one (limit "
                f"{self.max_command_gap_s:g} s): the firmware ends a motor test "
                f"{self.test_timeout_s:g} s after the last command, so the output did not hold "
                "the commanded value; this run failed"
            )

    def _sent(self) -> None:
        self._last_sent_s = self.clock.now_s()
        self._verified_since_sent = False

    def _send_or_assume_running(self, values: dict[int, float]) -> None:
        """Send; if the outcome is unknown (no ACK, link gone), assume the motor may be turning."""
        self._verified_since_sent = False
        try:
            self._send_throttle(values)
        except MotorTestRefused:
            raise  # explicitly refused: this command started nothing
        except BaseException:
            self._started = True
            self._current = self._current or dict(values)
            self._commanded.update(values)
            raise

    def set_throttle(self, values: Mapping[int, float]) -> None:
        if self._identity is None:
            self.identify()
        if not values:
            self.stop()
            return
        for motor, value in values.items():
            self._check_motor(motor)
            self._check_value(motor, value)
        self.poll()
        # never start, or go on, with an intruder on the link
        self.session.check_intruders(commanded=True, starting=not self._current)
        self._check_schedule()
        self._before_start(values)
        self._send_or_assume_running(dict(values))
        self._current = dict(values)
        self._commanded.update(values)
        self._sent()

    def keepalive(self) -> None:
        """Re-send the current command (the firmware's test timeout restarts); check the link."""
        self.poll()
        self.check_link()
        if self._current:
            self._check_schedule()
            self._send_or_assume_running(dict(self._current))
            self._sent()

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
    def _stop_commands(self) -> list[mav.CommandLong]:
        """The stop commands to send now (may be empty where a stop would start something)."""

    def stop(self) -> None:
        """Send the stop for every motor (all on the wire first), then check every ACK."""
        s = self.session
        commands = [s.target(c) for c in self._stop_commands()]
        self._current = {}
        self._stop_rpm = {m: st.value for m, st in s.esc_rpm.items()}
        self._stop_acked_s = None
        self._stop_refused = False
        if not commands:
            log.info("no motor test of ours is running: no stop sent, checking the outputs")
            self._stop_acked_s = self.clock.now_s()
            self._stop_acked_seq = s.rx_seq
            return
        for cmd in commands:  # all of them out before waiting for anything
            s.send(cmd.to_message())
        log.info("stop sent (%d command%s)", len(commands), "" if len(commands) == 1 else "s")
        wanted = {c.command for c in commands}
        s.acks = [a for a in s.acks if a.command not in wanted]
        needed = len(commands)
        results: list[mav.CommandAck] = []

        def all_acked() -> bool:
            while len(results) < needed:
                ack = s.take_ack(commands[0].command)
                if ack is None:
                    return False
                results.append(ack)
            return True

        if not s.wait_until(all_acked, s.ack_timeout_s):
            raise MavlinkLinkLost(
                f"stop sent, but only {len(results)} of {needed} COMMAND_ACKs arrived within "
                f"{s.ack_timeout_s:g} s"
            )
        refused = [a for a in results if not a.accepted]
        self._stop_refused = bool(refused)
        if refused:
            texts = s.texts_since(self.clock.now_s() - s.ack_timeout_s)
            log.warning(
                "%s", self._refusal_message("the stop command", int(refused[0].result), texts)
            )
        self._stop_acked_s = self.clock.now_s()
        self._stop_acked_seq = s.rx_seq
        self._after_stop_acked(refused=bool(refused))

    def _after_stop_acked(self, *, refused: bool) -> None:  # noqa: B027 - optional hook
        """Firmware-specific bookkeeping once a stop was acknowledged."""

    # -- verification ------------------------------------------------------------------------------
    def _motor_indices(self) -> list[int]:
        return sorted(set(range(self.motor_count)) | self._commanded)

    def _has_output_evidence(self) -> bool:
        return "SERVO_OUTPUT_RAW" in self.session.seen or bool(self.session.esc_rpm)

    @abstractmethod
    def _outputs_stopped(self, outputs_us: Sequence[int], motors: Sequence[int]) -> bool: ...

    def _heartbeat_required(self) -> bool:
        return False

    def _stop_evidence(self, since: int) -> tuple[bool, list[str]]:
        """(all available evidence says stopped, what is still missing or wrong)."""
        s = self.session
        motors = self._motor_indices()
        missing: list[str] = []
        hb = s.heartbeat
        if self._heartbeat_required() and (hb is None or hb.seq <= since):
            missing.append("a HEARTBEAT after the stop")
        elif hb is not None and hb.seq > since and hb.value.armed:
            missing.append("HEARTBEAT still says ARMED")
        if "SERVO_OUTPUT_RAW" in s.seen:
            servo = s.servo
            if servo is None or servo.seq <= since:
                missing.append("a SERVO_OUTPUT_RAW after the stop")
            elif not self._outputs_stopped(servo.value.outputs_us, motors):
                missing.append(f"outputs not at stop: {servo.value.outputs_us[: len(motors) or 4]}")
        if s.esc_rpm:
            for m in motors:
                stamped = s.esc_rpm.get(self.esc_index(m))
                if stamped is None:
                    continue
                if stamped.seq <= since:
                    missing.append(f"ESC rpm of {self.motor_label(m)} after the stop")
                    continue
                rpm, at_stop = stamped.value, self._stop_rpm.get(self.esc_index(m), 0.0)
                coasting = at_stop > self.rest_rpm and rpm <= self.coast_fraction * at_stop
                if rpm > self.rest_rpm and not coasting:
                    missing.append(f"{self.motor_label(m)} at {rpm:.0f} rpm")
        return not missing, missing

    def verify_stopped(self) -> bool:
        if self._stop_acked_s is None:
            if self._started:
                log.warning("stop not verified: the FC did not acknowledge the last stop")
            else:  # the check before a run: nothing commanded yet, a stop follows
                log.info("motors at rest not confirmed yet: no stop sent so far")
            return False
        if self._stop_refused and not self._has_output_evidence():
            log.warning("stop not verified: the FC refused the stop and reports no outputs")
            return False
        outcome: list[str] = []

        def stopped() -> bool:
            ok, missing = self._stop_evidence(self._stop_acked_seq)
            outcome[:] = missing
            return ok

        ok = self.session.wait_until(stopped, self.verify_timeout_s)
        if ok:
            log.info("stop verified")
        else:
            log.warning("stop not verified: %s", "; ".join(outcome))
        return ok

    def stop_and_verify(self, attempts: int = 3, *, alarm: bool = True) -> bool:
        if not self._started:
            # Nothing we asked for was ever accepted (refused, or never commanded): no motor of
            # ours can be turning. Send what is harmless, but raise no alarm.
            try:
                self.stop()
            except Exception as exc:  # noqa: BLE001 - the link may be gone; nothing to stop
                log.info("stop (nothing of ours was running) not acknowledged: %s", exc)
            log.info("no motor command of ours was accepted: nothing of ours to stop")
            self.last_stop_verified = True
            return True
        if self._verified_since_sent and self._stop_is_idempotent_noop():
            log.info("stop already verified and nothing commanded since")
            return True
        ok = super().stop_and_verify(attempts, alarm=alarm)
        self.last_stop_verified = ok
        self._verified_since_sent = ok
        return ok

    def _stop_is_idempotent_noop(self) -> bool:
        """True where a repeated stop would send nothing (ArduPilot with no test of ours)."""
        return False

    # -- telemetry -------------------------------------------------------------------------------
    def _fresh(self, stamped: Stamped | None, now_s: float) -> Any:
        if stamped is None or now_s - stamped.time_s > self.telemetry_max_age_s:
            return None
        return stamped.value

    def read_telemetry(self) -> Telemetry:
        s = self.session
        s.poll()
        self.check_link()
        now_s = self.clock.now_s()
        voltage_v = current_a = None
        battery = self._fresh(s.battery, now_s)
        if battery is not None:
            voltage_v, current_a = battery.total_voltage_v, battery.current_a
        sys_status = self._fresh(s.sys_status, now_s)
        if sys_status is not None:
            voltage_v = voltage_v if voltage_v is not None else sys_status.voltage_v
            current_a = current_a if current_a is not None else sys_status.current_a
        count = self.motor_count or len(s.esc_rpm)
        rpm = tuple(self._fresh(s.esc_rpm.get(self.esc_index(m)), now_s) for m in range(count))
        temp = tuple(self._fresh(s.esc_temp.get(self.esc_index(m)), now_s) for m in range(count))
        return Telemetry(
            now_s,
            voltage_v,
            current_a,
            rpm if rpm and all(r is not None for r in rpm) else None,
            temp if temp and all(t is not None for t in temp) else None,
        )

    def close(self) -> None:
        self.session.close()
