"""MAVLink messages that pymavlink's bundled dialects lack, added to its v2.0 dialect.

pymavlink 2.4.x ships a common.xml without ESC_STATUS (291), which PX4 sends for ESC telemetry.
The class below follows pymavlink's generated message classes exactly (same attributes, packed
by pymavlink's own ``MAVLink_message._pack``), so framing, CRC and MAVLink 2 payload truncation
stay pymavlink's. ``crc_extra`` 10 is what pymavlink's generator (``mavparse``) computes from
the common.xml definition; ``tests/test_protocols_mavlink.py`` checks it against ``mavparse``.
Registration is idempotent and never replaces a definition pymavlink already has.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

MAVLINK_MSG_ID_ESC_STATUS = 291

ESC_STATUS_XML = """\
<message id="291" name="ESC_STATUS">
  <field type="uint8_t" name="index">Index of the first ESC in this message.</field>
  <field type="uint64_t" name="time_usec" units="us">Timestamp.</field>
  <field type="int32_t[4]" name="rpm" units="rpm">Reported motor RPM from each ESC.</field>
  <field type="float[4]" name="voltage" units="V">Voltage measured from each ESC.</field>
  <field type="float[4]" name="current" units="A">Current measured from each ESC.</field>
</message>
"""


class MAVLink_esc_status_message(mavlink2.MAVLink_message):  # type: ignore[misc]  # noqa: N801
    """ESC_STATUS (291): rpm[4] int32, voltage[4] V, current[4] A for ESCs index..index+3."""

    id = MAVLINK_MSG_ID_ESC_STATUS
    msgname = "ESC_STATUS"
    fieldnames = ["index", "time_usec", "rpm", "voltage", "current"]
    ordered_fieldnames = ["time_usec", "rpm", "voltage", "current", "index"]
    fieldtypes = ["uint8_t", "uint64_t", "int32_t", "float", "float"]
    fielddisplays_by_name: dict[str, str] = {}
    fieldenums_by_name: dict[str, str] = {}
    fieldunits_by_name: dict[str, str] = {
        "time_usec": "us",
        "rpm": "rpm",
        "voltage": "V",
        "current": "A",
    }
    native_format = bytearray(b"<QifffB")
    orders = [4, 0, 1, 2, 3]
    lengths = [1, 4, 4, 4, 1]
    array_lengths = [0, 4, 4, 4, 0]
    crc_extra = 10
    unpacker = struct.Struct("<Q4i4f4fB")
    instance_field = "index"
    instance_offset = 56

    def __init__(
        self,
        index: int,
        time_usec: int,
        rpm: Sequence[int],
        voltage: Sequence[float],
        current: Sequence[float],
    ) -> None:
        mavlink2.MAVLink_message.__init__(self, self.id, self.msgname)
        self._fieldnames = self.fieldnames
        self._instance_field = self.instance_field
        self._instance_offset = self.instance_offset
        self.index = index
        self.time_usec = time_usec
        self.rpm = rpm
        self.voltage = voltage
        self.current = current

    def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes:
        payload = self.unpacker.pack(
            self.time_usec, *self.rpm[:4], *self.voltage[:4], *self.current[:4], self.index
        )
        packed: bytes = self._pack(mav, self.crc_extra, payload, force_mavlink1=force_mavlink1)
        return packed


def register_extensions() -> None:
    """Teach pymavlink's v2.0 dialect the messages above (only where it lacks them)."""
    if MAVLINK_MSG_ID_ESC_STATUS not in mavlink2.mavlink_map:
        mavlink2.mavlink_map[MAVLINK_MSG_ID_ESC_STATUS] = MAVLink_esc_status_message
        mavlink2.MAVLINK_MSG_ID_ESC_STATUS = MAVLINK_MSG_ID_ESC_STATUS
        mavlink2.MAVLink_esc_status_message = MAVLink_esc_status_message


register_extensions()
