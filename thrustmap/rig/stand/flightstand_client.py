"""The gRPC link to a Tyto Flight Stand core through Tyto's official package: its URL
(``flightstand://HOST:PORT?board=&clear_cutoff=&timeout=``), every call with a deadline and
errors as ``FlightStandError``, the heartbeat thread the core requires while an output is
open, and the ``WatchSamples`` stream read on a thread into a bounded queue.

What the calls mean for a stand and its ESC (inputs, tare, cutoffs, the verified stop) is in
``rig.stand.flightstand``, which builds on this module.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from thrustmap.core.errors import ConfigError, ThrustmapError

SCHEME = "flightstand"
DEFAULT_PORT = 50051
HEARTBEAT_PERIOD_S = 0.25  # the service asks for one call per second at least; 1/2 s works
CALL_TIMEOUT_S = 1.0
SAMPLE_QUEUE_GROUPS = 20_000  # sample groups buffered between two reads (200 s at 100 Hz)


class FlightStandError(ThrustmapError):
    """The core refused a call or cannot be reached."""


def _package() -> tuple[Any, Any, Any]:
    """The official package's generated modules and grpc (``pip install thrustmap[flightstand]``)."""
    # gRPC's C core logs to stderr on its own (a refused bind, a dropped link): thrustmap says
    # what happened in one line itself; GRPC_VERBOSITY set by the user wins
    os.environ.setdefault("GRPC_VERBOSITY", "NONE")
    try:
        import grpc
        from FlightStand import flight_stand_api_v1_pb2 as fs
        from FlightStand import flight_stand_api_v1_pb2_grpc as fs_grpc
    except ImportError as exc:
        raise ConfigError(
            "flightstand:// needs Tyto's official Python API: pip install 'thrustmap[flightstand]'"
            f" ({exc})"
        ) from None
    return fs, fs_grpc, grpc


@dataclass(frozen=True)
class FlightStandUrl:
    address: str  # host:port
    board: str | None = None
    clear_cutoff: bool = False
    timeout_s: float = CALL_TIMEOUT_S


def parse_url(url: str) -> FlightStandUrl:
    """``flightstand://HOST[:PORT][?board=NAME&clear_cutoff=1&timeout=S]``."""
    parts = urlsplit(url)
    if parts.scheme.lower() != SCHEME or not parts.hostname:
        raise ConfigError(
            f"{url}: expected flightstand://HOST:PORT (e.g. flightstand://127.0.0.1:50051)"
        )
    try:
        port = parts.port or DEFAULT_PORT
    except ValueError:
        raise ConfigError(f"{url}: the port must be a number 1..65535") from None
    options = dict(parse_qsl(parts.query, keep_blank_values=True))
    unknown = sorted(set(options) - {"board", "clear_cutoff", "timeout"})
    if unknown:
        raise ConfigError(
            f"{url}: unknown option(s) {', '.join(unknown)}; expected board, clear_cutoff, timeout"
        )
    try:
        timeout_s = float(options.get("timeout", CALL_TIMEOUT_S))
    except ValueError:
        timeout_s = -1.0
    if not 0.05 <= timeout_s <= 30.0:
        raise ConfigError(f"{url}: timeout={options['timeout']!r}: expected seconds, 0.05 to 30")
    host = parts.hostname
    address = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    clear = options.get("clear_cutoff", "0").lower() in ("1", "true", "yes")
    return FlightStandUrl(address, options.get("board") or None, clear, timeout_s)


def seconds_of(ts: Any) -> float:
    """A protobuf ``Timestamp`` (a sample's or a group's time) in seconds."""
    return float(ts.seconds) + float(ts.nanos) * 1e-9


