"""MSP message payloads as typed records in SI units (volts, amps, °C, rpm, percent).

Every record has ``CMD`` (its MSP command id), ``encode() -> bytes`` (the payload) and
``decode(payload) -> record``; the same classes serve a driver (decode replies, encode requests)
and the simulated flight controller (decode requests, encode replies). Records keep every wire
field they read, so ``decode(p).encode() == p`` for the payload lengths they document; fields
beyond what is modelled are kept in ``tail`` bytes. Scaled values (0.01 V, 0.01 A, ...) are
floats; encoding rounds to the wire resolution.

Decoding a payload too short for the fields it must hold raises :class:`MspPayloadError`
(a :class:`~thrustmap.protocols.msp.framing.MspProtocolError`). Motor records and throttle encodings live
in :mod:`thrustmap.protocols.msp.motor`.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from typing import ClassVar

from thrustmap.protocols.msp.framing import MspCommand, MspFrame, MspPayloadError
from thrustmap.protocols.msp.motor import (
    AdvancedConfig,
    Motor,
    MotorConfig,
    MotorTelemetry,
    SetMotor,
)


class ArmingDisable(enum.IntFlag):
    """The Betaflight 4.x arming-disable bits a motor test cares about (STATUS_EX)."""

    NO_GYRO = 1 << 0
    FAILSAFE = 1 << 1
    RX_FAILSAFE = 1 << 2
    THROTTLE = 1 << 7
    ANGLE = 1 << 8
    CLI = 1 << 13
    MSP = 1 << 16  # set by SET_ARMING_DISABLED 1 (Configurator's motor tab)


def _need(payload: bytes, size: int, what: str) -> None:
    if len(payload) < size:
        raise MspPayloadError(f"{what}: need {size} payload bytes, got {len(payload)}")


def _q(value: float, resolution: float) -> int:
    return int(round(value / resolution))


def _text(raw: bytes) -> str:
    return raw.decode("ascii", errors="replace")


# --------------------------------------------------------------------------- identity


@dataclass(frozen=True)
class ApiVersion:
    CMD: ClassVar[int] = MspCommand.API_VERSION
    protocol: int
    major: int
    minor: int

    def encode(self) -> bytes:
        return bytes((self.protocol, self.major, self.minor))

    @classmethod
    def decode(cls, payload: bytes) -> ApiVersion:
        _need(payload, 3, "API_VERSION")
        return cls(payload[0], payload[1], payload[2])


@dataclass(frozen=True)
class FcVariant:
    CMD: ClassVar[int] = MspCommand.FC_VARIANT
    identifier: str  # "BTFL", "INAV", ...

    def encode(self) -> bytes:
        return self.identifier.encode("ascii")[:4].ljust(4, b" ")

    @classmethod
    def decode(cls, payload: bytes) -> FcVariant:
        _need(payload, 4, "FC_VARIANT")
        return cls(_text(payload[:4]))


@dataclass(frozen=True)
class FcVersion:
    """``major.minor.patch``; from Betaflight 2025.12 the first byte is year-2000, then month,
    patch and a length-prefixed version string (``label``)."""

    CMD: ClassVar[int] = MspCommand.FC_VERSION
    major: int
    minor: int
    patch: int
    label: str | None = None

    @property
    def is_year_based(self) -> bool:
        return self.label is not None or self.major >= 25

    def __str__(self) -> str:
        if self.label:
            return self.label
        if self.is_year_based:
            return f"{2000 + self.major}.{self.minor}.{self.patch}"
        return f"{self.major}.{self.minor}.{self.patch}"

    def encode(self) -> bytes:
        out = bytes((self.major, self.minor, self.patch))
        if self.label is not None:
            text = self.label.encode("ascii")[:255]
            out += bytes((len(text),)) + text
        return out

    @classmethod
    def decode(cls, payload: bytes) -> FcVersion:
        _need(payload, 3, "FC_VERSION")
        label = None
        if len(payload) >= 4 and len(payload) >= 4 + payload[3]:
            label = _text(payload[4 : 4 + payload[3]])
        return cls(payload[0], payload[1], payload[2], label)


@dataclass(frozen=True)
class BoardInfo:
    CMD: ClassVar[int] = MspCommand.BOARD_INFO
    board_id: str
    hardware_revision: int = 0
    tail: bytes = b""  # board type, capabilities, names, ... (not modelled)

    def encode(self) -> bytes:
        ident = self.board_id.encode("ascii")[:4].ljust(4, b" ")
        return ident + struct.pack("<H", self.hardware_revision) + self.tail

    @classmethod
    def decode(cls, payload: bytes) -> BoardInfo:
        _need(payload, 4, "BOARD_INFO")
        if len(payload) < 6:
            return cls(_text(payload[:4]))
        return cls(_text(payload[:4]), struct.unpack_from("<H", payload, 4)[0], payload[6:])


# --------------------------------------------------------------------------- status & arming

_STATUS_HEAD = struct.Struct("<HHHIBH")  # 13 bytes


@dataclass(frozen=True, kw_only=True)
class Status:
    """STATUS (101). ``mode_flags`` bit 0 is ARMED. ``arming_disable_flags`` is None when the
    firmware does not send them (older firmware, INAV's legacy STATUS)."""

    CMD: ClassVar[int] = MspCommand.STATUS
    cycle_time_us: int = 0
    i2c_errors: int = 0
    sensors: int = 0
    mode_flags: int = 0
    pid_profile: int = 0
    cpu_load: int = 0
    profile_word: int = 0  # STATUS: gyro cycle time; STATUS_EX: u8 profile count, u8 rate profile
    extra_mode_flags: bytes = b""
    arming_disable_count: int | None = None
    arming_disable_flags: int | None = None
    tail: bytes = b""

    @property
    def armed(self) -> bool:
        return bool(self.mode_flags & 1)

    @property
    def arming_disabled_by_msp(self) -> bool | None:
        if self.arming_disable_flags is None:
            return None
        return bool(self.arming_disable_flags & ArmingDisable.MSP)

    def encode(self) -> bytes:
        out = _STATUS_HEAD.pack(
            self.cycle_time_us,
            self.i2c_errors,
            self.sensors,
            self.mode_flags,
            self.pid_profile,
            self.cpu_load,
        ) + struct.pack("<H", self.profile_word)
        if self.arming_disable_flags is None:
            return out
        count = 26 if self.arming_disable_count is None else self.arming_disable_count
        return (
            out
            + bytes((len(self.extra_mode_flags),))
            + self.extra_mode_flags
            + struct.pack("<BI", count, self.arming_disable_flags)
            + self.tail
        )

    @classmethod
    def decode(cls, payload: bytes) -> Status:
        _need(payload, 15, cls.__name__.upper())
        head = _STATUS_HEAD.unpack_from(payload, 0)
        (word,) = struct.unpack_from("<H", payload, 13)
        extra, count, flags, tail = b"", None, None, b""
        if len(payload) > 15:
            nbytes = payload[15]  # count of extra mode-flag bytes (0..15)
            arm_at = 16 + nbytes
            if nbytes > 15 or len(payload) < arm_at + 5:
                raise MspPayloadError(f"{cls.__name__.upper()}: malformed tail after 15 bytes")
            extra = payload[16:arm_at]
            count, flags = struct.unpack_from("<BI", payload, arm_at)
            tail = payload[arm_at + 5 :]
        return cls(
            cycle_time_us=head[0],
            i2c_errors=head[1],
            sensors=head[2],
            mode_flags=head[3],
            pid_profile=head[4],
            cpu_load=head[5],
            profile_word=word,
            extra_mode_flags=extra,
            arming_disable_count=count,
            arming_disable_flags=flags,
            tail=tail,
        )


@dataclass(frozen=True, kw_only=True)
class StatusEx(Status):
    CMD: ClassVar[int] = MspCommand.STATUS_EX


@dataclass(frozen=True)
class SetArmingDisabled:
    """Request: ``disable`` True blocks arming (and disarms); optional runaway-takeoff byte."""

    CMD: ClassVar[int] = MspCommand.SET_ARMING_DISABLED
    disable: bool
    disable_runaway_takeoff: bool | None = None

    def encode(self) -> bytes:
        out = bytes((int(self.disable),))
        if self.disable_runaway_takeoff is not None:
            out += bytes((int(self.disable_runaway_takeoff),))
        return out

    @classmethod
    def decode(cls, payload: bytes) -> SetArmingDisabled:
        _need(payload, 1, "SET_ARMING_DISABLED")
        runaway = bool(payload[1]) if len(payload) > 1 else None
        return cls(bool(payload[0]), runaway)


# --------------------------------------------------------------------------- battery


@dataclass(frozen=True)
class Analog:
    """ANALOG (110). ``voltage_v`` is the 0.01 V field (the 0.1 V byte when absent)."""

    CMD: ClassVar[int] = MspCommand.ANALOG
    voltage_v: float
    current_a: float
    consumed_mah: int = 0
    rssi: int = 0
    voltage_coarse_v: float | None = None  # the legacy u8 0.1 V field; None = derived

    def encode(self) -> bytes:
        coarse = self.voltage_v if self.voltage_coarse_v is None else self.voltage_coarse_v
        return struct.pack(
            "<BHHhH",
            min(_q(coarse, 0.1), 255),
            self.consumed_mah,
            self.rssi,
            _q(self.current_a, 0.01),
            _q(self.voltage_v, 0.01),
        )

    @classmethod
    def decode(cls, payload: bytes) -> Analog:
        _need(payload, 7, "ANALOG")
        vbat, mah, rssi, amps = struct.unpack_from("<BHHh", payload)
        if len(payload) >= 9:
            (volts,) = struct.unpack_from("<H", payload, 7)
            return cls(volts / 100, amps / 100, mah, rssi, vbat / 10)
        return cls(vbat / 10, amps / 100, mah, rssi, vbat / 10)


class BatteryStateCode(enum.IntEnum):
    OK = 0
    WARNING = 1
    CRITICAL = 2
    NOT_PRESENT = 3
    INIT = 4


_BATTERY_STATE = struct.Struct("<BHBHhBH")  # 11 bytes


@dataclass(frozen=True)
class BatteryState:
    """BATTERY_STATE (130): all 11 bytes, including the u8 0.1 V byte some clients skip."""

    CMD: ClassVar[int] = MspCommand.BATTERY_STATE
    cell_count: int
    capacity_mah: int
    voltage_v: float  # the 0.01 V field
    current_a: float
    consumed_mah: int = 0
    state: int = BatteryStateCode.OK
    voltage_coarse_v: float | None = None  # the u8 0.1 V field; None = derived

    def encode(self) -> bytes:
        coarse = self.voltage_v if self.voltage_coarse_v is None else self.voltage_coarse_v
        return _BATTERY_STATE.pack(
            self.cell_count,
            self.capacity_mah,
            min(_q(coarse, 0.1), 255),
            self.consumed_mah,
            _q(self.current_a, 0.01),
            self.state,
            _q(self.voltage_v, 0.01),
        )

    @classmethod
    def decode(cls, payload: bytes) -> BatteryState:
        _need(payload, _BATTERY_STATE.size, "BATTERY_STATE")
        cells, cap, vbat, mah, amps, state, volts = _BATTERY_STATE.unpack_from(payload)
        return cls(cells, cap, volts / 100, amps / 100, mah, state, vbat / 10)


_BATTERY_CONFIG = struct.Struct("<BBBHBBHHH")  # 13 bytes


@dataclass(frozen=True)
class BatteryConfig:
    CMD: ClassVar[int] = MspCommand.BATTERY_CONFIG
    min_cell_v: float
    max_cell_v: float
    warning_cell_v: float
    capacity_mah: int = 0
    voltage_source: int = 1
    current_source: int = 1

    def encode(self) -> bytes:
        return _BATTERY_CONFIG.pack(
            min(_q(self.min_cell_v, 0.1), 255),
            min(_q(self.max_cell_v, 0.1), 255),
            min(_q(self.warning_cell_v, 0.1), 255),
            self.capacity_mah,
            self.voltage_source,
            self.current_source,
            _q(self.min_cell_v, 0.01),
            _q(self.max_cell_v, 0.01),
            _q(self.warning_cell_v, 0.01),
        )

    @classmethod
    def decode(cls, payload: bytes) -> BatteryConfig:
        _need(payload, 7, "BATTERY_CONFIG")
        vmin, vmax, vwarn, cap, vsrc, isrc = struct.unpack_from("<BBBHBB", payload)
        if len(payload) >= _BATTERY_CONFIG.size:
            pmin, pmax, pwarn = struct.unpack_from("<HHH", payload, 7)
            return cls(pmin / 100, pmax / 100, pwarn / 100, cap, vsrc, isrc)
        return cls(vmin / 10, vmax / 10, vwarn / 10, cap, vsrc, isrc)


_INAV_ANALOG = struct.Struct("<BHHIIIIBH")  # 24 bytes


@dataclass(frozen=True)
class InavAnalog:
    """MSP2_INAV_ANALOG (0x2002, v2 only)."""

    CMD: ClassVar[int] = MspCommand.INAV_ANALOG
    voltage_v: float
    current_a: float
    power_w: float = 0.0
    consumed_mah: int = 0
    consumed_mwh: int = 0
    remaining_capacity: int = 0
    percentage: int = 0
    rssi: int = 0
    flags: int = 0

    def encode(self) -> bytes:
        return _INAV_ANALOG.pack(
            self.flags,
            _q(self.voltage_v, 0.01),
            _q(self.current_a, 0.01),
            _q(self.power_w, 0.01),
            self.consumed_mah,
            self.consumed_mwh,
            self.remaining_capacity,
            self.percentage,
            self.rssi,
        )

    @classmethod
    def decode(cls, payload: bytes) -> InavAnalog:
        _need(payload, _INAV_ANALOG.size, "MSP2_INAV_ANALOG")
        f, v, a, p, mah, mwh, rem, pct, rssi = _INAV_ANALOG.unpack_from(payload)
        return cls(v / 100, a / 100, p / 100, mah, mwh, rem, pct, rssi, f)


# --------------------------------------------------------------------------- registry

MspMessage = (
    ApiVersion
    | FcVariant
    | FcVersion
    | BoardInfo
    | Status
    | SetArmingDisabled
    | Motor
    | SetMotor
    | MotorConfig
    | MotorTelemetry
    | AdvancedConfig
    | Analog
    | BatteryState
    | BatteryConfig
    | InavAnalog
)

#: Command id -> record of the reply payload (host side decodes these).
REPLY_TYPES: dict[int, type[MspMessage]] = {
    t.CMD: t
    for t in (
        ApiVersion,
        FcVariant,
        FcVersion,
        BoardInfo,
        Status,
        StatusEx,
        Motor,
        MotorConfig,
        MotorTelemetry,
        AdvancedConfig,
        Analog,
        BatteryState,
        BatteryConfig,
        InavAnalog,
    )
}
#: Command id -> record of the request payload (FC side decodes these).
REQUEST_TYPES: dict[int, type[MspMessage]] = {t.CMD: t for t in (SetArmingDisabled, SetMotor)}


def decode_reply(frame: MspFrame) -> MspMessage:
    """Decode a reply frame's payload into its record. ``!`` frames and unknown commands raise
    :class:`MspPayloadError` (an ``!`` means the FC refused or does not know the command)."""
    if frame.is_error:
        raise MspPayloadError(f"FC answered '!' to cmd {frame.cmd}", cmd=frame.cmd)
    kind = REPLY_TYPES.get(frame.cmd)
    if kind is None:
        raise MspPayloadError(f"no reply record for cmd {frame.cmd}", cmd=frame.cmd)
    return kind.decode(frame.payload)


def decode_request(frame: MspFrame) -> MspMessage | None:
    """Decode a request payload; None for commands whose request has no payload."""
    kind = REQUEST_TYPES.get(frame.cmd)
    return None if kind is None else kind.decode(frame.payload)


__all__ = [
    "Analog",
    "ApiVersion",
    "ArmingDisable",
    "BatteryConfig",
    "BatteryState",
    "BatteryStateCode",
    "BoardInfo",
    "FcVariant",
    "FcVersion",
    "InavAnalog",
    "MspMessage",
    "REPLY_TYPES",
    "REQUEST_TYPES",
    "SetArmingDisabled",
    "Status",
    "StatusEx",
    "decode_reply",
    "decode_request",
]
