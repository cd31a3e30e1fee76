"""A Betaflight/INAV-like flight controller at the MSP byte level (a ``BytePeer``).

It answers the way real firmware does, quirks included:

- replies in the version it was asked in (v1, v2, v2-over-v1);
- ``!`` (empty payload, the request's cmd) for unknown and refused commands;
- NO answer to a bad checksum or a request payload over 192 bytes (the client must time out);
- one request served per serial-task run (``serial_rate_hz``, default 100 Hz): replies become
  readable at the next free service slot, not instantly;
- SET_MOTOR values persist forever (no timeout) and are refused (``!``) while armed; a
  SET_MOTOR shorter than 8 values gets ``!`` on newer firmware (``reject_short_set_motor``),
  older firmware applies the values it got; values apply again after a disarm;
- SET_ARMING_DISABLED is tracked (ARMING_DISABLED_MSP in STATUS/STATUS_EX; disabling disarms);
- MOTOR returns the last values (external units; 0 for absent motors or a disabled protocol,
  and 0 for every motor on a profile without read-back: a SITL whose motor loop is not running
  answers so whatever SET_MOTOR said — "no information", not "stopped");
- the SITL profiles (``betaflight-4.6-sitl``, ``betaflight-2026-sitl``) answer reply for reply
  like the real SITL builds (identity, BOARD_INFO, STATUS layout, no battery, PWM output) and
  acknowledge but ignore SET_ARMING_DISABLED 1, as SITL firmware does;
  real DShot firmware converts back from DShot values and may be 1 off — verify with a
  tolerance;
- MOTOR_TELEMETRY, ANALOG, BATTERY_STATE (and INAV's MSP2_INAV_ANALOG) come from a
  :class:`~thrustmap.rig.sim.plant.Plant` read at the request's arrival time;
- stray bytes outside frames: ``#`` enters the CLI and ``R`` (disarmed) reboots into the
  bootloader — both make the peer go silent, as real firmware would for an MSP client.

SET_MOTOR maps to plant throttle: DShot 1001..2000 -> 0..1, PWM-like (v-1000)/1000.
"""

from __future__ import annotations

import heapq
import logging
import math
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, replace

from thrustmap.core.errors import ConfigError
from thrustmap.protocols.msp.framing import (
    MSP_MAX_REQUEST_PAYLOAD,
    MspCommand,
    MspDecoder,
    MspDirection,
    MspFrame,
    MspPayloadError,
    encode_frame,
)
from thrustmap.protocols.msp.messages import (
    Analog,
    ApiVersion,
    ArmingDisable,
    BatteryConfig,
    BatteryState,
    BatteryStateCode,
    BoardInfo,
    FcVariant,
    FcVersion,
    InavAnalog,
    SetArmingDisabled,
    Status,
    StatusEx,
)
from thrustmap.protocols.msp.motor import (
    AdvancedConfig,
    EscTelemetry,
    Motor,
    MotorConfig,
    MotorProtocol,
    MotorTelemetry,
    SetMotor,
    external_to_fraction,
)
from thrustmap.protocols.peer import BytePeer, register_peer
from thrustmap.rig.sim.options import MAX_SIM_MOTORS, opt_flag, opt_float, opt_int
from thrustmap.rig.sim.plant import ConstantPlant, Plant, PlantState

log = logging.getLogger(__name__)

MSP_MOTOR_SLOTS = 8