class FlightStandClient:
    """The gRPC channel to a core: every call with a deadline, errors as ``FlightStandError``;
    the heartbeat thread; the sample stream thread."""

    def __init__(self, address: str, *, timeout_s: float = CALL_TIMEOUT_S) -> None:
        self.fs, fs_grpc, self.grpc = _package()
        self.address = address
        self.timeout_s = timeout_s
        self.channel = self.grpc.insecure_channel(address)
        self.stub = fs_grpc.FlightStandStub(self.channel)
        self._heartbeat_stop = threading.Event()
        self._heartbeat: threading.Thread | None = None
        self.heartbeat_ok_s = time.monotonic()
        self.heartbeat_error: str | None = None
        self._watch: Any = None
        self._watch_thread: threading.Thread | None = None
        self.groups: deque[Any] = deque(maxlen=SAMPLE_QUEUE_GROUPS)
        self.groups_dropped = 0
        self.watch_error: str | None = None
        self._lock = threading.Lock()
        self._watch_stop = threading.Event()
        self._ack = threading.Event()

    def call(self, method: str, request: Any, *, timeout_s: float | None = None) -> Any:
        try:
            return getattr(self.stub, method)(request, timeout=timeout_s or self.timeout_s)
        except self.grpc.RpcError as exc:
            raise FlightStandError(
                f"Flight Stand core at {self.address}: {method} failed: "
                f"{exc.code().name} {exc.details() or ''}".rstrip()
            ) from None

    def code_of(self, exc: BaseException) -> str:
        text = str(exc)
        for code in ("FAILED_PRECONDITION", "UNAVAILABLE", "DEADLINE_EXCEEDED", "NOT_FOUND"):
            if f" {code}" in text:
                return code
        return ""

    # -- heartbeat ----------------------------------------------------------------------------
    def start_heartbeat(self) -> None:
        if self._heartbeat is not None:
            return
        self._heartbeat_stop.clear()
        self.heartbeat_ok_s = time.monotonic()
        self._heartbeat = threading.Thread(
            target=self._beat, name="flightstand-heartbeat", daemon=True
        )
        self._heartbeat.start()

    def _beat(self) -> None:
        request = self.fs.GetServerStatusRequest()
        while not self._heartbeat_stop.is_set():
            try:
                self.stub.GetServerStatus(request, timeout=2 * HEARTBEAT_PERIOD_S)
                self.heartbeat_ok_s = time.monotonic()
                self.heartbeat_error = None
            except self.grpc.RpcError as exc:
                self.heartbeat_error = f"{exc.code().name} {exc.details() or ''}".rstrip()
            except Exception as exc:  # the channel closed under us
                self.heartbeat_error = str(exc)
            self._heartbeat_stop.wait(HEARTBEAT_PERIOD_S)

    def stop_heartbeat(self) -> None:
        self._heartbeat_stop.set()
        if self._heartbeat is not None:
            self._heartbeat.join(timeout=2.0)
            self._heartbeat = None

    # -- samples ------------------------------------------------------------------------------
    def start_watch(self) -> None:
        """``WatchSamples``, used as the service requires: a request, then one more after each
        response (the acknowledgement); responses are read on a thread into a bounded queue."""
        self._watch_stop.clear()
        self._watch = self.stub.WatchSamples(self._watch_requests())
        self._watch_thread = threading.Thread(
            target=self._read_watch, name="flightstand-samples", daemon=True
        )
        self._watch_thread.start()

    def _watch_requests(self) -> Iterator[Any]:
        while not self._watch_stop.is_set():
            yield self.fs.WatchSamplesRequest()
            self._ack.wait(timeout=1.0)
            self._ack.clear()

    def _read_watch(self) -> None:
        try:
            for response in self._watch:
                with self._lock:
                    room = self.groups.maxlen or 0
                    extra = len(self.groups) + len(response.sample_groups) - room
                    if extra > 0:
                        self.groups_dropped += extra
                    self.groups.extend(response.sample_groups)
                self._ack.set()
            if not self._watch_stop.is_set():
                self.watch_error = "the core ended the sample stream"
        except self.grpc.RpcError as exc:
            if exc.code() != self.grpc.StatusCode.CANCELLED or not self._watch_stop.is_set():
                self.watch_error = (
                    f"sample stream: {exc.code().name} {exc.details() or ''}".rstrip()
                )
        except Exception as exc:
            self.watch_error = f"sample stream: {exc}"

    def take_groups(self) -> list[Any]:
        with self._lock:
            out = list(self.groups)
            self.groups.clear()
        return out

    def close(self) -> None:
        self.stop_heartbeat()
        self._watch_stop.set()
        self._ack.set()
        if self._watch is not None:
            self._watch.cancel()
        if self._watch_thread is not None:
            self._watch_thread.join(timeout=2.0)
        self.channel.close()
