"""What a driver declares (python-can style): the ``Driver`` record, what it is given to open a
device (``OpenRequest``) and what detection concludes (``Detection``).

The lowest piece of ``rig.devices``: the built-in declarations (``builtin``) and the registry
that collects them (``registry``) both build on it, so neither imports the other's module to
name these types.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    from thrustmap.core.clock import Clock
    from thrustmap.rig.interfaces import Stand, ThrottleOutput


@dataclass(frozen=True)
class Detection:
    """What a URL or a port turned out to be."""

    kind: str  # a registered driver's kind
    firmware: str | None = None  # "betaflight", "inav", "px4", "ardupilot", ...
    line_preset: str | None = None  # for line stands, when the header matches a preset
    evidence: str = ""


@dataclass(frozen=True)
class OpenRequest:
    """Everything a driver may need to open a device at ``url``."""

    url: str
    clock: Clock
    baudrate: int | None = None
    firmware: str | None = None  # the autopilot/firmware hint (from --kind or detection)
    calibration: str | None = None  # Tyto 1585 calibration file
    line_preset: str | None = None
    line_spec_file: str | None = None
    detected_preset: str | None = None  # the line preset a header or sim URL named
    wait_s: float = 3.0  # a stand must send data within this
    opts: Mapping[str, Any] = field(default_factory=dict)  # driver constructor options


#: (the bytes seen, their complete text lines) -> a detection, or None
Classifier = Callable[[bytes, list[str]], Detection | None]


@dataclass(frozen=True)
class Driver:
    kind: str
    role: Literal["fc", "stand"]
    description: str
    default_baud: int
    #: names a user may give (``--kind``) -> the firmware hint each implies
    aliases: Mapping[str, str | None]
    #: ``sim://<name>`` peers this driver talks to -> the detection (from the URL options)
    sim_detect: Callable[[str, Mapping[str, str]], Detection | None] = lambda n, o: None
    #: recognise the device from what it sends unasked (no writes involved)
    classify: Classifier | None = None
    #: what a host writes first to this kind (to read a transcript's kind)
    host_prefixes: tuple[bytes, ...] = ()
    open_output: Callable[[OpenRequest], ThrottleOutput] | None = None
    open_stand: Callable[[OpenRequest], Stand] | None = None
    #: a stand's own ESC output (None when ``stand`` is not this driver's)
    esc_output: Callable[[Stand, int], ThrottleOutput | None] | None = None
    #: URL schemes that name this driver (``flightstand://host:port``)
    url_schemes: tuple[str, ...] = ()
    #: how its protocol was checked (``thrustmap probe`` says it)
    verified: str = ""
