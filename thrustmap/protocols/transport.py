"""Byte transports for drivers: pyserial ports and thrustmap's own URL schemes.

``open_transport`` registers ``thrustmap.protocols.urlhandlers`` with pyserial (explicitly and
idempotently, where a transport is opened: importing this package changes nothing), so it
understands, besides pyserial's own ``loop://``,
``socket://host:port``, ``rfc2217://`` and device paths:

- ``sim://<peer>?key=value`` — an in-process simulated device (``protocol_sim``),
- ``record://<inner url>?file=x.jsonl`` — tap any transport into a transcript (``protocol_record``),
- ``replay://x.jsonl`` — serve a transcript back to the same driver code (``protocol_replay``).

Extra keyword arguments of ``open_transport``/``serial_for_url`` reach the handlers: ``clock=``
(a ``thrustmap.core.clock.Clock``; ``sim://``, ``record://`` and ``replay://`` take it), ``strict=``
(``replay://``). A driver depends only on ``SerialLike`` and never learns which one it has.
"""

from __future__ import annotations

from typing import Any, Protocol, cast

import serial

HANDLER_PACKAGE = "thrustmap.protocols.urlhandlers"


def register_url_handlers() -> None:
    """Idempotently put thrustmap's URL handlers on pyserial's search list."""
    if HANDLER_PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(HANDLER_PACKAGE)


class SerialLike(Protocol):
    """The part of ``serial.Serial`` a driver may use."""

    @property
    def timeout(self) -> float | None: ...

    @timeout.setter
    def timeout(self, value: float | None) -> None: ...

    @property
    def in_waiting(self) -> int: ...

    @property
    def is_open(self) -> bool: ...

    def read(self, size: int = 1, /) -> bytes: ...

    def write(self, data: bytes, /) -> int | None: ...

    def reset_input_buffer(self) -> None: ...

    def close(self) -> None: ...


def open_transport(url: str, **kwargs: Any) -> SerialLike:
    """``serial.serial_for_url`` with thrustmap's handlers registered (and opened)."""
    register_url_handlers()
    return cast(SerialLike, serial.serial_for_url(url, **kwargs))


def transport_chain(transport: Any) -> list[Any]:
    """``transport`` and every transport it wraps (``record://`` exposes ``.inner``)."""
    chain: list[Any] = []
    current = transport
    while current is not None and len(chain) < 8 and all(c is not current for c in chain):
        chain.append(current)
        try:
            current = getattr(current, "inner", None)
        except OSError:  # a closed record:// port (serial.PortNotOpenError)
            break
    return chain


def locked_endpoint(transport: Any) -> Any:
    """The network endpoint under ``transport`` that locks onto one peer (``udpin``,
    ``udpout``, ``tcpin``: it has ``intrusions`` and ``identifies_peer``), or None."""
    for t in transport_chain(transport):
        if hasattr(t, "intrusions") and hasattr(t, "identifies_peer"):
            return t
    return None
