"""MAVLink parameter values: the two wire encodings, and which one a vehicle uses.

PARAM_VALUE / PARAM_SET carry every parameter in a 4-byte ``float`` field plus a
``param_type`` (MAV_PARAM_TYPE). Integers travel in one of two ways, and a vehicle says which in
AUTOPILOT_VERSION.capabilities:

- BYTEWISE (``MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE``, bit 16; PX4): the integer's own
  little-endian bytes sit in the float field. ``COM_MOT_TEST_EN=1`` (INT32) arrives as the bytes
  ``01 00 00 00``; read as a float that is 1.4e-45, which is why a float-only reader sees 0.
- C_CAST (``MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST``, bit 131072, or neither bit;
  ArduPilot): the integer converted to a float value (``MOT_PWM_MIN=1000`` is 1000.0).

Without AUTOPILOT_VERSION the encoding follows the autopilot's known practice (PX4 bytewise,
everything else C cast). Functions only, no I/O.
"""

from __future__ import annotations

import math
import struct
from enum import Enum, IntEnum

from thrustmap.core.errors import DataFormatError

MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE = 16
MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST = 131072
MAV_AUTOPILOT_PX4 = 12


class ParamType(IntEnum):
    """MAV_PARAM_TYPE."""

    UINT8 = 1
    INT8 = 2
    UINT16 = 3
    INT16 = 4
    UINT32 = 5
    INT32 = 6
    UINT64 = 7
    INT64 = 8
    REAL32 = 9
    REAL64 = 10


class ParamEncoding(Enum):
    BYTEWISE = "bytewise"
    C_CAST = "c_cast"


#: struct format and byte count of each integer type inside the 4-byte field
_INT_FORMATS: dict[int, tuple[str, int]] = {
    ParamType.UINT8: ("<B", 1),
    ParamType.INT8: ("<b", 1),
    ParamType.UINT16: ("<H", 2),
    ParamType.INT16: ("<h", 2),
    ParamType.UINT32: ("<I", 4),
    ParamType.INT32: ("<i", 4),
}


def encoding_from_capabilities(capabilities: int | None, autopilot: int) -> ParamEncoding:
    """The encoding a vehicle uses: its capability bits, else its autopilot's practice."""
    if capabilities is not None:
        if capabilities & MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE:
            return ParamEncoding.BYTEWISE
        return ParamEncoding.C_CAST
    return ParamEncoding.BYTEWISE if autopilot == MAV_AUTOPILOT_PX4 else ParamEncoding.C_CAST


def is_integer_type(param_type: int) -> bool:
    return param_type in _INT_FORMATS or param_type in (ParamType.UINT64, ParamType.INT64)


def float_field_bytes(value: float) -> bytes:
    """The 4 bytes of a float field as they were on the wire (little-endian)."""
    return struct.pack("<f", value)


def decode_param(raw4: bytes, param_type: int, encoding: ParamEncoding) -> float:
    """The parameter's number from the 4 wire bytes of its value field.

    REAL32 (and unknown types, which a reader cannot do better for) are the float itself.
    Integers: bytewise -> the bytes as that integer type; C cast -> the float's value, which
    must then be a whole number. 64-bit types cannot fit in 4 bytes: refused.
    """
    if len(raw4) != 4:
        raise DataFormatError(f"a MAVLink parameter value is 4 bytes, got {len(raw4)}")
    (as_float,) = struct.unpack("<f", raw4)
    if param_type in (ParamType.UINT64, ParamType.INT64, ParamType.REAL64):
        raise DataFormatError(
            f"parameter type {ParamType(param_type).name} does not fit a PARAM_VALUE float field"
        )
    if param_type not in _INT_FORMATS:
        return float(as_float)
    if encoding is ParamEncoding.BYTEWISE:
        fmt, size = _INT_FORMATS[param_type]
        (number,) = struct.unpack(fmt, raw4[:size])
        return float(number)
    if not math.isfinite(as_float) or as_float != math.floor(as_float):
        raise DataFormatError(
            f"integer parameter (type {ParamType(param_type).name}) arrived as {as_float!r}, "
            "which is not a whole number: the vehicle's parameter encoding is not C cast"
        )
    return float(as_float)


def encode_param(value: float, param_type: int, encoding: ParamEncoding) -> bytes:
    """The 4 wire bytes for ``value`` of ``param_type`` (the inverse of ``decode_param``)."""
    if param_type in _INT_FORMATS and encoding is ParamEncoding.BYTEWISE:
        fmt, size = _INT_FORMATS[param_type]
        return struct.pack(fmt, int(value)).ljust(4, b"\x00")
    return struct.pack("<f", float(value))


def encode_param_float(value: float, param_type: int, encoding: ParamEncoding) -> float:
    """``encode_param`` as the Python float pymavlink packs into the field."""
    (as_float,) = struct.unpack("<f", encode_param(value, param_type, encoding))
    return float(as_float)
