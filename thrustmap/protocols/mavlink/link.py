"""A pymavlink connection over any pyserial-like byte transport, timed by an injected clock.

``MavlinkSerialLink(transport, clock)`` is a ``pymavlink.mavutil.mavfile``: drivers use the
familiar ``wait_heartbeat``, ``recv_match(type=..., blocking=True, timeout=...)``,
``mav.command_long_send(...)`` and ``messages``. The transport may be a real port, ``sim://px4``,
``record://...`` or ``replay://...``, so MAVLink drivers get record/replay for free and never know
which they have.

Differences from the stock ``mavutil`` classes, all so tests never sleep for real:
- waiting is a ``transport.read(1)`` with the port's timeout set to the wait (a real port blocks
  in the OS, ``sim://`` advances its clock, ``replay://`` returns at once);
- ``recv_match`` timeouts and message timestamps use the injected clock, not ``time.time()``;
- the link is always MAVLink 2 (pymavlink's v2.0 ardupilotmega dialect, chosen here where the
  connection is built; nothing reads or sets the process-wide ``MAVLINK20`` switch);
- bytes are read in chunks (everything the port holds, up to ``MAX_READ_CHUNK``), so a
  ``record://`` transcript holds one event per read, not one per byte.
- on a network endpoint that locks onto one peer (``udpin:``, ``tcpin:``; see
  ``protocols.urlhandlers.protocol_udpin``) the peer is the sender of the first vehicle
  HEARTBEAT (validly signed, once signing is on): a ground station's heartbeat, or anything
  else sent to the port first, locks nothing and is dropped; after the lock nothing from
  another address reaches the parser and nothing is sent anywhere else.
- MAVLink 2 signing (``thrustmap.protocols.mavlink.signing.enable_signing``) is pymavlink's own.

``open_mavlink(url, clock=..., **serial_kwargs)`` opens the transport by URL and wraps it. Besides
thrustmap's URLs and device paths it takes pymavlink's spellings: ``udpin:HOST:PORT``,
``udpout:HOST:PORT``, ``udp:`` (= ``udpin:``), ``tcp:HOST:PORT`` (= ``socket://HOST:PORT``) and
``tcpin:HOST:PORT`` (listen for one peer, ``protocol_tcpin``), also inside ``record://``
(``record://udpin:0.0.0.0:14550?file=run.jsonl``).
"""

from __future__ import annotations

import logging
import time
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from thrustmap.core.clock import Clock, MonotonicClock
from thrustmap.protocols.mavlink.codec import decode_heartbeat
from thrustmap.protocols.mavlink.signing import is_signed
from thrustmap.protocols.transcript import TransportError
from thrustmap.protocols.transport import SerialLike, locked_endpoint, open_transport
from thrustmap.protocols.urlhandlers.protocol_tcpin import normalize_tcpin_url
from thrustmap.protocols.urlhandlers.protocol_udpin import is_udp_url, normalize_udp_url

log = logging.getLogger(__name__)

MAX_IDLE_POLLS = 100_000
MAX_IDLE_WALL_S = 10.0  # a real port on a clock that does not advance: give up after this
MAX_READ_CHUNK = 4096  # bytes per transport read: bounded, and a whole burst in one event
GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER


