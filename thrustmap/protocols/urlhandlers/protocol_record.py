"""``record://<inner url>?file=x.jsonl`` — tap every read and write of any pyserial transport.

URL rule: everything after ``record://`` is the inner URL, except the query parameters the
recorder owns, which are removed before the inner URL is opened:

- ``file`` (required): transcript path, percent-encoded if it contains ``&``, ``?``, ``%`` or ``#``.
- ``baudrate`` (optional): overrides the ``baudrate=`` keyword for the inner port.

Any other query parameters stay with the inner URL, in order. Examples::

    record:///dev/ttyACM0?file=run1.jsonl&baudrate=115200   -> /dev/ttyACM0
    record://COM3?file=run1.jsonl                            -> COM3
    record://sim://px4?motors=4&file=px4.jsonl               -> sim://px4?motors=4
    record://loop://?file=loop.jsonl                         -> loop://
    record://socket://192.168.4.1:23?file=wifi.jsonl         -> socket://192.168.4.1:23
    record://udpin:0.0.0.0:14550?file=px4.jsonl              -> udpin://0.0.0.0:14550
    record://udpout:192.168.1.5:14550?file=px4.jsonl         -> udpout://192.168.1.5:14550

UDP (pymavlink's ``udpin:``/``udpout:``/``udp:`` spellings, or ``udpin://``) is what PX4 SITL and
most companion links speak. One transcript event is written per read or write CALL with all the
bytes of that call, so the transcript grows with the number of calls, not of bytes (MAVLink
links read a whole burst per call), and recording keeps up with a link streaming 20 kB/s.

Keyword arguments (``timeout``, ``baudrate``, ...) apply to the inner port; ``clock=`` is used for
the timestamps and handed on to an inner ``sim://``/``record://``/``replay://``.

Direct form: ``RecordingSerial(inner_port, TranscriptWriter(...), clock)`` wraps an open port.
"""

from __future__ import annotations

import logging
from typing import Any
from urllib.parse import quote, unquote

import serial
from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from thrustmap.core.clock import Clock, MonotonicClock
from thrustmap.protocols.transcript import TranscriptWriter
from thrustmap.protocols.transport import register_url_handlers
from thrustmap.protocols.urlhandlers.protocol_udpin import is_udp_url, normalize_udp_url

log = logging.getLogger(__name__)

OWN_OPTIONS = ("file", "baudrate")
CLOCK_AWARE_SCHEMES = ("sim", "record", "replay")


def split_record_url(url: str) -> tuple[str, dict[str, str]]:
    """``record://<inner>?...`` -> (inner URL, the recorder's own options)."""
    if not url.lower().startswith("record://"):
        raise SerialException(f"expected record://<inner url>?file=x.jsonl, got {url!r}")
    rest = url[len("record://") :]
    base, sep, query = rest.partition("?")
    own: dict[str, str] = {}
    kept: list[str] = []
    for part in query.split("&") if sep else []:
        if not part:
            continue
        key, _, value = part.partition("=")
        if unquote(key) in OWN_OPTIONS:
            own[unquote(key)] = unquote(value)
        else:
            kept.append(part)
    inner = base + ("?" + "&".join(kept) if kept else "")
    if is_udp_url(inner):
        inner = normalize_udp_url(inner)
    if not base:
        raise SerialException(f"record:// needs an inner URL or device path: {url!r}")
    if "file" not in own:
        raise SerialException(f"record:// needs ?file=<transcript.jsonl>: {url!r}")
    return inner, own


def record_url(inner: str, file: str) -> str:
    """Build a ``record://`` URL (percent-encodes the file name)."""
    sep = "&" if "?" in inner else "?"
    return f"record://{inner}{sep}file={quote(file, safe='/:')}"


