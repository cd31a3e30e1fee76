"""PX4 and ArduPilot flight controllers over MAVLink: pick the driver, open the link.

The pieces live beside this module:
- ``rig.fc.mavlink_session``: one MAVLink conversation (receive loop, command/ACK, parameters);
- ``rig.fc.mavlink_output``: the throttle-output logic both autopilots share;
- ``rig.fc.px4`` (``Px4ThrottleOutput``) and ``rig.fc.ardupilot`` (``ArduPilotThrottleOutput``).

``open_mavlink_output(url_or_link, clock)`` waits for a HEARTBEAT and picks the driver from its
autopilot field (3 ArduPilot, 12 PX4). For the device registry: ``KINDS`` (the kinds this
module opens), ``detect(url_or_link, clock)`` (which of them answers, or None) and
``open_output(url_or_link, clock, **options)``.
"""

from __future__ import annotations

from typing import Any

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink.link import open_mavlink
from thrustmap.protocols.mavlink.signing import SigningKey, enable_signing
from thrustmap.rig.devices.urls import load_sim_peers, sim_peer
from thrustmap.rig.fc.ardupilot import ArduPilotThrottleOutput
from thrustmap.rig.fc.mavlink_output import MavlinkThrottleOutput
from thrustmap.rig.fc.mavlink_session import (
    MavlinkLinkLost,
    UnsupportedAutopilot,
    wait_for_vehicle_heartbeat,
)
from thrustmap.rig.fc.px4 import Px4ThrottleOutput

__all__ = [
    "AUTOPILOT_NAMES",
    "DRIVERS",
    "KINDS",
    "detect",
    "open_mavlink_output",
    "open_output",
]

DRIVERS: dict[int, type[MavlinkThrottleOutput]] = {
    mav.Autopilot.PX4: Px4ThrottleOutput,
    mav.Autopilot.ARDUPILOT: ArduPilotThrottleOutput,
}
AUTOPILOT_NAMES = {"px4": mav.Autopilot.PX4, "ardupilot": mav.Autopilot.ARDUPILOT}
KINDS = tuple(AUTOPILOT_NAMES)


def _autopilot_id(autopilot: str | int) -> int:
    if isinstance(autopilot, str):
        key = autopilot.strip().lower()
        if key not in AUTOPILOT_NAMES:
            raise ConfigError(
                f"unknown autopilot {autopilot!r}; expected one of: {', '.join(AUTOPILOT_NAMES)}"
            )
        return int(AUTOPILOT_NAMES[key])
    return int(autopilot)


def _link(url_or_link: str | Any, clock: Clock) -> tuple[Any, bool]:
    if isinstance(url_or_link, str):
        if sim_peer(url_or_link) is not None:
            load_sim_peers()  # sim://px4 needs the simulator's peers, whatever was imported
        return open_mavlink(url_or_link, clock=clock), True
    return url_or_link, False


def detect(url_or_link: str | Any, clock: Clock, *, timeout_s: float = 3.0) -> str | None:
    """ "px4" / "ardupilot" for the vehicle whose HEARTBEAT arrives, None if none or another.

    Listens only: sends nothing. A link this function opened is closed again.
    """
    link, opened = _link(url_or_link, clock)
    try:
        hb = wait_for_vehicle_heartbeat(link, clock, timeout_s)
    except MavlinkLinkLost:
        return None
    finally:
        if opened:
            link.close()
    for name, autopilot in AUTOPILOT_NAMES.items():
        if int(hb.autopilot) == int(autopilot):
            return name
    return None


def open_mavlink_output(
    url_or_link: str | Any,
    clock: Clock,
    *,
    autopilot: str | int | None = None,
    heartbeat_timeout_s: float = 3.0,
    signing_key: SigningKey | None = None,
    **driver_kwargs: Any,
) -> MavlinkThrottleOutput:
    """Wait for a vehicle HEARTBEAT and return the PX4 or ArduPilot driver for it.

    ``url_or_link``: a URL for ``open_mavlink`` (device path, ``sim://px4``, ``record://...``,
    ``replay://...``, ``udpin:``/``udpout:``/``tcp:``) or an open pymavlink connection.
    ``autopilot`` ("px4", "ardupilot", 12, 3) insists on one firmware: a vehicle of another kind
    is refused. ``signing_key``: sign every message and accept only validly signed ones
    (``thrustmap.protocols.mavlink.signing``). A link this function opened is closed again if
    it fails.
    """
    link, opened = _link(url_or_link, clock)
    try:
        if signing_key is not None:
            enable_signing(link, signing_key)
        hb = wait_for_vehicle_heartbeat(link, clock, heartbeat_timeout_s)
        found = int(hb.autopilot)
        if autopilot is not None and _autopilot_id(autopilot) != found:
            raise ConfigError(
                f"expected a {autopilot} vehicle, but the HEARTBEAT says autopilot {found} "
                f"({hb.firmware})"
            )
        driver = DRIVERS.get(found)
        if driver is None:
            raise UnsupportedAutopilot(
                f"HEARTBEAT autopilot {found} has no motor-test driver; supported: "
                "3 (ArduPilot), 12 (PX4)"
            )
        return driver(
            link, clock, heartbeat=hb, heartbeat_timeout_s=heartbeat_timeout_s, **driver_kwargs
        )
    except BaseException:
        if opened:
            link.close()
        raise


open_output = open_mavlink_output
