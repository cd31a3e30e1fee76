"""Slow links on purpose: a fixed delay on every byte a device sends back.

Real links to a flight controller are slow in ways a bench on a USB cable never shows: a
Betaflight SITL on a loaded machine answers MSP in 10..680 ms, radio and Bluetooth MSP bridges
take longer. Two ways to put such a link in front of a device:

- :class:`LaggedPeer` wraps a simulated ``BytePeer`` (``sim://`` on a simulated clock): bytes the
  device sends at ``t`` reach the host at ``t + delay_s``. Deterministic; for tests and
  benchmarks.
- :class:`LatencyProxy` is a TCP proxy (one client at a time, as a SITL's MSP port): bytes from
  the device reach the client ``delay_s`` after they arrived, in order; bytes from the client
  pass at once. When the client goes, the proxy drops the device connection too (a SITL then
  takes the next client). Run it from a shell in front of a real SITL (from ``tests/``)::

      python -m support.latency_proxy --listen 5762 --to 127.0.0.1:5761 --delay-ms 500
      thrustmap probe tcp://127.0.0.1:5762

The proxy listens on 127.0.0.1 only unless another address is named (``host=``,
``--host ADDR``): it forwards motor commands, so nobody else on the network may reach it.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import logging
import select
import socket
import threading
import time
from dataclasses import dataclass, field

from support.sockets import tcp_listener
from thrustmap.protocols.peer import BytePeer

log = logging.getLogger(__name__)

LOOPBACK = "127.0.0.1"


class LaggedPeer:
    """A ``BytePeer`` whose replies arrive ``delay_s`` after the wrapped peer sent them."""

    def __init__(self, inner: BytePeer, delay_s: float) -> None:
        self.inner = inner
        self.delay_s = delay_s
        self._in_flight: collections.deque[tuple[float, bytes]] = collections.deque()

    def write(self, data: bytes, now_s: float) -> None:
        self._pull(now_s)
        self.inner.write(data, now_s)

    def read(self, now_s: float) -> bytes:
        self._pull(now_s)
        out = bytearray()
        while self._in_flight and self._in_flight[0][0] <= now_s:
            out += self._in_flight.popleft()[1]
        return bytes(out)

    def _pull(self, now_s: float) -> None:
        data = self.inner.read(now_s)
        if data:
            self._in_flight.append((now_s + self.delay_s, data))

    def close(self) -> None:
        close = getattr(self.inner, "close", None)
        if callable(close):
            close()

    def __getattr__(self, name: str) -> object:  # the wrapped peer's state, for tests
        return getattr(self.inner, name)


@dataclass
class LatencyProxy:
    """TCP proxy delaying device-to-client bytes by ``delay_s`` (see the module)."""

    upstream: tuple[str, int]
    delay_s: float
    host: str = LOOPBACK  # loopback unless the caller names another address
    port: int = 0
    #: connections served so far
    connections: int = 0
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _listener: socket.socket | None = None

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    def start(self) -> LatencyProxy:
        listener = tcp_listener(self.host, self.port, 4)
        self.port = listener.getsockname()[1]
        self._listener = listener
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name="latency-proxy", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        if self._listener is not None:
            self._listener.close()
        self._thread = self._listener = None

    def __enter__(self) -> LatencyProxy:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _serve(self) -> None:
        assert self._listener is not None
        while not self._stop.is_set():
            ready, _, _ = select.select([self._listener], [], [], 0.1)
            if not ready:
                continue
            client, _ = self._listener.accept()
            self.connections += 1
            try:
                device = socket.create_connection(self.upstream, timeout=5.0)
            except OSError as exc:
                log.warning("latency proxy: cannot reach %s: %s", self.upstream, exc)
                client.close()
                continue
            with client, device:
                self._pipe(client, device)

    def _pipe(self, client: socket.socket, device: socket.socket) -> None:
        """Until either side closes: client bytes go on at once, device bytes after delay_s."""
        in_flight: collections.deque[tuple[float, bytes]] = collections.deque()
        client.setblocking(False)
        device.setblocking(False)
        while not self._stop.is_set():
            now = time.monotonic()
            wait = 0.05
            if in_flight:
                wait = max(0.0, min(wait, in_flight[0][0] - now))
            ready, _, _ = select.select([client, device], [], [], wait)
            try:
                if client in ready:
                    data = client.recv(4096)
                    if not data:
                        return
                    device.sendall(data)
                if device in ready:
                    data = device.recv(4096)
                    if not data:
                        return
                    in_flight.append((time.monotonic() + self.delay_s, data))
                now = time.monotonic()
                while in_flight and in_flight[0][0] <= now:
                    client.setblocking(True)
                    client.sendall(in_flight.popleft()[1])
                    client.setblocking(False)
            except OSError:
                return


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m support.latency_proxy",
        description="TCP proxy adding a fixed delay to every reply (test a slow MSP link).",
    )
    parser.add_argument("--listen", type=int, required=True, help="local TCP port to serve")
    parser.add_argument(
        "--host",
        default=LOOPBACK,
        help="address to listen on (default 127.0.0.1: this computer only; name another, "
        "e.g. 0.0.0.0, only to let other hosts reach the device through the proxy)",
    )
    parser.add_argument("--to", required=True, help="HOST:PORT of the device (e.g. a SITL)")
    parser.add_argument("--delay-ms", type=float, required=True, help="delay per reply, ms")
    args = parser.parse_args(argv)
    host, _, port = args.to.rpartition(":")
    proxy = LatencyProxy(
        (host or "127.0.0.1", int(port)), args.delay_ms / 1000, host=args.host, port=args.listen
    )
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.host != LOOPBACK:
        log.warning("the proxy listens on %s: other hosts can reach the device", args.host)
    with proxy:
        log.info("proxy %s -> %s, +%g ms per reply", proxy.url, args.to, args.delay_ms)
        with contextlib.suppress(KeyboardInterrupt):
            while True:
                time.sleep(1.0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