@dataclass(frozen=True)
class FirmwareProfile:
    """What a firmware generation reports and how strict it is."""

    name: str
    variant: str  # FC_VARIANT identifier
    api: ApiVersion
    version: FcVersion
    board_id: str = "S405"
    reject_short_set_motor: bool = True
    has_inav_analog: bool = False
    status_has_arming_flags: bool = True
    #: ARMING_DISABLE_FLAGS_COUNT in STATUS (grows with firmware: 26 in 4.3, 29 in 4.6, 30 later)
    arming_disable_count: int = 26
    #: STATUS bytes after the arming-disable flags (config state, core temperature, ...)
    status_tail: bytes = b"\x00"
    #: BOARD_INFO bytes after board id and hardware revision
    board_tail: bytes = b""
    #: MOTOR_CONFIG minthrottle (newer firmware reports 0: the setting is gone)
    min_throttle_ext: int = 1070
    #: False: MSP_MOTOR reads 0 for every motor whatever SET_MOTOR said (a SITL whose motor
    #: device or control loop is not running: "no information", not "stopped")
    motor_readback: bool = True
    #: False: SET_ARMING_DISABLED 1 is acknowledged and ignored (SITL builds: SIMULATOR_BUILD)
    honours_arming_disable: bool = True
    #: what a SITL reports instead of a battery: no cells, 0 V, state INIT
    no_battery: bool = False
    sensors: int = 0x23  # STATUS sensor bits: ACC | BARO | GYRO
    #: ADVANCED_CONFIG bytes after the first 8 (gyro and calibration settings)
    advanced_tail: bytes = b""
    use_unsynced_pwm: bool = False
    #: the motor protocol a fresh board of this kind is set to (None: DShot600)
    motor_protocol: MotorProtocol | None = None


#: BOARD_INFO after "SITL" + hardware revision (board type, capabilities, target name "SITL",
#: empty board name and manufacturer id, empty signature, MCU type, configuration state, gyro
#: sample rate, configuration problems...) as the two SITL builds send it
_SITL_4_6_BOARD_TAIL = bytes.fromhex("0000045349544c" + "00" * 34 + "0001401f000000000000")
_SITL_2026_BOARD_TAIL = bytes.fromhex("0000045349544c" + "00" * 34 + "fe01e803000000000000")

FIRMWARE: dict[str, FirmwareProfile] = {
    p.name: p
    for p in (
        FirmwareProfile(
            "betaflight-4",
            "BTFL",
            ApiVersion(0, 1, 46),
            FcVersion(4, 5, 1),
            reject_short_set_motor=False,
        ),
        FirmwareProfile(
            "betaflight-2025",
            "BTFL",
            ApiVersion(0, 1, 47),
            FcVersion(25, 12, 0, "2025.12.0"),
        ),
        # Real SITL builds, reply for reply as recorded (the tests compare them): Betaflight
        # 4.6.0 SITL with a simulator feeding it (its control loop runs, MSP_MOTOR reads back)
        # and 2026.12.0-alpha SITL as recorded without one (MSP_MOTOR reads 0).
        FirmwareProfile(
            "betaflight-4.6-sitl",
            "BTFL",
            ApiVersion(0, 1, 47),
            FcVersion(4, 6, 0),
            board_id="SITL",
            reject_short_set_motor=False,
            arming_disable_count=29,
            status_tail=bytes(3) + b"\x04",
            board_tail=_SITL_4_6_BOARD_TAIL,
            min_throttle_ext=0,
            honours_arming_disable=False,
            no_battery=True,
            advanced_tail=bytes.fromhex("00000000307d000000020062"),
            use_unsynced_pwm=True,
            motor_protocol=MotorProtocol.PWM,
        ),
        FirmwareProfile(
            "betaflight-2026-sitl",
            "BTFL",
            ApiVersion(0, 1, 49),
            FcVersion(26, 12, 0, "2026.12.0-alpha"),
            board_id="SITL",
            reject_short_set_motor=False,
            arming_disable_count=30,
            status_tail=bytes(3) + b"\x04\x03\x00",
            board_tail=_SITL_2026_BOARD_TAIL,
            min_throttle_ext=0,
            motor_readback=False,
            honours_arming_disable=False,
            no_battery=True,
            sensors=0x27,
            advanced_tail=bytes.fromhex("00000000307d000000020067"),
            use_unsynced_pwm=True,
            motor_protocol=MotorProtocol.PWM,
        ),
        FirmwareProfile(
            "inav",
            "INAV",
            ApiVersion(0, 2, 5),
            FcVersion(8, 0, 0),
            board_id="MTKS",
            has_inav_analog=True,
            status_has_arming_flags=False,
        ),
    )
}


def firmware_profile(name: str) -> FirmwareProfile:
    try:
        return FIRMWARE[name.lower()]
    except KeyError:
        raise ConfigError(
            f"unknown simulated firmware '{name}'; expected one of: {', '.join(FIRMWARE)}"
        ) from None


