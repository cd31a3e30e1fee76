"""Serial ports described from their USB IDs and strings, without opening them
(``thrustmap ports``). The table maps vendors' published USB IDs to the driver kinds worth
trying on such a port, most likely first; ``--probe`` then asks ``rig.devices.detect``."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Protocol

from thrustmap.rig.devices.registry import kinds as all_kinds


class PortInfo(Protocol):
    """The part of ``serial.tools.list_ports_common.ListPortInfo`` used here."""

    device: str
    description: str
    hwid: str
    vid: int | None
    pid: int | None
    serial_number: str | None
    manufacturer: str | None
    product: str | None


@dataclass(frozen=True)
class PortDescription:
    device: str
    description: str
    vid: int | None
    pid: int | None
    manufacturer: str
    product: str
    serial_number: str
    guess: str
    kinds: tuple[str, ...] = ()  # device kinds worth trying, most likely first
    probe_safe: bool = True  # False for bootloaders (DFU): opening them is pointless

    @property
    def usb_id(self) -> str:
        if self.vid is None or self.pid is None:
            return ""
        return f"{self.vid:04X}:{self.pid:04X}"

    def to_dict(self) -> dict[str, object]:
        return {
            "device": self.device,
            "description": self.description,
            "usb_id": self.usb_id,
            "manufacturer": self.manufacturer,
            "product": self.product,
            "serial_number": self.serial_number,
            "guess": self.guess,
            "kinds": list(self.kinds),
        }


#: (vid, pid or None for any) -> (guess, likely kinds). From the vendors' published USB IDs.
USB_IDS: dict[tuple[int, int | None], tuple[str, tuple[str, ...]]] = {
    (0x0483, 0x5740): (
        "STM32 virtual COM port: a flight controller (Betaflight/INAV; some ArduPilot/PX4 boards)",
        ("msp", "mavlink"),
    ),
    (0x0483, 0xDF11): ("STM32 in DFU bootloader mode (flashing, not a serial link)", ()),
    (0x2E3C, 0x5740): (
        "Artery AT32 virtual COM port: likely a Betaflight/INAV flight controller",
        ("msp",),
    ),
    (0x1209, 0x5740): ("ArduPilot ChibiOS board (e.g. Matek, CubeOrange)", ("mavlink",)),
    (0x1209, 0x5741): ("ArduPilot ChibiOS board, bootloader", ()),
    (0x26AC, None): ("PX4 FMU / 3DR Pixhawk (PX4 or ArduPilot)", ("mavlink",)),
    (0x2DAE, None): ("Hex/CubePilot Cube (ArduPilot or PX4)", ("mavlink",)),
    (0x3162, None): ("Holybro Pixhawk (PX4 or ArduPilot)", ("mavlink",)),
    (0x10C4, 0xEA60): (
        "CP210x USB-UART bridge: ESP32/DIY stand, FC UART or telemetry radio",
        ("line-stand", "mavlink", "msp"),
    ),
    (0x1A86, 0x7523): (
        "CH340 USB-UART bridge: Arduino-type board, a DIY line stand or a Tyto-like stand",
        ("line-stand", "tyto-1585"),
    ),
    (0x1A86, 0x55D4): ("CH9102 USB-UART bridge: ESP32 DIY stand", ("line-stand",)),
    (0x0403, 0x6001): (
        "FTDI FT232R USB-UART: Arduino-type stand, FC UART or telemetry radio",
        ("line-stand", "tyto-1585", "mavlink"),
    ),
    (0x0403, 0x6015): (
        "FTDI FT-X USB-UART: SiK telemetry radio (MAVLink) or a DIY stand",
        ("mavlink", "line-stand"),
    ),
    (0x0403, 0x6014): ("FTDI FT232H USB-UART", ("line-stand",)),
    (0x0403, 0x6010): ("FTDI FT2232 USB-UART", ("line-stand",)),
    (0x2341, None): ("Arduino board: a DIY line stand or a Tyto-like stand", ("line-stand",)),
    (0x2A03, None): ("Arduino board: a DIY line stand", ("line-stand",)),
    (0x2E8A, None): (
        "Raspberry Pi RP2040/RP2350: a DIY line stand (e.g. the einsz whoop stand, einsz-whoop)",
        ("line-stand",),
    ),
    (0x1CBE, 0x00FD): (
        "TI Stellaris/Tiva C LaunchPad ICDI: a DIY line stand (e.g. the MQTB stand, "
        "mqtb-teststand)",
        ("line-stand",),
    ),
    (0x16C0, 0x0483): ("Teensy USB serial: a DIY line stand", ("line-stand",)),
    (0x303A, None): ("Espressif ESP32-S2/S3/C3 USB serial: a DIY line stand", ("line-stand",)),
    (0x239A, None): ("Adafruit board: a DIY line stand", ("line-stand",)),
}
#: words in the USB strings -> (guess, kinds); checked before the ID table
KEYWORDS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("betaflight", "Betaflight flight controller", ("msp",)),
    ("inav", "INAV flight controller", ("msp",)),
    ("ardupilot", "ArduPilot flight controller", ("mavlink",)),
    ("px4", "PX4 flight controller", ("mavlink",)),
    ("pixhawk", "Pixhawk flight controller (PX4 or ArduPilot)", ("mavlink",)),
    ("cube", "Cube flight controller (ArduPilot or PX4)", ("mavlink",)),
    ("rcbenchmark", "RCbenchmark / Tyto thrust stand", ("tyto-1585",)),
    ("tyto", "Tyto Robotics thrust stand", ("tyto-1585",)),
)


def describe_port(info: PortInfo) -> PortDescription:
    """A guess at what a serial port is, from its USB IDs and strings (the port is not opened)."""
    manufacturer = info.manufacturer or ""
    product = info.product or ""
    description = info.description or ""
    words = f"{manufacturer} {product} {description}".lower()
    guess = ""
    kinds: tuple[str, ...] = ()
    probe_safe = True
    for word, what, what_kinds in KEYWORDS:
        if re.search(rf"\b{re.escape(word)}", words):
            guess, kinds = what, what_kinds
            break
    if info.vid is not None:
        entry = USB_IDS.get((info.vid, info.pid)) if info.pid is not None else None
        if entry is None:
            entry = USB_IDS.get((info.vid, None))
        if entry is not None:
            if not entry[1] and ("bootloader" in entry[0] or "DFU" in entry[0]):
                probe_safe = False
            if not guess:
                guess, kinds = entry
            elif entry[0] not in guess:
                guess = f"{guess} ({entry[0].split(':')[0]})"
        elif not guess:
            guess = "unknown USB serial device"
            kinds = all_kinds()
    elif not guess:
        guess = "built-in or virtual serial port (no USB IDs)"
    return PortDescription(
        device=info.device,
        description=description,
        vid=info.vid,
        pid=info.pid,
        manufacturer=manufacturer,
        product=product,
        serial_number=info.serial_number or "",
        guess=guess,
        kinds=kinds,
        probe_safe=probe_safe,
    )


def list_ports() -> list[PortDescription]:
    """Every serial port pyserial sees, described (none is opened)."""
    from serial.tools import list_ports as lp

    return [describe_port(p) for p in sorted(lp.comports(), key=lambda p: p.device)]
