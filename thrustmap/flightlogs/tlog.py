"""MAVLink telemetry logs (.tlog: 8-byte big-endian µs timestamp + MAVLink frame), via pymavlink.

The messages go through ``telemetry.Telemetry``, the same code ``thrustmap gamma live`` feeds a
live stream to, so a recording and the live run give the same FlightLog.

Fields (flight-logs.md): SYS_STATUS.voltage_battery (mV), HEARTBEAT.base_mode & 128 (armed),
EXTENDED_SYS_STATE.landed_state (1 = on the ground; in air, taking off and landing are airborne),
SERVO_OUTPUT_RAW.servoN_raw (µs), HIGHRES_IMU.zacc (m/s², FRD) or SCALED_IMU.zacc (mG),
ATTITUDE_TARGET.thrust (0..1), ATTITUDE roll/pitch (tilt). Telemetry rates are low (a few Hz).
Only messages from the vehicle are used (the first system whose HEARTBEAT is not a GCS).
"""

from __future__ import annotations

import logging
import struct
from pathlib import Path
from typing import Any

from thrustmap.core.errors import DataFormatError
from thrustmap.flightlogs.series import FlightLog
from thrustmap.flightlogs.telemetry import Telemetry

log = logging.getLogger(__name__)

#: plausible tlog timestamps: 2005-01-01 .. 2100-01-01 in µs
_T_MIN_US, _T_MAX_US = 1_104_537_600_000_000, 4_102_444_800_000_000


def _record_end(head: bytes, pos: int) -> int | None:
    """End of the tlog record (8-byte timestamp + MAVLink frame) starting at ``pos``, or None
    when there is no plausible record there."""
    if pos + 10 > len(head):
        return None
    (t_us,) = struct.unpack_from(">Q", head, pos)
    magic, length = head[pos + 8], head[pos + 9]
    if not _T_MIN_US <= t_us <= _T_MAX_US:
        return None
    if magic == 0xFE:
        return pos + 8 + length + 8
    if magic == 0xFD and pos + 11 <= len(head):
        signed = head[pos + 10] & 0x01
        return pos + 8 + length + 12 + (13 if signed else 0)
    return None


#: consecutive records that must chain for a tlog to be recognised
_CHAIN = 3


def sniff(path: Path, head: bytes) -> bool:
    """A tlog is a chain of (timestamp, frame) records; it may start mid-record (a recording
    joined late, or cut), so look for a chain of valid records anywhere in the head."""
    for start in range(min(len(head), 512)):
        pos, ok = start, 0
        while ok < _CHAIN:
            end = _record_end(head, pos)
            if end is None or end > len(head):
                break
            pos, ok = end, ok + 1
        if ok >= _CHAIN or (ok and pos == len(head) and start == 0):
            return True
    return False


def read(path: Path, **_: Any) -> list[FlightLog]:
    """The whole file through ``Telemetry`` (the code ``gamma live`` feeds a stream with)."""
    from pymavlink import mavutil

    if path.stat().st_size == 0:
        raise DataFormatError("telemetry log is empty (0 bytes)", file=str(path))
    try:
        mlog = mavutil.mavlink_connection(str(path), robust_parsing=True)
    except Exception as exc:
        raise DataFormatError(
            f"cannot open telemetry log ({type(exc).__name__}: {exc})", file=str(path)
        ) from None
    telemetry = Telemetry(str(path), "tlog")
    try:
        while True:
            try:
                m = mlog.recv_match(blocking=False)
            except Exception as exc:  # pymavlink raises assorted errors on garbage
                if telemetry.messages == 0:
                    raise DataFormatError(
                        f"not a readable telemetry log ({type(exc).__name__}: {exc})",
                        file=str(path),
                    ) from None
                telemetry.add_bad_data(1)
                break
            if m is None:
                break
            telemetry.add(m, float(m._timestamp))
    finally:
        mlog.close()
    if telemetry.messages == 0:
        raise DataFormatError(
            f"no MAVLink messages decoded ({telemetry.bad_bytes} bytes of bad data)",
            file=str(path),
        )
    if telemetry.vehicle is None:
        raise DataFormatError("no vehicle HEARTBEAT in the telemetry log", file=str(path))
    return [telemetry.flight_log()]
