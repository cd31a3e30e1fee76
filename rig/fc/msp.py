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
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

from thrustmap.clock import Clock
from thrustmap.errors import SafetyError, ThrustmapError
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

log = logging.getLogger(__name__)

MSP_MOTOR_SLOTS = 8
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
    ) -> None:
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
        self.request(MspCommand.SET_MOTOR, SetMotor(tuple(ext)).encode())

    def stop(self) -> None:
        self.request(MspCommand.SET_MOTOR, SetMotor.stop_all(MSP_MOTOR_SLOTS).encode())

    def motor_values(self) -> tuple[int, ...]:
        return Motor.decode(self.request(MspCommand.MOTOR)).values

    def verify_stopped(self) -> bool:
        values = self.motor_values()
        return all(v <= MSP_MOTOR_STOP for v in values)

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
        ok = super().stop_and_verify(attempts)
        if ok and self._arming_disabled:
            try:
                self.request(MspCommand.SET_ARMING_DISABLED, SetArmingDisabled(False).encode())
                self._arming_disabled = False
            except ThrustmapError as exc:
                log.warning("could not re-enable arming: %s", exc)
        return ok

    def close(self) -> None:
        self.port.close()
