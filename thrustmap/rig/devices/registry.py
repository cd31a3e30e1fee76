"""The driver registry: every kind of device thrustmap can open, declared once each.

A ``Driver`` says what it is (``kind``, ``aliases``, ``role``), how to recognise it without
writing to it (the ``sim://`` peer names it answers to, what it sends unasked, what a host
writes to it first), and how to open it (``open_output`` for flight controllers; ``open_stand``
and ``esc_output`` for stands). Detection (``rig.devices.detect``), ``thrustmap ports --probe``
and ``thrustmap probe`` iterate ``drivers()``; ``rig.devices.opening`` opens through ``driver(kind)``.

The built-in drivers (``rig.devices.builtin``) are imported on first use, so importing the
registry costs nothing and a driver's heavy dependencies (pymavlink) load only when it opens.
"""

from __future__ import annotations

from thrustmap.core.errors import ConfigError
from thrustmap.rig.devices.declaration import Driver

__all__ = [
    "driver",
    "drivers",
    "kind_aliases",
    "kinds",
    "normalize_kind",
    "register",
    "unregister",
]


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
