"""One MAVLink conversation with one vehicle: the receive loop, COMMAND_LONG/ACK, parameters.

``MavlinkSession(link, clock)`` wraps a pymavlink ``mavfile`` (normally
``thrustmap.protocols.mavlink.link.MavlinkSerialLink``) and keeps the latest state the vehicle
reported, stamped with the clock and with its position in the received stream (``seq``: "after
the stop" is decided by order, not by clock time). It knows nothing about motors; the throttle
outputs (``rig.fc.mavlink_output``, ``rig.fc.px4``, ``rig.fc.ardupilot``) are built on it.

- Receiving: ``poll()`` handles what has arrived without waiting, but at most
  ``max_messages_per_poll`` messages per call, so a vehicle streaming 20 kB/s (PX4's GCS link)
  can never keep the caller from sending its next command; the rest is read on the next call.
  ``wait_until(done, timeout_s)`` receives until a condition holds.
- Commands: ``command(cmd)`` sends a COMMAND_LONG and returns its final COMMAND_ACK, re-sending
  up to ``command_attempts`` times; no ACK -> ``MavlinkLinkLost``.
- Parameters: ``read_params(names)`` asks for all of them at once; a PARAM_ERROR answers a name
  for good (it is not asked again). Values are decoded by ``param_type`` and the vehicle's
  encoding (bytewise or C cast, from AUTOPILOT_VERSION.capabilities, else the autopilot's
  practice; see ``thrustmap.protocols.mavlink.params``), also for values that arrived before
  AUTOPILOT_VERSION did.
- ``check_link()`` raises ``MavlinkLinkLost`` when the vehicle's HEARTBEAT is too old.
- The locked link: the session talks to one vehicle (``target_system``/``target_component``,
  from its HEARTBEAT); messages from other system ids are dropped and counted
  (``foreign_system_messages``): a vehicle forwards other systems' traffic (ArduPilot routes a
  ground station's HEARTBEAT from one port to the others), so they are no intrusion. Datagrams
  from another ADDRESS never get here: the network endpoint drops and counts them
  (``protocols.urlhandlers.protocol_udpin``); ``check_intruders(commanded=True)`` turns them
  into ``LinkIntruder`` (naming the address) while motors are commanded.
- Signing: with a key (``protocols.mavlink.signing``) unsigned or wrongly signed messages are
  refused by pymavlink. When the vehicle stays silent, ``signing_problem()`` says why in one
  line (``SigningRequired``, a ``ConfigError``: exit 2).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from serial import SerialException

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError, DataFormatError, SafetyError, ThrustmapError
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink.params import ParamEncoding, encoding_from_capabilities
from thrustmap.protocols.mavlink.signing import is_signed
from thrustmap.rig.fc.link_lock import IntruderWatch
from thrustmap.rig.fc.link_timing import ReplyTimer

log = logging.getLogger(__name__)

MAX_FOREIGN = 32  # distinct foreign system ids remembered (the count goes on)


class MavlinkLinkLost(ThrustmapError):
    """No HEARTBEAT or no COMMAND_ACK in time, or the transport failed: the link is gone."""


class SigningRequired(ConfigError):
    """The vehicle and thrustmap disagree about MAVLink 2 signing (see ``signing_problem``)."""


def signing_problem(link: Any, signed_seen: int = 0, unsigned_seen: int = 0) -> str | None:
    """One line saying why a vehicle is silent because of signing, or None.

    ``signed_seen``/``unsigned_seen``: vehicle messages the session received with and without
    a signature (a link without a key accepts both)."""
    from thrustmap.protocols.mavlink.signing import ENV_VAR, signing_enabled, signing_stats

    mav_obj = getattr(link, "mav", None)
    if mav_obj is None or not hasattr(mav_obj, "signing"):
        return None
    if not signing_enabled(link):
        if signed_seen and not unsigned_seen:
            return (
                "the vehicle requires signed MAVLink: pass --signing-key FILE|HEX "
                f"(or set {ENV_VAR}); it signs its messages and ignored our unsigned commands"
            )
        return None
    stats = signing_stats(link)
    bad = stats.bad + int(getattr(link, "heartbeats_refused_bad_signature", 0))
    unsigned = stats.unsigned_refused + int(getattr(link, "heartbeats_refused_unsigned", 0))
    if stats.good == 0 and bad:
        return (
            f"refused {bad} signed MAVLink message(s) from the vehicle: signed with another "
            "key (wrong --signing-key?) or with a timestamp over a minute older than this "
            "computer's clock"
        )
    if stats.good == 0 and unsigned:
        return (
            f"refused {unsigned} unsigned MAVLink message(s): the vehicle does not sign "
            "(no key set on it?), and with --signing-key only signed messages are accepted"
        )
    return None


class MotorTestRefused(SafetyError):
    """The vehicle answered a motor command with something other than ACCEPTED."""

    def __init__(self, message: str, *, result: int, statustext: Sequence[str] = ()) -> None:
        super().__init__(message)
        self.result = result
        self.statustext = tuple(statustext)


class CommandsLate(SafetyError):
    """A motor command did not go out on schedule: the firmware may have ended the test, so the
    output did not hold the commanded value. A run with this error failed."""


class UnsupportedAutopilot(ConfigError):
    """The HEARTBEAT names an autopilot this package has no driver for."""


@dataclass(frozen=True)
class Stamped:
    value: Any
    time_s: float  # clock reading when processed (for telemetry age)
    seq: int = 0  # position in the received stream (for "after the stop": order, not time)


def command_name(command: int) -> str:
    names = {
        mav.MAV_CMD_DO_MOTOR_TEST: "DO_MOTOR_TEST",
        mav.MAV_CMD_ACTUATOR_TEST: "ACTUATOR_TEST",
        mav.MAV_CMD_SET_MESSAGE_INTERVAL: "SET_MESSAGE_INTERVAL",
        mav.MAV_CMD_REQUEST_MESSAGE: "REQUEST_MESSAGE",
    }
    return names.get(command, f"command {command}")


def result_name(result: int) -> str:
    try:
        return mav.MavResult(result).name
    except ValueError:
        return f"result {result}"


def wait_for_vehicle_heartbeat(link: Any, clock: Clock, timeout_s: float) -> mav.Heartbeat:
    """The first HEARTBEAT from a vehicle (not a GCS, not autopilot INVALID) within ``timeout_s``."""
    deadline_s = clock.now_s() + timeout_s
    while True:
        remaining_s = deadline_s - clock.now_s()
        if remaining_s <= 0:
            problem = signing_problem(link)
            if problem is not None:
                raise SigningRequired(f"{getattr(link, 'address', link)}: {problem}")
            raise MavlinkLinkLost(
                f"no HEARTBEAT from a vehicle within {timeout_s:g} s on "
                f"{getattr(link, 'address', link)}"
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


class MavlinkSession:
    """See the module docstring."""

    def __init__(
        self,
        link: Any,
        clock: Clock,
        *,
        heartbeat: mav.Heartbeat | None = None,
        ack_timeout_s: float | None = None,
        command_attempts: int = 2,
        heartbeat_timeout_s: float = 3.0,
        param_timeout_s: float = 0.3,
        max_messages_per_poll: int = 200,
    ) -> None:
        if command_attempts < 1:
            raise ConfigError(f"command_attempts must be >= 1, got {command_attempts}")
        if max_messages_per_poll < 1:
            raise ConfigError(f"max_messages_per_poll must be >= 1, got {max_messages_per_poll}")
        self.link = link
        self.clock = clock
        #: None: the COMMAND_ACK wait is learned from the link (``ack_timer``); else fixed
        self.fixed_ack_timeout_s = ack_timeout_s
        self.ack_timer = ReplyTimer(initial_s=0.5, min_s=0.2, max_s=1.5)
        #: COMMAND_ACKs that arrived for a command nobody waited for any more (dropped)
        self.stale_acks = 0
        self._duplicates: dict[int, list[float]] = {}  # command -> until when a twin may come
        self.command_attempts = command_attempts
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.param_timeout_s = param_timeout_s
        self.max_messages_per_poll = max_messages_per_poll
        self.target_system = heartbeat.system_id if heartbeat is not None else 0
        self.target_component = heartbeat.component_id if heartbeat is not None else 0
        now_s = clock.now_s()
        self.heartbeat: Stamped | None = None if heartbeat is None else Stamped(heartbeat, now_s)
        self.autopilot = int(heartbeat.autopilot) if heartbeat is not None else 0
        self.sys_status: Stamped | None = None
        self.battery: Stamped | None = None
        self.servo: Stamped | None = None
        self.esc_rpm: dict[int, Stamped] = {}
        self.esc_temp: dict[int, Stamped] = {}
        self.statustext: list[Stamped] = []
        self.acks: list[mav.CommandAck] = []
        self.param_values: dict[str, mav.ParamValue] = {}
        self.param_errors: set[str] = set()
        self.autopilot_version: mav.AutopilotVersion | None = None
        self.seen: set[str] = set()
        self.rx_seq = 0
        self.polls_cut_short = 0  # polls that stopped at max_messages_per_poll
        #: messages from other system ids, dropped (at most ``MAX_FOREIGN`` ids remembered)
        self.foreign_system_messages = 0
        self.foreign_systems: set[int] = set()
        #: vehicle messages received with / without a signature (for ``signing_problem``)
        self.signed_messages = 0
        self.unsigned_messages = 0
        self.acks_received = 0  # COMMAND_ACKs for us, ever (none: signing may be the reason)
        self.intruders = IntruderWatch(getattr(link, "port", None))
        self.endpoint = self.intruders.endpoint

    # -- receiving ----------------------------------------------------------------------------
    def _from_target(self, msg: Any) -> bool:
        if self.target_system == 0:
            return True
        return int(msg.get_srcSystem()) == self.target_system

    def handle(self, msg: Any) -> None:
        """Fold one received message into the state."""
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        if not self._from_target(msg):
            self.foreign_system_messages += 1
            system = int(msg.get_srcSystem())
            if system not in self.foreign_systems and len(self.foreign_systems) < MAX_FOREIGN:
                self.foreign_systems.add(system)
                log.info(
                    "dropped a %s from system %d (the link talks to system %d only)",
                    kind,
                    system,
                    self.target_system,
                )
            return
        if is_signed(msg):
            self.signed_messages += 1
        else:
            self.unsigned_messages += 1
        now_s = self.clock.now_s()
        self.rx_seq += 1
        decoded = mav.decode(msg)
        if decoded is None:
            return
        seq = self.rx_seq
        if isinstance(decoded, mav.Heartbeat):
            if not decoded.is_vehicle or (
                self.target_component and decoded.component_id != self.target_component
            ):
                return
            self.heartbeat = Stamped(decoded, now_s, seq)
            self.autopilot = int(decoded.autopilot)
        elif isinstance(decoded, mav.CommandAck):
            target = int(getattr(msg, "target_system", 0) or 0)
            if target not in (0, int(self.link.mav.srcSystem)):
                return  # an ACK for another ground station
            self.acks.append(decoded)
            self.acks_received += 1
        elif isinstance(decoded, mav.StatusText):
            log.info("vehicle: %s", decoded.text)
            self.statustext.append(Stamped(decoded.text, now_s, seq))
            del self.statustext[:-100]  # bounded
        elif isinstance(decoded, mav.ParamValue):
            self.param_values[decoded.name] = decoded
        elif isinstance(decoded, mav.ParamError):
            self.param_errors.add(decoded.name)
        elif isinstance(decoded, mav.AutopilotVersion):
            self.autopilot_version = decoded
        elif isinstance(decoded, mav.SysStatus):
            self.sys_status = Stamped(decoded, now_s, seq)
        elif isinstance(decoded, mav.BatteryStatus):
            if decoded.battery_id == 0:
                self.battery = Stamped(decoded, now_s, seq)
        elif isinstance(decoded, mav.ServoOutputRaw):
            if decoded.port == 0:
                self.servo = Stamped(decoded, now_s, seq)
        elif isinstance(decoded, mav.EscStatus):
            for i, rpm in enumerate(decoded.rpm):
                self.esc_rpm[decoded.first_index + i] = Stamped(rpm, now_s, seq)
        elif isinstance(decoded, mav.EscTelemetry):
            for i, rpm in enumerate(decoded.rpm):
                self.esc_rpm[decoded.first_index + i] = Stamped(rpm, now_s, seq)
                self.esc_temp[decoded.first_index + i] = Stamped(
                    decoded.temperature_c[i], now_s, seq
                )
        self.seen.add(kind)

    def recv_one(self, timeout_s: float) -> Any:
        try:
            if timeout_s > 0:
                msg = self.link.recv_match(blocking=True, timeout=timeout_s)
            else:  # a timeout of 0 would return before reading anything
                msg = self.link.recv_match(blocking=False)
        except (OSError, SerialException) as exc:
            raise MavlinkLinkLost(f"MAVLink transport failed: {exc}") from exc
        if msg is not None:
            self.handle(msg)
        return msg

    def poll(self) -> int:
        """Handle what has arrived, without waiting: at most ``max_messages_per_poll``."""
        count = 0
        while count < self.max_messages_per_poll:
            if self.recv_one(0.0) is None:
                return count
            count += 1
        self.polls_cut_short += 1
        return count

    def wait_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Receive until ``done()`` is true (True) or ``timeout_s`` passes (False)."""
        deadline_s = self.clock.now_s() + timeout_s
        while not done():
            remaining_s = deadline_s - self.clock.now_s()
            if remaining_s <= 0:
                return False
            self.recv_one(remaining_s)
        return True

    def check_link(self) -> None:
        """Raise ``MavlinkLinkLost`` if the vehicle's HEARTBEAT is older than the timeout."""
        hb = self.heartbeat
        age_s = math.inf if hb is None else self.clock.now_s() - hb.time_s
        if age_s > self.heartbeat_timeout_s:
            raise MavlinkLinkLost(
                f"no HEARTBEAT from the vehicle for {age_s:.1f} s "
                f"(limit {self.heartbeat_timeout_s:g} s): link lost"
            )

    @property
    def peer(self) -> str:
        """The locked peer: address (when the link has one) and system/component id."""
        address = getattr(self.endpoint, "peer", None)
        ids = f"system {self.target_system} component {self.target_component}"
        return f"{address} ({ids})" if address else ids

    def check_intruders(self, *, commanded: bool, starting: bool = False) -> None:
        """Raise ``LinkIntruder`` if another address sent to the link (datagrams dropped by
        the endpoint) while motors are ``commanded`` (``starting``: about to be); otherwise
        only log it."""
        self.intruders.check(commanded=commanded, starting=starting, peer_label=self.peer)

    def signing_problem(self) -> str | None:
        return signing_problem(self.link, self.signed_messages, self.unsigned_messages)

    def ensure_heartbeat(self) -> mav.Heartbeat:
        if self.heartbeat is None:
            hb = wait_for_vehicle_heartbeat(self.link, self.clock, self.heartbeat_timeout_s)
            self.target_system, self.target_component = hb.system_id, hb.component_id
            self.autopilot = int(hb.autopilot)
            self.heartbeat = Stamped(hb, self.clock.now_s())
        heartbeat: mav.Heartbeat = self.heartbeat.value
        return heartbeat

    def texts_since(self, time_s: float) -> list[str]:
        return [s.value for s in self.statustext if s.time_s >= time_s]

    def texts_after(self, seq: int) -> list[str]:
        return [s.value for s in self.statustext if s.seq > seq]

    # -- sending -------------------------------------------------------------------------------
    def send(self, msg: Any) -> None:
        try:
            self.link.mav.send(msg)
        except (OSError, SerialException) as exc:
            raise MavlinkLinkLost(f"MAVLink transport failed on send: {exc}") from exc

    def target(self, cmd: mav.CommandLong) -> mav.CommandLong:
        return mav.CommandLong(
            cmd.command, cmd.params, self.target_system or 1, self.target_component or 1
        )

    def take_ack(self, command: int) -> mav.CommandAck | None:
        for i, ack in enumerate(self.acks):
            if ack.command == command and ack.result != mav.MavResult.IN_PROGRESS:
                return self.acks.pop(i)
        return None

    @property
    def ack_timeout_s(self) -> float:
        """The wait for a COMMAND_ACK: fixed, or learned from the link's measured round trip
        (:class:`ReplyTimer`: 0.2..1.5 s; retries wait twice as long as the try before)."""
        if self.fixed_ack_timeout_s is not None:
            return self.fixed_ack_timeout_s
        return self.ack_timer.timeout_s

    def _ack_wait_for_try(self, attempt: int) -> float:
        if self.fixed_ack_timeout_s is not None:
            return self.fixed_ack_timeout_s
        return self.ack_timer.timeout_for_try(attempt)

    def _duplicate_due(self, command: int) -> bool:
        """An ACK for ``command`` is expected as the late twin of an earlier retried one."""
        now_s = self.clock.now_s()
        due = [t for t in self._duplicates.get(command, []) if t > now_s]
        if not due:
            self._duplicates.pop(command, None)
            return False
        self._duplicates[command] = due[1:]
        return True

    def command(self, cmd: mav.CommandLong, *, attempts: int | None = None) -> mav.CommandAck:
        """Send a COMMAND_LONG to the vehicle and return its final COMMAND_ACK (any result).

        A late ACK to an earlier try is the answer too; ACKs for this command left from before
        are dropped (``stale_acks``). The round trip of a command answered at its first try
        teaches the ACK wait (``ack_timer``)."""
        self.intruders.check_claims(peer_label=self.peer)  # which one is the vehicle?
        cmd = self.target(cmd)
        tries = self.command_attempts if attempts is None else attempts
        kept = [a for a in self.acks if a.command != cmd.command]
        self.stale_acks += len(self.acks) - len(kept)
        self.acks = kept
        waited_s = 0.0
        for attempt in range(1, tries + 1):
            log.debug("-> %s %s (attempt %d)", command_name(cmd.command), cmd.params, attempt)
            self.send(cmd.to_message())
            sent_s = self.clock.now_s()
            found: list[mav.CommandAck] = []

            def got_ack(command: int = cmd.command, out: list[mav.CommandAck] = found) -> bool:
                while not out:
                    ack = self.take_ack(command)
                    if ack is None:
                        break
                    if self._duplicate_due(command):
                        self.stale_acks += 1  # the late twin of an earlier command's ACK
                        log.debug("dropped a late duplicate COMMAND_ACK for %s", command)
                        continue
                    out.append(ack)
                return bool(out)

            wait_s = self._ack_wait_for_try(attempt)
            if self.wait_until(got_ack, wait_s):
                if attempt == 1:
                    self.ack_timer.sample(self.clock.now_s() - sent_s)
                else:  # the other tries' ACKs may still come: they answer nothing new
                    due_s = self.clock.now_s() + 2 * self.ack_timer.max_s
                    self._duplicates.setdefault(cmd.command, []).extend([due_s] * (attempt - 1))
                return found[0]
            if attempt == 1 and self.fixed_ack_timeout_s is None:
                self.ack_timer.timed_out()
            waited_s += wait_s
        problem = None if self.acks_received else self.signing_problem()
        if problem is not None:  # never answered: signing, not a lost link, may be why
            raise SigningRequired(problem)
        raise MavlinkLinkLost(
            f"no COMMAND_ACK for {command_name(cmd.command)} after {tries} tries "
            f"({waited_s:.2f} s in all): link lost"
        )

    def request_autopilot_version(self) -> mav.AutopilotVersion | None:
        """Ask for AUTOPILOT_VERSION (capabilities decide the parameter encoding)."""
        if self.autopilot_version is None:
            ack = self.command(mav.request_message(mav.MSG_AUTOPILOT_VERSION))
            if ack.accepted:
                self.wait_until(lambda: self.autopilot_version is not None, self.param_timeout_s)
        if self.autopilot_version is None:
            log.info(
                "vehicle sent no AUTOPILOT_VERSION: firmware version unknown, parameter "
                "encoding assumed %s",
                self.param_encoding.value,
            )
        return self.autopilot_version

    # -- parameters ----------------------------------------------------------------------------
    @property
    def param_encoding(self) -> ParamEncoding:
        caps = self.autopilot_version.capabilities if self.autopilot_version else None
        return encoding_from_capabilities(caps, self.autopilot)

    def param(self, name: str) -> float | None:
        """The decoded value of a parameter received so far (None if not received)."""
        raw = self.param_values.get(name)
        if raw is None:
            return None
        try:
            return raw.number(self.param_encoding)
        except DataFormatError as exc:
            log.warning("parameter %s: %s", name, exc)
            return None

    def params(self, names: Iterable[str]) -> dict[str, float]:
        out: dict[str, float] = {}
        for name in names:
            value = self.param(name)
            if value is not None:
                out[name] = value
        return out

    def _answered(self, name: str) -> bool:
        return name in self.param_values or name in self.param_errors

    def read_params(self, names: Iterable[str], *, attempts: int = 2) -> dict[str, float]:
        """Read parameters by name (all requested at once); names the vehicle lacks are absent.

        A name answered with PARAM_ERROR is not asked again; one never answered is asked
        ``attempts`` times, ``param_timeout_s`` each.
        """
        names = list(names)
        for _ in range(attempts):
            missing = [n for n in names if not self._answered(n)]
            if not missing:
                break
            for name in missing:
                self.send(
                    mav.param_request_read(
                        name,
                        target_system=self.target_system or 1,
                        target_component=self.target_component or 1,
                    )
                )
            self.wait_until(
                lambda m=missing: all(self._answered(n) for n in m),  # type: ignore[misc]
                self.param_timeout_s,
            )
        return self.params(names)

    # -- closing -------------------------------------------------------------------------------
    def close(self) -> None:
        try:
            self.link.close()
        except (OSError, SerialException) as exc:
            log.debug("closing the MAVLink link: %s", exc)
