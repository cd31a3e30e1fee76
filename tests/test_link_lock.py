"""The locked vehicle link (issue 36, item 2): once the vehicle is identified, the link talks to
it alone. Datagrams from any other address are dropped and counted and never answered; while
a motor is commanded they stop the motor (through the locked peer) and abort the run naming
the intruder (exit 1). pymavlink's ``udpin`` "answers whoever sent last": here the transport
itself is locked, so no command can be redirected.

The vehicles are thrustmap's simulated PX4 and ArduPilot on loopback UDP (a real socket pair;
the host side is the real CLI), the intruder a second local socket sending HEARTBEATs.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from click.testing import CliRunner

from thrustmap.cli import cli
from thrustmap.core.clock import MonotonicClock
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink import encode as enc
from thrustmap.protocols.mavlink.link import open_mavlink
from thrustmap.protocols.transport import open_transport
from thrustmap.rig.fc.link_lock import LinkIntruder
from thrustmap.rig.fc.mavlink import open_mavlink_output
from thrustmap.rig.sim.mavlink_loopback import UdpVehicleLink
from thrustmap.rig.sim.mavlink_peers import ArduPilotVehicle, PX4Vehicle
from thrustmap.rig.sim.mavlink_vehicle import SimMavlinkVehicle
from thrustmap.rig.sim.plant import ConstantPlant


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def udp_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    return s


def heartbeat_bytes(system_id: int, *, autopilot: int = mav.Autopilot.PX4) -> bytes:
    """A HEARTBEAT that claims to be a vehicle (the strongest intruder: a spoof)."""
    return mav.MavlinkCodec(system_id, 1).encode(enc.heartbeat_message(autopilot, armed=False))


def drain(sock: socket.socket) -> int:
    got = 0
    while True:
        try:
            got += len(sock.recv(65535))
        except BlockingIOError:
            return got


@contextmanager
def vehicle_on_udp(vehicle: SimMavlinkVehicle, port: int) -> Iterator[UdpVehicleLink]:
    """The vehicle behind ``udpout:127.0.0.1:port``, pumped by a thread (bounded, stopped)."""
    stop = threading.Event()
    with UdpVehicleLink(vehicle, port, MonotonicClock()) as link:

        def pump() -> None:
            while not stop.is_set():
                link.pump()
                stop.wait(0.005)

        thread = threading.Thread(target=pump, daemon=True)
        thread.start()
        try:
            yield link
        finally:
            stop.set()
            thread.join(timeout=5)


class Intruder:
    """A second local socket sending a HEARTBEAT every ``period_s`` to the vehicle port once
    ``when()`` is true; counts every byte it receives."""

    def __init__(
        self,
        port: int,
        when: Callable[[], bool],
        period_s: float = 0.05,
        heartbeat: bytes | None = None,
    ) -> None:
        self.heartbeat = heartbeat_bytes(1) if heartbeat is None else heartbeat
        self.sock = udp_socket()
        self.address = self.sock.getsockname()
        self.port = port
        self.when = when
        self.period_s = period_s
        self.sent = 0
        self.received = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        deadline = time.monotonic() + 30.0
        while not self._stop.is_set() and time.monotonic() < deadline:
            self.received += drain(self.sock)
            if self.when():
                self.sock.sendto(self.heartbeat, ("127.0.0.1", self.port))
                self.sent += 1
            self._stop.wait(self.period_s)

    def __enter__(self) -> Intruder:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        time.sleep(0.05)
        self.received += drain(self.sock)
        self.sock.close()


# ------------------------------------------------------------------------------------------
# the transport
# ------------------------------------------------------------------------------------------
def test_udpin_locks_to_its_first_peer_and_never_answers_another() -> None:
    port = free_udp_port()
    port_ = open_transport(f"udpin://127.0.0.1:{port}", timeout=0.5)
    a, b = udp_socket(), udp_socket()
    try:
        a.sendto(b"from-a", ("127.0.0.1", port))
        assert port_.read(100) == b"from-a"
        b.sendto(b"from-b", ("127.0.0.1", port))
        a.sendto(b"a-again", ("127.0.0.1", port))
        time.sleep(0.05)
        assert port_.read(100) == b"a-again"  # b's datagram never reached the reader
        port_.write(b"reply")
        time.sleep(0.05)
        assert a.recv(100) == b"reply"
        assert drain(b) == 0  # pymavlink's udpin would have answered b: it sent last
        endpoint: Any = port_
        assert endpoint.foreign_datagrams == 1
        assert endpoint.last_foreign == b.getsockname()
        assert endpoint.foreign_senders == {b.getsockname(): 1}
    finally:
        port_.close()
        a.close()
        b.close()


def test_no_other_program_can_bind_the_port_thrustmap_listens_on() -> None:
    """With SO_REUSEADDR on both sockets Linux lets a second program bind the same UDP port
    and hands it the vehicle's datagrams: thrustmap's listening socket does not allow it."""
    port = free_udp_port()
    port_ = open_transport(f"udpin://127.0.0.1:{port}", timeout=0.2)
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        other.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        with pytest.raises(OSError):
            other.bind(("127.0.0.1", port))
    finally:
        other.close()
        port_.close()


def test_udpout_hears_only_its_target() -> None:
    target, other = udp_socket(), udp_socket()
    port_ = open_transport(f"udpout://localhost:{target.getsockname()[1]}", timeout=0.3)
    try:
        port_.write(b"hello")
        time.sleep(0.05)
        data, sender = target.recvfrom(100)
        assert data == b"hello"
        other.sendto(b"intruder", sender)  # the OS drops it: the socket is connected
        target.sendto(b"answer", sender)
        assert port_.read(100) == b"answer"
        assert port_.read(100) == b""
    finally:
        port_.close()
        target.close()
        other.close()


def test_the_first_vehicle_heartbeat_locks_the_link_not_a_ground_station() -> None:
    """A ground station (or anything) that speaks first locks nothing; the vehicle does."""
    port = free_udp_port()
    link = open_mavlink(f"udpin:127.0.0.1:{port}", clock=MonotonicClock())
    gcs, vehicle = udp_socket(), udp_socket()
    try:
        gcs_hb = mav.MavlinkCodec(255, 190).encode(
            enc.heartbeat_message(mav.Autopilot.INVALID, armed=False, vehicle_type=6)
        )
        gcs.sendto(gcs_hb, ("127.0.0.1", port))
        vehicle.sendto(heartbeat_bytes(1), ("127.0.0.1", port))
        msg = link.recv_match(type="HEARTBEAT", blocking=True, timeout=2.0)
        assert msg is not None and msg.get_srcSystem() == 1
        endpoint: Any = link.port
        assert endpoint.remote == vehicle.getsockname()
        assert endpoint.unidentified_datagrams == 1
        link.mav.heartbeat_send(6, 8, 0, 0, 0)
        time.sleep(0.05)
        assert drain(vehicle) > 0 and drain(gcs) == 0
    finally:
        link.close()
        gcs.close()
        vehicle.close()


def test_an_intruder_while_idle_is_counted_and_a_motor_start_refused() -> None:
    """Traffic from another address before any motor command: logged and counted; the first
    motor command is then refused (nothing is sent), naming the address."""
    port = free_udp_port()
    vehicle = PX4Vehicle(ConstantPlant())
    with vehicle_on_udp(vehicle, port):
        out = open_mavlink_output(f"udpin:127.0.0.1:{port}", MonotonicClock())
        intruder = udp_socket()
        try:
            out.identify()
            intruder.sendto(heartbeat_bytes(1), ("127.0.0.1", port))
            time.sleep(0.05)
            out.read_telemetry()  # idle: no abort, the datagram is only counted
            assert out.session.endpoint.foreign_datagrams == 1
            host, iport = intruder.getsockname()
            with pytest.raises(LinkIntruder, match=f"{host}:{iport}.*no motor command sent"):
                out.set_throttle({0: 0.1})
            assert out.stop_and_verify() is True
            time.sleep(0.05)
            assert drain(intruder) == 0
        finally:
            out.close()
            intruder.close()
    assert vehicle.running_motors() == {}
    started = [
        c
        for c in vehicle.commands_received
        if c.command == mav.MAV_CMD_ACTUATOR_TEST and c.params[0] == c.params[0]  # not NaN: stop
    ]
    assert started == []


def test_other_system_ids_through_the_vehicle_are_dropped_not_an_abort() -> None:
    """A vehicle routes other systems' messages (ArduPilot forwards a ground station's
    HEARTBEAT between its ports: MAVLink_routing.cpp handle_heartbeat): they are dropped and
    counted, and a spin goes on."""
    clock = MonotonicClock()
    port = free_udp_port()
    vehicle = PX4Vehicle(ConstantPlant())
    with vehicle_on_udp(vehicle, port) as vlink:
        out = open_mavlink_output(f"udpin:127.0.0.1:{port}", clock)
        try:
            out.identify()
            out.set_throttle({0: 0.1})
            vlink._conn.write(heartbeat_bytes(7))  # from the vehicle's own address
            time.sleep(0.05)
            out.keepalive()
            assert out.session.foreign_system_messages >= 1
            assert 7 in out.session.foreign_systems
            assert out.stop_and_verify() is True
        finally:
            out.close()
    assert vehicle.running_motors() == {}


# ------------------------------------------------------------------------------------------
# the CLI, end to end: spin on udpin with an intruder
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("firmware", ["px4", "ardupilot"])
def test_spin_aborts_naming_the_intruder_and_stops_through_the_vehicle(firmware: str) -> None:
    port = free_udp_port()
    vehicle: Any = (
        PX4Vehicle(ConstantPlant()) if firmware == "px4" else ArduPilotVehicle(ConstantPlant())
    )

    def spinning() -> bool:
        if firmware == "px4":
            return bool(vehicle.running_motors())
        return bool(vehicle.motor_test_running)

    with vehicle_on_udp(vehicle, port), Intruder(port, spinning) as intruder:
        done = CliRunner().invoke(
            cli,
            ["spin", f"udpin:127.0.0.1:{port}", "--motor", "1", "--throttle", "10"]
            + ["--seconds", "4", "--ramp", "0", "--yes"],
        )
        assert intruder.sent > 0, done.output
    host, iport = intruder.address
    assert done.exit_code == 1, done.output
    assert f"{host}:{iport} sent to the vehicle link" in done.output
    assert "stopped (verified)" in done.output
    assert intruder.received == 0  # not one byte of thrustmap's traffic
    assert not spinning()  # the vehicle's outputs are back at rest
    assert max(vehicle.outputs_us()[:4]) <= 1000


def test_spin_completes_on_a_quiet_udp_link() -> None:
    port = free_udp_port()
    vehicle = PX4Vehicle(ConstantPlant())
    with vehicle_on_udp(vehicle, port):
        done = CliRunner().invoke(
            cli,
            ["spin", f"udpin:127.0.0.1:{port}", "--motor", "1", "--throttle", "10"]
            + ["--seconds", "0.5", "--ramp", "0", "--yes"],
        )
    assert done.exit_code == 0, done.output
    assert "stopped (verified)" in done.output


# ------------------------------------------------------------------------------------------
# tcpin: the first connection is the peer; a reconnect from elsewhere is refused
# ------------------------------------------------------------------------------------------
def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def connect_when_listening(port: int) -> socket.socket:
    deadline = time.monotonic() + 10
    while True:
        try:
            return socket.create_connection(("127.0.0.1", port), timeout=2)
        except ConnectionRefusedError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.02)


def test_tcpin_talks_to_its_first_connection_only() -> None:
    port = free_tcp_port()
    endpoint: Any = open_transport(f"tcpin://127.0.0.1:{port}", timeout=0.5)
    first = connect_when_listening(port)
    try:
        first.sendall(b"vehicle")
        assert endpoint.read(100) == b"vehicle"
        second = socket.create_connection(("127.0.0.1", port), timeout=2)
        second.sendall(b"intruder")
        assert endpoint.read(100) == b""  # accepted only to be closed
        with contextlib.suppress(ConnectionResetError):  # a reset: its bytes were never read
            assert second.recv(100) == b""  # closed at once, never answered
        second.close()
        endpoint.write(b"command")
        assert first.recv(100) == b"command"
        assert endpoint.intrusions == 1 and endpoint.last_foreign is not None
        first.close()
        with pytest.raises(OSError, match="closed the connection"):
            for _ in range(20):
                endpoint.read(100)
    finally:
        endpoint.close()


class TcpVehicle:
    """The vehicle connects to ``tcpin`` as a TCP client (once it listens), pumped by a thread
    (bounded: 30 s at most, stopped on exit)."""

    def __init__(self, vehicle: SimMavlinkVehicle, port: int) -> None:
        self.vehicle = vehicle
        self.port = port
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        clock = MonotonicClock()
        with connect_when_listening(self.port) as sock:
            sock.settimeout(0.005)
            deadline = time.monotonic() + 30
            while not self._stop.is_set() and time.monotonic() < deadline:
                try:
                    data = sock.recv(65536)
                    if not data:
                        return
                    self.vehicle.write(data, clock.now_s())
                except TimeoutError:
                    pass
                except OSError:
                    return
                out = self.vehicle.read(clock.now_s())
                if out:
                    sock.sendall(out)

    def __enter__(self) -> TcpVehicle:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def test_spin_on_tcpin_aborts_when_a_peer_connects_from_elsewhere() -> None:
    port = free_tcp_port()
    vehicle = ArduPilotVehicle(ConstantPlant())
    received: list[int] = []
    stop = threading.Event()

    def intrude() -> None:
        deadline = time.monotonic() + 30
        while not vehicle.motor_test_running and time.monotonic() < deadline:
            if stop.wait(0.01):
                return
        with socket.create_connection(("127.0.0.1", port), timeout=2) as sock:
            received.append(sock.getsockname()[1])
            sock.sendall(heartbeat_bytes(1))
            try:  # closed at once (a reset: our heartbeat was never read), not one byte
                received.append(len(sock.recv(65536)))
            except ConnectionResetError:
                received.append(0)

    intruder = threading.Thread(target=intrude, daemon=True)
    with TcpVehicle(vehicle, port):
        intruder.start()
        done = CliRunner().invoke(
            cli,
            ["spin", f"tcpin:127.0.0.1:{port}", "--motor", "1", "--throttle", "10"]
            + ["--seconds", "4", "--ramp", "0", "--yes"],
        )
        stop.set()
        intruder.join(timeout=5)
    assert len(received) == 2, done.output
    assert done.exit_code == 1, done.output
    assert f"127.0.0.1:{received[0]} sent to the vehicle link" in done.output
    assert "stopped (verified)" in done.output
    assert received[1] == 0
    assert not vehicle.motor_test_running


# ------------------------------------------------------------------------------------------
# MSP over UDP: the same lock, the same abort
# ------------------------------------------------------------------------------------------
def test_msp_over_udpin_aborts_on_an_intruder_while_motors_run() -> None:
    """A UDP MSP bridge that speaks first (one datagram) locks the endpoint; a motor command
    goes out; then a datagram from another address: the next telemetry read raises
    ``LinkIntruder`` naming it, the stop goes to the bridge, the intruder hears nothing."""
    from thrustmap.rig.fc.msp import MspThrottleOutput
    from thrustmap.rig.sim.msp_peer import MspPeer

    port = free_udp_port()
    peer = MspPeer(ConstantPlant(4))
    clock = MonotonicClock()
    fc_port = open_transport(f"udpin://127.0.0.1:{port}")
    bridge, intruder = udp_socket(), udp_socket()
    stop = threading.Event()

    def serve() -> None:
        bridge.sendto(b"\x00", ("127.0.0.1", port))  # hello: the bridge speaks first
        deadline = time.monotonic() + 30
        while not stop.is_set() and time.monotonic() < deadline:
            try:
                data, host = bridge.recvfrom(65535)
                peer.write(data, clock.now_s())
            except BlockingIOError:
                host = ("127.0.0.1", port)
            out = peer.read(clock.now_s())
            if out:
                bridge.sendto(out, host)
            stop.wait(0.002)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    out = MspThrottleOutput(fc_port, clock, watchdog=False)
    try:
        out.identify()
        out.set_throttle({0: out.throttle_scale.lo + 0.1 * out.throttle_scale.span})
        out.read_telemetry()
        intruder.sendto(b"$M<\x00\x00\x00", ("127.0.0.1", port))
        time.sleep(0.05)
        host, iport = intruder.getsockname()
        with pytest.raises(LinkIntruder, match=f"{host}:{iport} sent to the vehicle link"):
            for _ in range(50):
                out.read_telemetry()
                time.sleep(0.01)
        assert out.stop_and_verify() is True
        assert drain(intruder) == 0
    finally:
        out.close()
        stop.set()
        thread.join(timeout=5)
        bridge.close()
        intruder.close()


def test_an_intruder_before_the_motor_starts_gets_spin_refused(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A second ground station on the port from the start (its HEARTBEATs lock nothing, and
    arrive while the vehicle is identified): the spin is refused before any motor command,
    exit 2, one line naming it."""
    from thrustmap.cli import main

    port = free_udp_port()
    vehicle = PX4Vehicle(ConstantPlant())
    gcs = mav.MavlinkCodec(255, 190).encode(
        enc.heartbeat_message(mav.Autopilot.INVALID, armed=False, vehicle_type=6)
    )
    with (
        vehicle_on_udp(vehicle, port),
        Intruder(port, lambda: True, period_s=0.005, heartbeat=gcs) as intruder,
        pytest.raises(SystemExit) as exc,
    ):
        main(
            ["spin", f"udpin:127.0.0.1:{port}", "--motor", "1", "--throttle", "10"]
            + ["--seconds", "1", "--ramp", "0", "--yes"]
        )
    host, iport = intruder.address
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"error: {host}:{iport} sent to the vehicle link before a motor command" in err, err
    assert intruder.received == 0
    assert not [
        c
        for c in vehicle.commands_received
        if c.command == mav.MAV_CMD_ACTUATOR_TEST and c.params[0] == c.params[0]
    ]


def test_a_second_vehicle_on_the_port_stops_every_command() -> None:
    """Which address is the vehicle is unknown once two claim to be: no command goes out."""
    port = free_udp_port()
    vehicle = PX4Vehicle(ConstantPlant())
    with vehicle_on_udp(vehicle, port):
        out = open_mavlink_output(f"udpin:127.0.0.1:{port}", MonotonicClock())
        spoofer = udp_socket()
        try:
            out.identify()
            sent = len(vehicle.commands_received)
            spoofer.sendto(heartbeat_bytes(1), ("127.0.0.1", port))
            time.sleep(0.05)
            out.poll()
            host, iport = spoofer.getsockname()
            with pytest.raises(LinkIntruder, match=f"{host}:{iport} also claims to be the"):
                out.command(mav.request_message(mav.MSG_AUTOPILOT_VERSION))
            time.sleep(0.05)
            assert len(vehicle.commands_received) == sent and drain(spoofer) == 0
        finally:
            out.close()
            spoofer.close()
