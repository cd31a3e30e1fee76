"""``udpin://host:port`` and ``udpout://host:port`` — a UDP endpoint as a pyserial-like port.

MAVLink links to PX4 SITL, companion computers and radios are mostly UDP. pymavlink writes them
``udpin:0.0.0.0:14550`` (listen; answer whoever sent last) and ``udpout:10.0.0.2:14550`` (send
to that address; listen on an ephemeral port); ``normalize_udp_url`` turns those spellings (and
``udp:`` = ``udpin:``) into these URLs, so ``record://udpin:0.0.0.0:14550?file=x.jsonl`` works.

Datagrams become a byte stream: ``read(n)`` returns buffered bytes first and waits (up to the
port's ``timeout``) only when none are buffered; ``in_waiting`` drains what the socket holds
(at most ``MAX_DATAGRAMS_PER_POLL`` datagrams per call, so a flood cannot pin the caller).
A ``write`` before any peer has spoken to a ``udpin`` endpoint is dropped (logged): there is
nobody to send it to yet.

The peer is LOCKED (pymavlink's ``udpin`` "answers whoever sent last"; this one never does):

- ``udpin``: the first datagram that identifies the peer locks the endpoint to its sender's
  address and port. What identifies it is ``identifies_peer`` (a predicate on the datagram,
  set by the protocol above: MAVLink says "holds a vehicle HEARTBEAT"); without one, the first
  datagram does. Datagrams before the lock that do not identify the peer are dropped
  (``unidentified_datagrams``); after it, datagrams from any other address are dropped and
  counted (``foreign_datagrams``, ``foreign_senders``, ``last_foreign``; those that would have
  identified a peer, a second "vehicle", also in ``foreign_claims``): they never reach the
  reader and nothing is ever sent to them. Every write goes to the locked peer, or nowhere.
  Without authentication (MAVLink signing) a host that speaks first with an identifying
  datagram is taken for the peer; the real one is then a foreign claim, and the driver above
  refuses to command anything (``rig.fc.link_lock``).
- ``udpout``: the socket is connected to the target, so the operating system itself drops
  datagrams from any other address (they cannot be counted).
"""

from __future__ import annotations

import logging
import select
import socket
from typing import Any

from serial.serialutil import PortNotOpenError, SerialException

from thrustmap.protocols.urlhandlers.buffered import BufferedEndpoint

log = logging.getLogger(__name__)

MAX_DATAGRAM = 65535
MAX_DATAGRAMS_PER_POLL = 64
UDP_SCHEMES = ("udpin", "udpout", "udp")


def is_udp_url(url: str) -> bool:
    scheme = url.split(":", 1)[0].lower()
    return scheme in UDP_SCHEMES and ":" in url


def normalize_udp_url(url: str) -> str:
    """``udpin:h:p`` / ``udp:h:p`` / ``udpout:h:p`` (pymavlink) -> ``udpin://h:p`` ..."""
    scheme, _, rest = url.partition(":")
    scheme = scheme.lower()
    rest = rest[2:] if rest.startswith("//") else rest
    if scheme not in UDP_SCHEMES or not rest:
        raise SerialException(f"expected udpin:HOST:PORT or udpout:HOST:PORT, got {url!r}")
    return f"{'udpin' if scheme == 'udp' else scheme}://{rest}"


def _address(url: str) -> tuple[str, bool, tuple[str, int]]:
    scheme, _, rest = normalize_udp_url(url).partition("://")
    hostport = rest.split("?", 1)[0]
    host, sep, port = hostport.rpartition(":")
    if not sep or not port.isdigit() or not 0 < int(port) < 65536:
        raise SerialException(f"{url!r}: expected HOST:PORT with a port 1..65535")
    return scheme, scheme == "udpin", (host or "0.0.0.0", int(port))


class UdpSerial(BufferedEndpoint):
    """A UDP endpoint with the ``SerialLike`` surface; see the module docstring."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._sock: socket.socket | None = None
        # _remote is the locked peer (udpout: the target); identifies_peer says which datagram
        # identifies it (None: the first one does)
        self.unidentified_datagrams = 0  # dropped before the lock: they identified nobody
        self.foreign_datagrams = 0  # dropped after the lock: from another address
        self.last_claim: tuple[str, int] | None = None
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        self._check_openable()
        _, listen, address = _address(str(self.port))
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if listen:
                # no SO_REUSEADDR: with it, another program (also setting it) could bind the
                # same port and take the vehicle's datagrams (Linux gives them to the last)
                sock.bind(address)
            else:
                sock.connect(address)  # the OS drops datagrams from any other address
                host, port = sock.getpeername()[:2]
                self._remote = (str(host), int(port))  # as recvfrom names it ("localhost" resolved)
        except OSError as exc:
            sock.close()
            raise SerialException(f"{self.port}: cannot open UDP endpoint: {exc}") from exc
        sock.setblocking(False)
        self._sock = sock
        self.is_open = True

    @property
    def intrusions(self) -> int:
        """Datagrams from other addresses since the lock (the interface ``tcpin`` shares)."""
        return self.foreign_datagrams

    def _accept(self, data: bytes, sender: tuple[str, int]) -> bool:
        """Lock on the first identifying datagram; drop (and count) everything else."""
        if self._remote is None:
            check = self.identifies_peer
            if check is not None and not check(data):
                self.unidentified_datagrams += 1
                return False
            self._remote = sender
            log.info("%s: locked to %s:%d", self.port, sender[0], sender[1])
            return True
        if sender == self._remote:
            return True
        self.foreign_datagrams += 1
        check = self.identifies_peer
        if check is not None and check(data):
            self.foreign_claims += 1
            self.last_claim = sender
        if self._count_foreign(sender):  # once per address, bounded: so is the log
            log.warning(
                "%s: dropped a datagram from %s:%d (the link is locked to %s)",
                self.port,
                sender[0],
                sender[1],
                self.peer,
            )
        return False

    def _drain(self, wait_s: float) -> None:
        sock = self._sock
        if sock is None:
            raise PortNotOpenError()
        if wait_s > 0 and not self._buffer:
            ready, _, _ = select.select([sock], [], [], wait_s)
            if not ready:
                return
        for _ in range(MAX_DATAGRAMS_PER_POLL):
            try:
                data, sender = sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionRefusedError:
                continue  # ICMP from a udpout target not listening yet: no data
            except OSError as exc:
                raise SerialException(f"{self.port}: UDP receive failed: {exc}") from exc
            if self._accept(data, (str(sender[0]), int(sender[1]))):
                self._buffer += data

    def write(self, b: Any, /) -> int | None:
        sock = self._sock
        if sock is None or not self.is_open:
            raise PortNotOpenError()
        data = bytes(b)
        if self._remote is None:
            self.dropped_writes += 1
            log.debug("%s: no peer has spoken yet; dropped %d bytes", self.port, len(data))
            return len(data)
        try:
            sock.sendto(data, self._remote)
        except ConnectionRefusedError:
            log.debug("%s: peer not listening (ICMP refused)", self.port)
        except OSError as exc:
            raise SerialException(f"{self.port}: UDP send failed: {exc}") from exc
        return len(data)

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        self.is_open = False


class Serial(UdpSerial):
    """The class pyserial instantiates for ``udpin://`` URLs."""
