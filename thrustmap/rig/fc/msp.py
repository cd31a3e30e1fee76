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
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING, Literal

from thrustmap.core.clock import Clock
from thrustmap.core.errors import SafetyError, ThrustmapError
from thrustmap.protocols.msp.framing import MspDecoder, MspFrame, MspVersion, encode_request
from thrustmap.protocols.msp.messages import (
    MSP_MOTOR_STOP,
    AdvancedConfig,
    ApiVersion,
    BatteryState,
    BoardInfo,
    FcVariant,
    FcVersion,
    Motor,
    MotorConfig,
    MotorProtocol,
    MotorTelemetry,
    MspCommand,
    SetArmingDisabled,
    SetMotor,
    Status,
    native_to_external,
    throttle_scale_for,
)
from thrustmap.protocols.transport import SerialLike
from thrustmap.rig.interfaces import DeviceIdentity, Telemetry, ThrottleOutput

if TYPE_CHECKING:
    from thrustmap.rig.watchdog import Watchdog

log = logging.getLogger(__name__)

MSP_MOTOR_SLOTS = 8
#: the outcome of reading MSP_MOTOR after a stop
StopCheck = Literal["verified", "running", "unverifiable"]
VARIANTS = {"BTFL": "betaflight", "INAV": "inav", "CLFL": "cleanflight", "EMUF": "emuflight"}


class MspTimeout(ThrustmapError):
    """The FC did not answer an MSP request (it ignores bad frames silently)."""


class MspRefused(ThrustmapError):
    """The FC answered with an MSP error frame (``!``): unknown or refused command."""


class MspThrottleOutput(ThrottleOutput):
    def __init__(
        self,
        port: SerialLike,
        clock: Clock,
        *,
        timeout_s: float = 0.1,
        retries: int = 2,
        version: MspVersion = MspVersion.V1,
        url: str | None = None,
        baudrate: int | None = None,
        watchdog: bool = True,
        watchdog_log: str | None = None,
    ) -> None:
        """``url``/``baudrate``: how ``port`` was opened. With them (and ``watchdog``), the
        preflight starts the motor-stop watchdog on the same port (not for simulated or
        replayed ports, which end with this process)."""
        self.port = port
        self.clock = clock
        self.timeout_s = timeout_s
        self.retries = retries
        self.version = version
        self._decoder = MspDecoder()
        self._identity: DeviceIdentity | None = None
        self.motor_protocol = MotorProtocol.DSHOT600
        self.throttle_scale = throttle_scale_for(self.motor_protocol)
        self._arming_disabled = False
        self._motor_count: int | None = None
        self._motors_may_run = False  # a motor command went out since the last confirmed stop
        #: why the last stop could not be verified on this FC (None: verified, or not known yet)
        self.stop_unverifiable: str | None = None
        self.watchdog_url = watchdog_target(url) if (url is not None and watchdog) else None
        self.baudrate = baudrate
        self.watchdog_log = watchdog_log
        self._watchdog: Watchdog | None = None
        self.port.timeout = 0.0  # we poll with our own clock-driven deadline

    # -- MSP request/response -------------------------------------------------------------
    def request(self, cmd: int, payload: bytes = b"") -> bytes:
        """Send one request and return the reply payload; retry on silence."""
        last: Exception | None = None
        for attempt in range(self.retries + 1):
            self.port.write(encode_request(cmd, payload, self.version))
            try:
                return self._await(cmd)
            except MspTimeout as exc:
                last = exc
                log.debug("MSP cmd %d: no reply (attempt %d)", cmd, attempt + 1)
        assert last is not None
        raise last

    def _await(self, cmd: int) -> bytes:
        deadline = self.clock.now_s() + self.timeout_s
        while True:
            data = self.port.read(max(1, self.port.in_waiting))
            for frame in self._decoder.feed(data):
                if frame.cmd != cmd:
                    log.debug("MSP: discarding unexpected reply to cmd %d", frame.cmd)
                    continue
                return self._payload(frame)
            if self.clock.now_s() >= deadline:
                raise MspTimeout(
                    f"no MSP reply to command {cmd} within {self.timeout_s * 1000:.0f} ms"
                )
            if not data:
                self.clock.sleep_s(0.001)

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
            self._ensure_watchdog()
            self._motors_may_run = True
        self.request(MspCommand.SET_MOTOR, SetMotor(tuple(ext)).encode())

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
        self.stop_unverifiable = None
        values = self.motor_values()
        running = [i + 1 for i, v in enumerate(values) if v > MSP_MOTOR_STOP]
        if running:
            log.warning("MSP_MOTOR: motor(s) %s above the stop value: %s", running, values)
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

    def read_telemetry(self) -> Telemetry:
        now = self.clock.now_s()
        batt = BatteryState.decode(self.request(MspCommand.BATTERY_STATE))
        rpm = temp = None
        try:
            tel = MotorTelemetry.decode(self.request(MspCommand.MOTOR_TELEMETRY))
            rpm = tuple(m.rpm for m in tel.motors)
            temp = tuple(m.temperature_c for m in tel.motors)
        except MspRefused:
            pass  # no ESC telemetry on this build
        return Telemetry(now, batt.voltage_v, batt.current_a, rpm, temp)

    def stop_and_verify(self, attempts: int = 3) -> bool:
        """Send the stop and confirm it with MSP_MOTOR; retry. Never raises.

        An FC that reports no motor values (see module) gets one acknowledged stop and a
        warning, not retries and a CRITICAL alarm: nothing says a motor turns, and nothing can
        say it stopped. The result is False all the same: such a stop is never "verified"."""
        for attempt in range(1, attempts + 1):
            try:
                self.stop()
                verified = self.verify_stopped()
            except Exception as exc:  # the link may be gone; keep trying, then report
                log.error("stop attempt %d failed: %s", attempt, exc)
                continue
            if verified:
                log.info("motors stopped (verified, attempt %d)", attempt)
                self._motors_may_run = False
                self._enable_arming()
                return True
            if self.stop_unverifiable is not None:
                # The FC acknowledged the stop and reports driving nothing: arming goes back
                # as Configurator leaves it, but the result stays "not verified".
                log.warning("motor stop sent and acknowledged; %s", self.stop_unverifiable)
                self._motors_may_run = False
                self._enable_arming()
                return False
            log.warning("stop not confirmed (attempt %d of %d)", attempt, attempts)
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
        self.stop()
        outcome = self.check_stopped()
        if outcome != "running":
            self._arming_disabled = True  # the dead session left it disabled
            self._enable_arming()
        return outcome

    # -- the watchdog ----------------------------------------------------------------------
    def _ensure_watchdog(self) -> None:
        if self._watchdog is not None or self.watchdog_url is None:
            return
        from thrustmap.rig.watchdog import start_watchdog

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