class RecordingSerial(SerialBase):
    """Forwards everything to ``inner`` and logs writes and non-empty reads to ``writer``."""

    def __init__(
        self,
        inner: Any | None = None,
        writer: TranscriptWriter | None = None,
        clock: Clock | None = None,
        **serial_kwargs: Any,
    ) -> None:
        self._inner: Any | None = inner
        self._writer: TranscriptWriter | None = writer
        self._clock: Clock = clock if clock is not None else MonotonicClock()
        serial_kwargs.pop("port", None)
        if inner is not None:
            # Mirror the inner port's settings without touching it.
            serial_kwargs.setdefault("timeout", inner.timeout)
            serial_kwargs.setdefault("baudrate", getattr(inner, "baudrate", 9600))
        super().__init__(port=None, **serial_kwargs)
        if inner is not None:
            self._port = f"record://{getattr(inner, 'port', None) or type(inner).__name__}"
            self.is_open = True

    @property
    def inner(self) -> Any:
        if self._inner is None:
            raise PortNotOpenError()
        return self._inner

    @property
    def writer(self) -> TranscriptWriter | None:
        return self._writer

    def note(self, text: str) -> None:
        """Write a marker into the transcript (ignored by replay)."""
        if self._writer is not None:
            self._writer.note(text, self._clock.now_s())

    # -- pyserial plumbing ------------------------------------------------------------------
    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        inner_url, own = split_record_url(self._port)
        register_url_handlers()
        baudrate = int(own["baudrate"]) if "baudrate" in own else self.baudrate
        kwargs: dict[str, Any] = {
            "baudrate": baudrate,
            "timeout": self.timeout,
            "write_timeout": self.write_timeout,
        }
        if inner_url.split("://", 1)[0].lower() in CLOCK_AWARE_SCHEMES:
            kwargs["clock"] = self._clock
        self.baudrate = baudrate  # not open yet: no reconfigure
        self._inner = serial.serial_for_url(inner_url, **kwargs)
        try:
            self._writer = TranscriptWriter(
                own["file"],
                inner=inner_url,
                origin_s=self._clock.now_s(),
                extra={"baudrate": baudrate, "clock": type(self._clock).__name__},
            )
        except OSError as exc:
            self._inner.close()
            raise SerialException(
                f"record://: cannot write transcript {own['file']!r}: {exc}"
            ) from exc
        self.is_open = True

    def _reconfigure_port(self) -> None:
        if self._inner is not None and self.is_open:
            self._inner.timeout = self.timeout
            self._inner.write_timeout = self.write_timeout
            if getattr(self._inner, "baudrate", None) != self.baudrate:
                self._inner.baudrate = self.baudrate

    def _update_dtr_state(self) -> None:
        if self._inner is not None:
            self._inner.dtr = self.dtr
            self.note(f"dtr {int(bool(self.dtr))}")  # a board's reset line: kept in the record

    def _update_rts_state(self) -> None:
        if self._inner is not None:
            self._inner.rts = self.rts

    def _update_break_state(self) -> None:
        if self._inner is not None:
            self._inner.break_condition = self.break_condition

    def close(self) -> None:
        if not self.is_open:
            return
        self.is_open = False
        try:
            if self._inner is not None:
                self._inner.close()
        finally:
            if self._writer is not None:
                self._writer.close()

    # -- data ------------------------------------------------------------------------------
    @property
    def in_waiting(self) -> int:
        return int(self.inner.in_waiting)

    def read(self, size: int = 1, /) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        data = bytes(self.inner.read(size))
        if data and self._writer is not None:
            self._writer.event("r", data, self._clock.now_s())
        return data

    def write(self, b: Any, /) -> int | None:
        if not self.is_open:
            raise PortNotOpenError()
        data = bytes(b)
        written = self.inner.write(data)
        if self._writer is not None and data:
            sent = data if written is None else data[: int(written)]
            self._writer.event("w", sent, self._clock.now_s())
        return written  # type: ignore[no-any-return]

    def flush(self) -> None:
        self.inner.flush()

    def reset_input_buffer(self) -> None:
        self.inner.reset_input_buffer()

    def reset_output_buffer(self) -> None:
        self.inner.reset_output_buffer()


class Serial(RecordingSerial):
    """The class pyserial instantiates for ``record://`` URLs."""

    def __init__(
        self, port: str | None = None, *args: Any, clock: Clock | None = None, **kwargs: Any
    ):
        if args:
            raise TypeError("record:// takes keyword arguments only (timeout=..., clock=...)")
        super().__init__(None, None, clock, **kwargs)
        if port is not None:
            self.port = port
            self.open()
