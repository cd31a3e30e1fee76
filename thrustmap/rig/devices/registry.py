"""The driver registry: every kind of device thrustmap can open, declared once each.

A ``Driver`` says what it is (``kind``, ``aliases``, ``role``), how to recognise it without
writing to it (the ``sim://`` peer names it answers to, what it sends unasked, what a host
writes to it first), and how to open it (``open_output`` for flight controllers; ``open_stand``
and ``esc_output`` for stands). Detection (``rig.devices.detect``), ``thrustmap ports --probe``
and ``thrustmap probe`` iterate ``drivers()``; ``rig.connect`` opens through ``driver(kind)``.

The built-in drivers (``rig.devices.builtin``) are imported on first use, so importing the
registry costs nothing and a driver's heavy dependencies (pymavlink) load only when it opens.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from thrustmap.core.errors import ConfigError

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


_DRIVERS: dict[str, Driver] = {}
_loaded = False


def _load_builtin() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        from thrustmap.rig.devices.builtin import BUILTIN

        for drv in BUILTIN:
            _DRIVERS.setdefault(drv.kind, drv)


def register(drv: Driver, *, replace: bool = False) -> None:
    """Add a driver (an out-of-tree stand, a test double)."""
    _load_builtin()
    if drv.kind in _DRIVERS and not replace:
        raise ValueError(f"a driver for {drv.kind!r} is registered (pass replace=True)")
    _DRIVERS[drv.kind] = drv


def unregister(kind: str) -> None:
    _DRIVERS.pop(kind, None)


def drivers() -> list[Driver]:
    """Every registered driver, in detection order."""
    _load_builtin()
    return list(_DRIVERS.values())


def driver(kind: str) -> Driver:
    _load_builtin()
    try:
        return _DRIVERS[kind]
    except KeyError:
        raise ConfigError(f"no driver for device kind {kind!r}") from None


def kinds(role: str | None = None) -> tuple[str, ...]:
    return tuple(d.kind for d in drivers() if role is None or d.role == role)


def kind_aliases() -> dict[str, tuple[str, str | None]]:
    """Every name ``--kind`` accepts -> (kind, firmware hint)."""
    out: dict[str, tuple[str, str | None]] = {}
    for drv in drivers():
        for alias, firmware in drv.aliases.items():
            out[alias] = (drv.kind, firmware)
    return out


def normalize_kind(kind: str) -> tuple[str, str | None]:
    """``"betaflight"`` -> ``("msp", "betaflight")``; unknown kinds raise ``ConfigError``."""
    aliases = kind_aliases()
    try:
        return aliases[kind.strip().lower()]
    except KeyError:
        raise ConfigError(
            f"unknown device kind '{kind}'; expected one of: {', '.join(aliases)}"
        ) from None
