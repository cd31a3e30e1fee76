"""``tcpin://host:port`` — listen for ONE TCP peer and talk to it alone (pymavlink's ``tcpin:``).

A vehicle or a forwarder connects to us (ArduPilot SITL ``--serial1 tcpclient:...``). The first
connection is the peer and the endpoint is locked to it: every later connection, from anywhere,
is accepted only to be closed at once, and counted (``intrusions``, ``foreign_senders``,
``last_foreign``); nothing is ever read from or written to it. When the peer's connection ends
the link is gone (a read raises): pymavlink's ``tcpin`` would take the next connection from
anyone and send it the motor commands meant for the vehicle.

The interface is the same as ``protocol_udpin``'s (``peer``, ``remote``, ``identifies_peer``
(unused here: a connection is a peer), ``intrusions``), so the MAVLink session watches both alike.
"""

from __future__ import annotations

import logging
import select
import socket
import time
from typing import Any

from serial.serialutil import PortNotOpenError, SerialException

from thrustmap.protocols.urlhandlers.buffered import BufferedEndpoint

log = logging.getLogger(__name__)

MAX_READ = 65536
MAX_SELECTS_PER_DRAIN = 4  # bounded: intruders connecting in a loop cannot pin a reader


def normalize_tcpin_url(url: str) -> str:
    """``tcpin:h:p`` (pymavlink) -> ``tcpin://h:p``."""
    scheme, _, rest = url.partition(":")
    rest = rest[2:] if rest.startswith("//") else rest
    if scheme.lower() != "tcpin" or not rest:
        raise SerialException(f"expected tcpin:HOST:PORT, got {url!r}")
    return f"tcpin://{rest}"


class Serial(BufferedEndpoint):
    """A listening TCP endpoint locked to its first connection; see the module docstring."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._listener: socket.socket | None = None
        self._conn: socket.socket | None = None
        self._closed_by_peer = False
        self.intrusions = (
            0  # identifies_peer and foreign_claims: a refused connection is never read
        )
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        self._check_openable()
        rest = normalize_tcpin_url(str(self.port)).partition("://")[2].split("?", 1)[0]
        host, sep, port = rest.rpartition(":")
        if not sep or not port.isdigit() or not 0 < int(port) < 65536:
            raise SerialException(f"{self.port!r}: expected HOST:PORT with a port 1..65535")
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            listener.bind((host or "127.0.0.1", int(port)))
            listener.listen(4)
        except OSError as exc:
            listener.close()
            raise SerialException(f"{self.port}: cannot listen: {exc}") from exc
        listener.setblocking(False)
        self._listener = listener
        self.is_open = True

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            conn, addr = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        sender = (str(addr[0]), int(addr[1]))
        if self._remote is None:
            conn.settimeout(2.0)  # sendall may wait for a full buffer, bounded; reads follow select
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._conn, self._remote = conn, sender
            log.info("%s: locked to %s", self.port, self.peer)
            return
        conn.close()  # never read from, never written to
        self.intrusions += 1
        if self._count_foreign(sender):  # once per address, bounded: so is the log
            log.warning(
                "%s: refused a connection from %s:%d (the link is locked to %s)",
                self.port,
                sender[0],
                sender[1],
                self.peer,
            )

    def _drain(self, wait_s: float) -> None:
        deadline_s = time.monotonic() + max(0.0, wait_s)
        for _ in range(MAX_SELECTS_PER_DRAIN):  # a new peer's first bytes in the same wait
            if self._drain_once(max(0.0, deadline_s - time.monotonic())) or self._buffer:
                return
            if time.monotonic() >= deadline_s:
                return

    def _drain_once(self, wait_s: float) -> bool:
        """One select; True when there is nothing more to wait for."""
        if self._listener is None:
            raise PortNotOpenError()
        watched = [self._listener] + ([self._conn] if self._conn is not None else [])
        ready, _, _ = select.select(watched, [], [], 0.0 if self._buffer else wait_s)
        if not ready:
            return True
        if self._listener in ready:
            self._accept()
        if self._conn is not None and self._conn in ready:
            try:
                data = self._conn.recv(MAX_READ)
            except (BlockingIOError, InterruptedError, TimeoutError):
                return False
            except OSError as exc:
                raise SerialException(
                    f"{self.port}: connection to {self.peer} failed: {exc}"
                ) from exc
            if not data:
                self._closed_by_peer = True
                self._conn.close()
                self._conn = None
            self._buffer += data
        if self._closed_by_peer and not self._buffer:
            raise SerialException(f"{self.port}: {self.peer} closed the connection")
        return False

    def write(self, b: Any, /) -> int | None:
        if not self.is_open:
            raise PortNotOpenError()
        data = bytes(b)
        if self._conn is None:
            if self._closed_by_peer:
                raise SerialException(f"{self.port}: {self.peer} closed the connection")
            self.dropped_writes += 1
            return len(data)
        try:
            self._conn.sendall(data)
        except OSError as exc:
            raise SerialException(f"{self.port}: send to {self.peer} failed: {exc}") from exc
        return len(data)

    def close(self) -> None:
        for sock in (self._conn, self._listener):
            if sock is not None:
                sock.close()
        self._conn = self._listener = None
        self.is_open = False