class MspPeer:
    """A simulated flight controller speaking MSP. See the module docstring for its quirks."""

    def __init__(
        self,
        plant: Plant,
        firmware: str | FirmwareProfile = "betaflight-4",
        *,
        motor_protocol: MotorProtocol | None = None,
        motor_count: int | None = None,
        bidir_dshot: bool = True,
        serial_rate_hz: float | None = 100.0,
        cell_count: int | None = None,
        capacity_mah: int = 1500,
        reject_short_set_motor: bool | None = None,
        motor_readback: bool | None = None,
    ) -> None:
        self.plant = plant
        self.profile = firmware if isinstance(firmware, FirmwareProfile) else None
        if self.profile is None:
            self.profile = firmware_profile(str(firmware))
        if reject_short_set_motor is not None:
            self.profile = replace(self.profile, reject_short_set_motor=reject_short_set_motor)
        if motor_readback is not None:
            self.profile = replace(self.profile, motor_readback=motor_readback)
        if motor_protocol is None:
            motor_protocol = self.profile.motor_protocol
        if motor_protocol is None:  # (PWM is 0: test for None, not falsiness)
            motor_protocol = MotorProtocol.DSHOT600
        self.motor_protocol = motor_protocol
        self.motor_count = plant.motor_count if motor_count is None else motor_count
        if not 1 <= self.motor_count <= MSP_MOTOR_SLOTS:
            raise ConfigError(f"motor count must be 1..{MSP_MOTOR_SLOTS}, got {self.motor_count}")
        # Outputs beyond the plant's motors are simply not connected (SR: one rotor on a 4-in-1).
        self.bidir_dshot = bidir_dshot
        self.service_interval_s = 0.0 if not serial_rate_hz else 1.0 / serial_rate_hz
        self.capacity_mah = capacity_mah
        self._decoder = MspDecoder(max_payload=MSP_MAX_REQUEST_PAYLOAD)
        self._outbox: list[tuple[float, int, bytes]] = []  # (ready_s, seq, bytes) heap
        self._seq = 0
        self._next_service_s = float("-inf")
        self._time_s = float("-inf")
        self._state: PlantState | None = None
        self._consumed_mah = 0.0
        self._motor_mah = [0.0] * self.motor_count
        self.motor_values = [1000] * self.motor_count  # external units, persist forever
        self.armed = False
        self.arming_disable_flags = 0
        self.in_cli = False
        self.in_bootloader = False
        self.requests_served = 0
        self.requests_ignored = 0
        self._cell_count = cell_count  # None: estimated from the first voltage seen

    @property
    def cell_count(self) -> int:
        if self._cell_count is None:
            volts = self._state.voltage_v if self._state is not None else 4.2
            self._cell_count = max(1, math.ceil(volts / 4.3))
        return self._cell_count

    # -- BytePeer ---------------------------------------------------------------------------
    def write(self, data: bytes, now_s: float) -> None:
        self._advance(now_s)
        if self.in_cli or self.in_bootloader:
            return
        if self._decoder.pending_bytes == 0 and self._stray_bytes(data):
            return
        before = self._decoder.error_count
        for frame in self._decoder.feed(data):
            if frame.direction is not MspDirection.REQUEST:
                self.requests_ignored += 1
                continue
            reply = self._handle(frame, now_s)
            if reply is not None:
                self._queue(reply, now_s)
        self.requests_ignored += self._decoder.error_count - before

    def read(self, now_s: float) -> bytes:
        self._advance(now_s)
        out = bytearray()
        while self._outbox and self._outbox[0][0] <= now_s:
            out += heapq.heappop(self._outbox)[2]
        return bytes(out)

    def close(self) -> None:
        """The port closes; the FC keeps running — motor values are NOT reset (no timeout)."""

    # -- test hooks (what a pilot or the firmware itself would do) ----------------------------
    def arm(self, now_s: float) -> None:
        """Arm as a pilot would (no checks); motors leave SET_MOTOR control."""
        self._advance(now_s)
        self.armed = True
        for i in range(min(self.motor_count, self.plant.motor_count)):
            self.plant.set_throttle(i, 0.0, self._time_s)
        self._state = self.plant.state(self._time_s)

    def disarm(self, now_s: float) -> None:
        """Disarm: the last SET_MOTOR values apply again (the firmware restores them)."""
        self._advance(now_s)
        self.armed = False
        self._apply_motors()

    @property
    def motors_at_rest(self) -> bool:
        return all(v <= 1000 for v in self.motor_values)

    # -- internals --------------------------------------------------------------------------
    def _stray_bytes(self, data: bytes) -> bool:
        """Act on ``#``/``R`` before the first ``$``; True when the FC went silent."""
        head = data.split(b"$", 1)[0]
        if b"#" in head:
            log.warning("simulated FC: '#' outside a frame, entering the CLI (MSP goes silent)")
            self.in_cli = True
        elif b"R" in head and not self.armed:
            log.warning("simulated FC: 'R' outside a frame, rebooting into the bootloader")
            self.in_bootloader = True
            self.motor_values = [1000] * self.motor_count
            self._apply_motors()
        return self.in_cli or self.in_bootloader

    def _advance(self, now_s: float) -> PlantState:
        t = max(now_s, self._time_s)
        state = self.plant.state(t)
        if self._state is not None and t > self._time_s:
            dt_h = (t - self._time_s) / 3600.0
            self._consumed_mah += max(self._state.current_a, 0.0) * 1000.0 * dt_h
            for i, amps in enumerate(self._state.motor_current_a[: self.motor_count]):
                self._motor_mah[i] += max(amps, 0.0) * 1000.0 * dt_h
        self._time_s = t
        self._state = state
        return state

    def _queue(self, raw: bytes, now_s: float) -> None:
        ready = max(now_s, self._next_service_s)
        self._next_service_s = ready + self.service_interval_s
        heapq.heappush(self._outbox, (ready, self._seq, raw))
        self._seq += 1

    def _apply_motors(self) -> None:
        if self.armed:
            return
        for i, value in enumerate(self.motor_values[: self.plant.motor_count]):
            fraction = 0.0
            if self.motor_protocol not in (MotorProtocol.DISABLED, MotorProtocol.DRONECAN):
                fraction = external_to_fraction(value, self.motor_protocol)
            self.plant.set_throttle(i, fraction, self._time_s)
        self._state = self.plant.state(self._time_s)  # current draw changes from now on

    def _reply(self, frame: MspFrame, payload: bytes) -> bytes:
        return encode_frame(MspFrame(frame.version, MspDirection.REPLY, frame.cmd, payload))

    def _error(self, frame: MspFrame) -> bytes:
        return encode_frame(MspFrame(frame.version, MspDirection.ERROR, frame.cmd, b""))

    def _handle(self, frame: MspFrame, now_s: float) -> bytes | None:
        self.requests_served += 1
        try:
            payload = self._answer(frame)
        except MspPayloadError as exc:
            log.debug("simulated FC refuses cmd %d: %s", frame.cmd, exc)
            payload = None
        return self._error(frame) if payload is None else self._reply(frame, payload)

    def _answer(self, frame: MspFrame) -> bytes | None:
        """The reply payload, or None for ``!``."""
        profile = self.profile
        assert profile is not None
        cmd = frame.cmd
        state = self._state
        assert state is not None
        if cmd == MspCommand.API_VERSION:
            return profile.api.encode()
        if cmd == MspCommand.FC_VARIANT:
            return FcVariant(profile.variant).encode()
        if cmd == MspCommand.FC_VERSION:
            return profile.version.encode()
        if cmd == MspCommand.BOARD_INFO:
            return BoardInfo(profile.board_id, 0, profile.board_tail).encode()
        if cmd in (MspCommand.STATUS, MspCommand.STATUS_EX):
            return self._status(cmd == MspCommand.STATUS_EX).encode()
        if cmd == MspCommand.SET_ARMING_DISABLED:
            return self._set_arming_disabled(SetArmingDisabled.decode(frame.payload))
        if cmd == MspCommand.MOTOR:
            return self._motor().encode()
        if cmd == MspCommand.SET_MOTOR:
            return self._set_motor(SetMotor.decode(frame.payload))
        if cmd == MspCommand.ANALOG and profile.no_battery:
            return Analog(0.0, 0.0).encode()
        if cmd == MspCommand.ANALOG:
            return Analog(
                state.voltage_v, state.current_a, int(self._consumed_mah), 0, None
            ).encode()
        if cmd == MspCommand.BATTERY_STATE:
            return self._battery_state(state).encode()
        if cmd == MspCommand.MOTOR_CONFIG:
            return MotorConfig(
                profile.min_throttle_ext,
                2000,
                1000,
                self.motor_count,
                14,
                self.bidir_dshot and self.motor_protocol.is_digital,
                False,
            ).encode()
        if cmd == MspCommand.MOTOR_TELEMETRY:
            return self._telemetry(state).encode()
        if cmd == MspCommand.ADVANCED_CONFIG:
            return AdvancedConfig(
                int(self.motor_protocol),
                480,
                5.5,
                1,
                profile.use_unsynced_pwm,
                1,
                profile.advanced_tail,
            ).encode()
        if cmd == MspCommand.BATTERY_CONFIG:
            return BatteryConfig(3.3, 4.3, 3.5, self.capacity_mah).encode()
        if cmd == MspCommand.INAV_ANALOG and profile.has_inav_analog:
            return InavAnalog(
                state.voltage_v,
                state.current_a,
                state.voltage_v * state.current_a,
                int(self._consumed_mah),
                int(self._consumed_mah * state.voltage_v),
                max(0, int(self.capacity_mah - self._consumed_mah)),
                max(0, min(100, int(100 * (1 - self._consumed_mah / self.capacity_mah)))),
                0,
                self.cell_count << 4,
            ).encode()
        return None  # unknown here (REBOOT included: a test must never send it)

    def _status(self, extended: bool) -> Status:
        profile = self.profile
        assert profile is not None
        kind = StatusEx if extended else Status
        if not profile.status_has_arming_flags:
            return kind(cycle_time_us=125, mode_flags=int(self.armed), cpu_load=10)
        return kind(
            cycle_time_us=125,
            sensors=profile.sensors,
            mode_flags=int(self.armed),
            cpu_load=10,
            profile_word=0x0003 if extended else 0,
            arming_disable_count=profile.arming_disable_count,
            arming_disable_flags=int(self.arming_disable_flags),
            tail=profile.status_tail,
        )

    def _set_arming_disabled(self, request: SetArmingDisabled) -> bytes:
        assert self.profile is not None
        if not self.profile.honours_arming_disable:
            return b""  # acknowledged, ignored (SITL: "we can safely arm with MSP link")
        if request.disable:
            self.arming_disable_flags |= ArmingDisable.MSP
            if self.armed:
                self.armed = False
                self._apply_motors()
        else:
            self.arming_disable_flags &= ~ArmingDisable.MSP
        return b""

    def _motor(self) -> Motor:
        values = [0] * MSP_MOTOR_SLOTS
        assert self.profile is not None
        if self.motor_protocol is not MotorProtocol.DISABLED and self.profile.motor_readback:
            values[: self.motor_count] = self.motor_values
        return Motor(tuple(values))

    def _set_motor(self, request: SetMotor) -> bytes | None:
        if self.armed:
            return None
        profile = self.profile
        assert profile is not None
        if len(request.values) < MSP_MOTOR_SLOTS and profile.reject_short_set_motor:
            return None
        for i, value in enumerate(request.values[: self.motor_count]):
            self.motor_values[i] = min(max(int(value), 1000), 2000)
        self._apply_motors()
        return b""

    def _battery_state(self, state: PlantState) -> BatteryState:
        assert self.profile is not None
        if self.profile.no_battery:
            return BatteryState(0, 0, 0.0, 0.0, 0, int(BatteryStateCode.INIT), 0.0)
        per_cell = state.voltage_v / self.cell_count
        code = BatteryStateCode.OK
        if per_cell < 3.3:
            code = BatteryStateCode.CRITICAL
        elif per_cell < 3.5:
            code = BatteryStateCode.WARNING
        return BatteryState(
            self.cell_count,
            self.capacity_mah,
            state.voltage_v,
            state.current_a,
            int(self._consumed_mah),
            int(code),
        )

    def _telemetry(self, state: PlantState) -> MotorTelemetry:
        has_rpm = self.bidir_dshot and self.motor_protocol.is_digital
        motors = []
        for i in range(self.motor_count):
            rpm = state.rpm[i] if has_rpm and i < len(state.rpm) else 0.0
            temp = state.temperature_c[i] if i < len(state.temperature_c) else 0.0
            amps = state.motor_current_a[i] if i < len(state.motor_current_a) else 0.0
            motors.append(
                EscTelemetry(
                    max(rpm, 0.0),
                    0.0,
                    min(max(temp, 0.0), 255.0),
                    state.voltage_v,
                    max(amps, 0.0),
                    int(self._motor_mah[i]),
                )
            )
        return MotorTelemetry(tuple(motors))