class MavlinkSerialLink(mavutil.mavfile):  # type: ignore[misc]
    """``mavfile`` over a ``SerialLike``; see the module docstring."""

    def __init__(
        self,
        transport: SerialLike,
        clock: Clock | None = None,
        *,
        source_system: int = GCS_SYSTEM_ID,
        source_component: int = GCS_COMPONENT_ID,
        name: str = "serial-like",
    ) -> None:
        self.port = transport
        self.clock: Clock = clock if clock is not None else MonotonicClock()
        self._pushback = bytearray()
        #: vehicle HEARTBEATs a locking endpoint refused because signing is on (see
        #: ``holds_vehicle_heartbeat``)
        self.heartbeats_refused_bad_signature = 0
        self.heartbeats_refused_unsigned = 0
        mavutil.mavfile.__init__(
            self,
            None,
            name,
            source_system=source_system,
            source_component=source_component,
            use_native=False,
        )
        # MAVLink 2 whatever mavutil loaded: a v2.0 MAVLink object writing to this file.
        self.mav = mavlink2.MAVLink(self, srcSystem=source_system, srcComponent=source_component)
        self.mav.robust_parsing = True
        self.WIRE_PROTOCOL_VERSION = "2.0"
        self.first_byte = False  # no auto-switching (it edits os.environ and the global dialect)
        endpoint = locked_endpoint(transport)
        if endpoint is not None:
            endpoint.identifies_peer = self.holds_vehicle_heartbeat

    def holds_vehicle_heartbeat(self, datagram: bytes) -> bool:
        """``datagram`` holds a HEARTBEAT from a vehicle (not a GCS), validly signed when this
        link signs: the datagram that identifies the peer a network endpoint locks onto."""
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        key = self.mav.signing.secret_key
        if key is not None:  # a fresh stream state: any timestamp, but the signature must match
            parser.signing.secret_key = key
            parser.signing.allow_unsigned_callback = lambda _mav, _msg_id: False
        if self._vehicle_heartbeat_in(parser, datagram):
            return True
        if key is not None:  # why not: for the diagnosis of a silent, signing-refused vehicle
            plain = mavlink2.MAVLink(None)
            plain.robust_parsing = True
            for msg in plain.parse_buffer(datagram) or []:
                if msg.get_type() == "HEARTBEAT" and decode_heartbeat(msg).is_vehicle:
                    if is_signed(msg):
                        self.heartbeats_refused_bad_signature += 1
                    else:
                        self.heartbeats_refused_unsigned += 1
        return False

    @staticmethod
    def _vehicle_heartbeat_in(parser: Any, datagram: bytes) -> bool:
        return any(
            msg.get_type() == "HEARTBEAT" and decode_heartbeat(msg).is_vehicle
            for msg in parser.parse_buffer(datagram) or []
        )

    # -- bytes ---------------------------------------------------------------------------
    def recv(self, n: int | None = None) -> bytes:
        if n is None:
            n = self.mav.bytes_needed()
        n = max(1, int(n))
        if len(self._pushback) < n:
            available = self.port.in_waiting
            if available:  # take the whole burst in one read (one transcript event)
                self._pushback += self.port.read(min(available, MAX_READ_CHUNK))
        out = bytes(self._pushback[:n])
        del self._pushback[:n]
        return out

    def write(self, buf: Any) -> int:
        written = self.port.write(bytes(buf))
        return len(buf) if written is None else int(written)

    def select(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for a byte (kept for the next ``recv``)."""
        if self._pushback:
            return True
        previous = self.port.timeout
        self.port.timeout = max(0.0, float(timeout))
        try:
            data = self.port.read(1)
        finally:
            self.port.timeout = previous
        if data:
            available = self.port.in_waiting  # the rest of the burst, in the same breath
            if available:
                data += self.port.read(min(available, MAX_READ_CHUNK))
        self._pushback += data
        return bool(data)

    def close(self) -> None:
        self.port.close()

    # -- clock-driven receive -------------------------------------------------------------
    def post_message(self, msg: Any) -> None:
        super().post_message(msg)
        msg._timestamp = self.clock.now_s()

    def recv_match(
        self,
        condition: str | None = None,
        type: str | list[str] | set[str] | None = None,  # noqa: A002 - pymavlink's name
        blocking: bool = False,
        timeout: float | None = None,
    ) -> Any:
        """As ``mavfile.recv_match``, with the timeout measured on the injected clock."""
        types = None if type is None else ({type} if isinstance(type, str) else set(type))
        start_s = self.clock.now_s()
        idle_polls = 0
        idle_since_wall_s = 0.0
        while True:
            if timeout is not None and self.clock.now_s() - start_s >= timeout:
                return None
            msg = self.recv_msg()
            if msg is None:
                if not blocking:
                    return None
                for hook in self.idle_hooks:
                    hook(self)
                before_s = self.clock.now_s()
                wait_s = 0.05 if timeout is None else timeout - (before_s - start_s)
                if self.select(max(0.0, min(0.05, wait_s))) or self.clock.now_s() > before_s:
                    idle_polls = 0
                else:
                    idle_polls += 1
                    if idle_polls == 1:
                        idle_since_wall_s = time.monotonic()
                    stuck_s = time.monotonic() - idle_since_wall_s
                    if idle_polls > MAX_IDLE_POLLS or stuck_s > MAX_IDLE_WALL_S:
                        raise TransportError(
                            f"{self.address}: no data and the clock does not advance; give the "
                            "transport the same clock as the link (clock=...)"
                        )
                continue
            if types is not None and msg.get_type() not in types:
                continue
            if condition is not None and not mavutil.evaluate_condition(
                condition, self.sysid_state[msg.get_srcSystem()].messages
            ):
                continue
            return msg


def mavutil_connection(
    url: str,
    *,
    source_system: int = GCS_SYSTEM_ID,
    source_component: int = GCS_COMPONENT_ID,
    **kwargs: Any,
) -> Any:
    """A stock ``mavutil.mavlink_connection`` (for forms thrustmap has no transport for, e.g.
    ``tcpin:``), switched to MAVLink 2 here, explicitly: no ``MAVLINK20`` in the environment,
    and no auto-switching (which would edit the environment and the global dialect)."""
    conn = mavutil.mavlink_connection(
        url, source_system=source_system, source_component=source_component, **kwargs
    )
    conn.mav = mavlink2.MAVLink(conn, srcSystem=source_system, srcComponent=source_component)
    conn.mav.robust_parsing = True
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False
    return conn


def is_own_transport(url: str) -> bool:
    """``open_mavlink`` has a transport for it (so it can be recorded and replayed)."""
    scheme = url.split(":", 1)[0].lower()
    return scheme != "udpbcast"


def normalize_mavlink_url(url: str) -> str:
    """pymavlink spellings -> thrustmap transport URLs (also inside ``record://``)."""
    if url.lower().startswith("record://"):
        return "record://" + normalize_mavlink_url(url[len("record://") :])
    if is_udp_url(url):
        return normalize_udp_url(url)
    scheme, sep, rest = url.partition(":")
    if sep and scheme.lower() == "tcp" and not rest.startswith("//"):
        return f"socket://{rest}"
    if sep and scheme.lower() == "tcpin":
        return normalize_tcpin_url(url)
    return url


def open_mavlink(
    url: str,
    *,
    clock: Clock | None = None,
    source_system: int = GCS_SYSTEM_ID,
    source_component: int = GCS_COMPONENT_ID,
    **serial_kwargs: Any,
) -> MavlinkSerialLink:
    """Open ``url`` (a device path, ``sim://px4``, ``record://...``, ``replay://...``,
    ``udpin:``/``udpout:``/``tcp:``) as a MAVLink 2 link."""
    url = normalize_mavlink_url(url)
    if clock is not None and url.split("://", 1)[0].lower() in ("sim", "record", "replay"):
        serial_kwargs["clock"] = clock
    serial_kwargs.setdefault("timeout", 0)
    transport = open_transport(url, **serial_kwargs)
    return MavlinkSerialLink(
        transport, clock, source_system=source_system, source_component=source_component, name=url
    )
