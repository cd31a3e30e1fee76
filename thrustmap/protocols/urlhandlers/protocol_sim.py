"""``sim://<peer>?key=value...`` — an in-process simulated device at the byte level.

URL form: ``serial.serial_for_url("sim://px4?motors=4", timeout=0.1, clock=SimClock())``.
The peer name selects a factory registered with ``thrustmap.protocols.peer.register_peer``;
the query (percent-decoded) is passed to it as a ``dict[str, str]``. Without ``clock=`` the
real monotonic clock is used.

Direct form (tests, the runner): ``SimSerial(peer, clock, timeout=0.1)`` is open at once.

Timing: a write reaches the peer at ``clock.now_s()``. A read collects what the peer has sent by
now; if that is short of ``size`` it waits like a serial port, by ``clock.sleep_s`` in steps of
``poll_interval_s`` (a ``SimClock`` just advances, so no test sleeps for real), until ``timeout``.
``timeout=None`` (blocking) waits at most ``max_block_s`` and then raises ``SimPeerSilentError``
instead of hanging forever.
"""

from __future__ import annotations

import logging
from typing import Any
from urllib.parse import unquote, urlsplit

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from thrustmap.core.clock import Clock, MonotonicClock
from thrustmap.protocols.peer import BytePeer, create_peer
from thrustmap.protocols.transcript import TransportError

log = logging.getLogger(__name__)


class SimPeerSilentError(TransportError):
    """A blocking read (timeout=None) on a simulated peer got nothing for ``max_block_s``."""


def parse_query(query: str) -> dict[str, str]:
    """``a=1&b=x%20y`` -> {"a": "1", "b": "x y"}. '+' stays '+' (file names may contain it)."""
    options: dict[str, str] = {}
    for part in query.split("&"):
        if not part:
            continue
        key, _, value = part.partition("=")
        options[unquote(key)] = unquote(value)
    return options


class SimSerial(SerialBase):
    """A pyserial-compatible port whose far end is a ``BytePeer``."""

    def __init__(
        self,
        peer: BytePeer | None = None,
        clock: Clock | None = None,
        *,
        poll_interval_s: float = 0.001,
        max_block_s: float = 10.0,
        name: str | None = None,
        **serial_kwargs: Any,
    ) -> None:
        self._peer: BytePeer | None = peer
        self._clock: Clock = clock if clock is not None else MonotonicClock()
        self._rx = bytearray()
        self.poll_interval_s = poll_interval_s
        self.max_block_s = max_block_s
        serial_kwargs.pop("port", None)
        super().__init__(port=None, **serial_kwargs)
        if peer is not None:
            self._port = name or f"sim://{type(peer).__name__}"
            self.is_open = True

    # -- pyserial plumbing ------------------------------------------------------------------
    @property
    def peer(self) -> BytePeer:
        if self._peer is None:
            raise PortNotOpenError()
        return self._peer

    @property
    def clock(self) -> Clock:
        return self._clock

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        parts = urlsplit(self._port)
        if parts.scheme.lower() != "sim":
            raise SerialException(f"expected a sim://<peer>?key=value URL, got {self._port!r}")
        name = unquote(parts.netloc or parts.path.lstrip("/"))
        self._peer = create_peer(name, parse_query(parts.query))
        self._rx.clear()
        self.is_open = True

    def _reconfigure_port(self) -> None:
        """Nothing to configure: a simulated link has no baud rate."""

    def _update_dtr_state(self) -> None:
        """A peer with ``set_dtr(asserted, now_s)`` sees the DTR line (an Arduino's reset)."""
        set_dtr = getattr(self._peer, "set_dtr", None)
        if callable(set_dtr):
            set_dtr(bool(self.dtr), self._clock.now_s())

    def _update_rts_state(self) -> None:
        pass

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            close = getattr(self._peer, "close", None)
            if callable(close):
                close()

    # -- data ------------------------------------------------------------------------------
    def _pull(self) -> None:
        if self._peer is not None:
            self._rx += self._peer.read(self._clock.now_s())

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        self._pull()
        return len(self._rx)

    def read(self, size: int = 1, /) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        read_all = size < 0  # io.RawIOBase semantics: everything until the timeout
        if read_all:
            size = 1 << 30
        self._pull()
        timeout = self.timeout
        if len(self._rx) < size and timeout != 0:
            wait_s = self.max_block_s if timeout is None else float(timeout)
            deadline = self._clock.now_s() + wait_s
            while len(self._rx) < size:
                now = self._clock.now_s()
                if now >= deadline:
                    break
                self._clock.sleep_s(min(self.poll_interval_s, deadline - now))
                self._pull()
            if timeout is None and len(self._rx) < size and not read_all:
                raise SimPeerSilentError(
                    f"{self._port}: blocking read of {size} bytes got {len(self._rx)} in "
                    f"{self.max_block_s} s; set a timeout on the port"
                )
        data = bytes(self._rx[:size])
        del self._rx[:size]
        return data

    def write(self, b: Any, /) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        data = bytes(b)
        if data:
            self.peer.write(data, self._clock.now_s())
        return len(data)

    def flush(self) -> None:
        pass

    def reset_input_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        self._pull()
        self._rx.clear()

    def reset_output_buffer(self) -> None:
        pass

    @property
    def out_waiting(self) -> int:
        return 0


class Serial(SimSerial):
    """The class pyserial instantiates for ``sim://`` URLs (``port`` is set, then ``open()``)."""

    def __init__(
        self, port: str | None = None, *args: Any, clock: Clock | None = None, **kwargs: Any
    ):
        if args:
            raise TypeError("sim:// takes keyword arguments only (timeout=..., clock=...)")
        super().__init__(None, clock, **kwargs)
        if port is not None:
            self.port = port
            self.open()
