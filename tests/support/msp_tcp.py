"""A simulated MSP flight controller served over TCP, one connection at a time, like a
Betaflight SITL on port 5761: for tests that need a real socket (the watchdog reopens the
port from another process). Test support, not product code."""

from __future__ import annotations

import select
import socket
import threading
import time
from dataclasses import dataclass, field

from support.sockets import tcp_listener
from thrustmap.protocols.msp.framing import MspCommand, MspDecoder, MspDirection
from thrustmap.protocols.msp.motor import SetMotor
from thrustmap.rig.sim.msp_peer import MspPeer


@dataclass
class MspTcpServer:
    peer: MspPeer
    host: str = "127.0.0.1"
    port: int = 0
    connections: int = 0
    #: (monotonic time, connection number, SET_MOTOR values) for every SET_MOTOR received
    set_motors: list[tuple[float, int, tuple[int, ...]]] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _listener: socket.socket | None = None

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    def start(self) -> MspTcpServer:
        listener = tcp_listener(self.host, self.port, 1)
        self.port = listener.getsockname()[1]
        self._listener = listener
        self._thread = threading.Thread(target=self._serve, name="msp-tcp", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        if self._listener is not None:
            self._listener.close()

    def __enter__(self) -> MspTcpServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _serve(self) -> None:
        assert self._listener is not None
        while not self._stop.is_set():
            ready, _, _ = select.select([self._listener], [], [], 0.05)
            if not ready:
                continue
            conn, _ = self._listener.accept()
            self.connections += 1
            with conn:
                self._session(conn, self.connections)

    def _session(self, conn: socket.socket, number: int) -> None:
        decoder = MspDecoder()
        while not self._stop.is_set():
            ready, _, _ = select.select([conn], [], [], 0.005)
            now = time.monotonic()
            if ready:
                try:
                    data = conn.recv(4096)
                except OSError:
                    return
                if not data:
                    return
                for frame in decoder.feed(data):
                    if (
                        frame.direction is MspDirection.REQUEST
                        and frame.cmd == MspCommand.SET_MOTOR
                    ):
                        values = SetMotor.decode(frame.payload).values
                        self.set_motors.append((now, number, values))
                self.peer.write(data, now)
            out = self.peer.read(now)
            if out:
                try:
                    conn.sendall(out)
                except OSError:
                    return
