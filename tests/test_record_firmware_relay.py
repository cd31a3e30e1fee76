"""The recorder's relay (tests/support/record_firmware.py) passes on the vehicle's traffic only.

The relay sits between the SITL and thrustmap (vehicle -> relay port -> thrustmap's udpin port)
so that a recording can cut the link; to thrustmap its address IS the vehicle (the locked peer).
A datagram it forwarded from anyone else would reach thrustmap as the vehicle's own traffic, and
the locked link could not see a second sender. That is what the PX4 recording of 2026-11-28
shows (fixtures/firmware/px4/README.md): every one of the second sender's heartbeats is in the
stream thrustmap accepted from its locked peer, none ever came from the sender's own address,
and PX4's own log shows it never received them. Real sockets on loopback, no SITL.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest
from support import record_firmware as rf

TIMEOUT_S = 2.0


def _udp(port: int = 0) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    sock.settimeout(TIMEOUT_S)
    return sock


@pytest.fixture
def relay(monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[rf.Relay, socket.socket]]:
    """A relay between free ports; yields it and thrustmap's side (a socket on the udpin port)."""
    thrustmap = _udp()
    probe = _udp()
    relay_port = probe.getsockname()[1]
    probe.close()
    monkeypatch.setattr(rf, "UDPIN_PORT", thrustmap.getsockname()[1])
    monkeypatch.setattr(rf, "RELAY_PORT", relay_port)
    relay = rf.Relay()
    try:
        yield relay, thrustmap
    finally:
        relay.close()
        thrustmap.close()


def test_a_second_sender_on_the_relay_port_never_reaches_thrustmap(
    relay: tuple[rf.Relay, socket.socket],
) -> None:
    relay_, thrustmap = relay
    vehicle, stranger = _udp(), _udp()
    try:
        relay_port = relay_.vehicle_side.getsockname()
        vehicle.sendto(b"vehicle 1", relay_port)
        data, sender = thrustmap.recvfrom(100)
        assert (data, sender) == (b"vehicle 1", relay_.host_side.getsockname())
        stranger.sendto(b"second sender", relay_port)  # queued before the vehicle's next
        vehicle.sendto(b"vehicle 2", relay_port)
        assert thrustmap.recvfrom(100)[0] == b"vehicle 2"
        assert relay_.strangers == {"{}:{}".format(*stranger.getsockname()): 1}
    finally:
        vehicle.close()
        stranger.close()


def test_only_thrustmap_reaches_the_vehicle(relay: tuple[rf.Relay, socket.socket]) -> None:
    relay_, thrustmap = relay
    vehicle, stranger = _udp(), _udp()
    try:
        vehicle.sendto(b"heartbeat", relay_.vehicle_side.getsockname())
        assert thrustmap.recvfrom(100)[0] == b"heartbeat"
        host_side = relay_.host_side.getsockname()
        stranger.sendto(b"not thrustmap", host_side)
        thrustmap.sendto(b"command", host_side)
        data, sender = vehicle.recvfrom(100)
        assert (data, sender) == (b"command", relay_.vehicle_side.getsockname())
        assert relay_.strangers == {"{}:{}".format(*stranger.getsockname()): 1}
    finally:
        vehicle.close()
        stranger.close()
