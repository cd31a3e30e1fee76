"""The part of a locked socket endpoint's ``SerialLike`` surface that is the same for UDP and TCP.

``protocol_udpin`` and ``protocol_tcpin`` differ in how bytes arrive (and from whom they are
taken); both keep the locked peer in ``_remote`` and what they accepted in ``_buffer``, and
serve reads from it the same way.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

MAX_FOREIGN_SENDERS = 32  # distinct intruding addresses remembered (the count goes on)


class BufferedEndpoint(SerialBase):
    """The locked peer (``remote``, ``peer``) and ``read``/``in_waiting`` over ``_buffer``, which ``_drain(wait_s)`` fills (at most
    ``wait_s`` seconds of waiting; 0 polls)."""

    _buffer: bytearray
    _remote: tuple[str, int] | None

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        # set before SerialBase.__init__, which opens the port when one is given
        self._remote = None
        self._buffer = bytearray()
        self.dropped_writes = 0
        #: which bytes identify the peer (None: the first sender is it); udpin reads it
        self.identifies_peer: Callable[[bytes], bool] | None = None
        self.foreign_claims = 0  # intruders' datagrams that would have identified a peer
        self.foreign_senders: dict[tuple[str, int], int] = {}
        self.last_foreign: tuple[str, int] | None = None
        kwargs.pop("clock", None)  # real sockets run on real time
        super().__init__(*args, **kwargs)

    def _check_openable(self) -> None:
        if self.port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")

    def _count_foreign(self, sender: tuple[str, int]) -> bool:
        """Count an intruder (bounded: at most ``MAX_FOREIGN_SENDERS`` addresses are kept, the
        count goes on); True the first time its address is kept, to be logged once."""
        self.last_foreign = sender
        if sender in self.foreign_senders:
            self.foreign_senders[sender] += 1
            return False
        if len(self.foreign_senders) < MAX_FOREIGN_SENDERS:
            self.foreign_senders[sender] = 1
            return True
        return False

    def _reconfigure_port(self) -> None:
        pass

    @property
    def remote(self) -> tuple[str, int] | None:
        """The locked peer (None while nobody has been identified)."""
        return self._remote

    @property
    def peer(self) -> str | None:
        """The locked peer as ``host:port``."""
        return None if self._remote is None else f"{self._remote[0]}:{self._remote[1]}"

    def _drain(self, wait_s: float) -> None:
        raise NotImplementedError

    @property
    def in_waiting(self) -> int:
        self._drain(0.0)
        return len(self._buffer)

    def read(self, size: int = 1, /) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        if not self._buffer:
            timeout = self.timeout
            self._drain(1e9 if timeout is None else float(timeout))
        out = bytes(self._buffer[:size])
        del self._buffer[:size]
        return out

    def reset_input_buffer(self) -> None:
        self._buffer.clear()

    def reset_output_buffer(self) -> None:
        pass

    def flush(self) -> None:
        pass