def _opt_int(options: Mapping[str, str], key: str, default: int) -> int:
    return opt_int(options, key, default)


PlantFactory = Callable[[Mapping[str, str]], Plant]


def constant_plant(options: Mapping[str, str]) -> Plant:
    return ConstantPlant(opt_int(options, "motors", 4, lo=1, hi=MAX_SIM_MOTORS))


MSP_OPTIONS = frozenset({"firmware", "motors", "protocol", "rate_hz", "motor_readback"})


def msp_peer_from_options(
    options: Mapping[str, str], plant: Plant | None = None, *, allow: Collection[str] = ()
) -> MspPeer:
    """Build a peer from ``sim://`` URL options: ``firmware`` (betaflight-4, betaflight-2025,
    betaflight-4.6-sitl, betaflight-2026-sitl, inav), ``motors`` (default 4), ``protocol``
    (DSHOT600, PWM, ...; default: the firmware's), ``rate_hz`` (100; ``unlimited``: no limit), ``motor_readback``
    (0: MSP_MOTOR reads 0 whatever was commanded, as a SITL without its motor loop does).
    Keys in ``allow`` (a plant factory's options) are accepted and ignored here."""
    unknown = set(options) - MSP_OPTIONS - set(allow)
    if unknown:
        raise ConfigError(
            f"unknown MSP sim options {sorted(unknown)}; expected some of {sorted(MSP_OPTIONS)}"
        )
    motors = opt_int(options, "motors", 4, lo=1, hi=MAX_SIM_MOTORS)
    protocol: MotorProtocol | None = None
    if "protocol" in options:
        name = options["protocol"].upper()
        try:
            protocol = MotorProtocol[name]
        except KeyError:
            known = ", ".join(MotorProtocol.__members__)
            raise ConfigError(
                f"unknown motor protocol '{name}'; expected one of: {known}"
            ) from None
    rate: float | None = None  # rate_hz=unlimited: no serial task limit (a benchmark's ceiling)
    if options.get("rate_hz", "").strip().lower() != "unlimited":
        rate = opt_float(
            options,
            "rate_hz",
            100.0,
            positive=True,
            what="a serial frame rate in Hz (or unlimited)",
        )
    readback = opt_flag(options, "motor_readback", True) if "motor_readback" in options else None
    return MspPeer(
        plant if plant is not None else ConstantPlant(motors),
        options.get("firmware", "betaflight-4"),
        motor_protocol=protocol,
        motor_count=motors,
        serial_rate_hz=rate,
        motor_readback=readback,
    )


def register_msp_peers(
    plant_factory: PlantFactory = constant_plant,
    *,
    plant_options: Collection[str] = (),
    replace: bool = True,
) -> None:
    """Register ``sim://betaflight`` (firmware betaflight-4 unless ``firmware=`` says otherwise)
    and ``sim://inav``; each builds its plant with ``plant_factory(options)``."""

    def betaflight(options: Mapping[str, str]) -> BytePeer:
        return msp_peer_from_options(options, plant_factory(options), allow=plant_options)

    def inav(options: Mapping[str, str]) -> BytePeer:
        opts = {"firmware": "inav", **options}
        return msp_peer_from_options(opts, plant_factory(opts), allow=plant_options)

    register_peer("betaflight", betaflight, replace=replace)
    register_peer("inav", inav, replace=replace)
