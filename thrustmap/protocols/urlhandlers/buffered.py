"""The part of a locked socket endpoint's ``SerialLike`` surface that is the same for UDP and TCP.

``protocol_udpin`` and ``protocol_tcpin`` differ in how bytes arrive (and from whom they are
taken); both keep the locked peer in ``_remote`` and what they accepted in ``_buffer``, and
serve reads from it the same way.
"""

from __future__ import annotations

from serial.serialutil import PortNotOpenError, SerialBase


class BufferedEndpoint(SerialBase):
    """The locked peer (``remote``, ``peer``) and ``read``/``in_waiting`` over ``_buffer``, which ``_drain(wait_s)`` fills (at most
    ``wait_s`` seconds of waiting; 0 polls)."""

    _buffer: bytearray
    _remote: tuple[str, int] | None

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
