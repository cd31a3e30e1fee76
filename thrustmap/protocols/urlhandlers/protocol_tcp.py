"""``tcp://host:port``: a raw TCP byte stream, the same as pyserial's ``socket://``.

Betaflight and INAV SITL builds serve MSP on TCP (Betaflight: 5760 + UART number, so UART1 is
5761), and users type ``tcp://``. This handler makes that form open exactly what
``socket://host:port`` opens, so it works wherever a URL is accepted (probing included).
"""

from __future__ import annotations

from typing import Any

from serial.urlhandler import protocol_socket


class Serial(protocol_socket.Serial):
    def from_url(self, url: str) -> Any:
        if url.lower().startswith("tcp://"):
            url = "socket://" + url[len("tcp://") :]
        return super().from_url(url)
