"""Put a simulated MAVLink vehicle on a loopback UDP socket, through pymavlink's own ``udpout``.

For integration tests and ad-hoc checks of code that uses stock ``mavutil.mavlink_connection``
(e.g. ``udpin:127.0.0.1:14550``): the vehicle sends first (its heartbeat), like a real vehicle
or SITL. Single-threaded and bounded: nothing happens between ``pump()`` calls, and ``pump``
never blocks. Only loopback addresses are accepted, so a simulator can never talk to a real
network (or a real vehicle) by mistake.
"""

from __future__ import annotations

import logging
from typing import Any

from pymavlink import mavutil

from thrustmap.core.clock import Clock
from thrustmap.core.errors import ConfigError
from thrustmap.rig.sim.mavlink_vehicle import SimMavlinkVehicle

log = logging.getLogger(__name__)

LOOPBACK_HOSTS = ("127.0.0.1", "localhost")
MAX_DATAGRAMS_PER_PUMP = 1000


class UdpVehicleLink:
    """One vehicle behind ``udpout:127.0.0.1:<port>`` (the host listens with ``udpin``)."""

    def __init__(
        self, vehicle: SimMavlinkVehicle, port: int, clock: Clock, *, host: str = "127.0.0.1"
    ):
        if host not in LOOPBACK_HOSTS:
            raise ConfigError(
                f"the simulated vehicle only talks to loopback ({', '.join(LOOPBACK_HOSTS)}), not {host!r}"
            )
        if not 0 < port < 65536:
            raise ConfigError(f"UDP port must be 1..65535, got {port}")
        self.vehicle = vehicle
        self.clock = clock
        self._conn: Any = mavutil.mavlink_connection(
            f"udpout:{host}:{port}", source_system=vehicle.system_id
        )
        self.frames_sent = 0
        self.bytes_received = 0

    def pump(self) -> int:
        """Deliver pending host datagrams to the vehicle, send what it has; returns frames sent."""
        now_s = self.clock.now_s()
        for _ in range(MAX_DATAGRAMS_PER_PUMP):
            data = self._conn.recv()
            if not data:
                break
            self.bytes_received += len(data)
            self.vehicle.write(bytes(data), now_s)
        frames = self.vehicle.read_frames(now_s)
        for frame in frames:
            self._conn.write(frame)
        self.frames_sent += len(frames)
        return len(frames)

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> UdpVehicleLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
