"""Serial transcripts: every byte a driver wrote and read, with monotonic timestamps.

Format (JSON Lines, UTF-8, one object per line, version 1)::

    {"format": "thrustmap.transcript", "version": 1, "inner": "sim://px4", "created_utc": "...", ...}
    {"t": 0.000120, "dir": "w", "hex": "fd09000000ff00..."}
    {"t": 0.010500, "dir": "r", "hex": "fd1c0000010101..."}
    {"t": 0.020000, "note": "marker: step 3"}

- ``t`` is seconds since the transport was opened on the recording clock (monotonic, never
  decreasing). ``dir`` is ``"w"`` (host to device) or ``"r"`` (device to host, as the driver
  read it: a read is recorded when the driver reads it, not when it arrived). ``hex`` is the
  bytes in lowercase hex. ``note`` events carry free text (markers) and never affect replay.
- Extra header keys are allowed and preserved (``extra``); a reader rejects a newer version.
- The writer flushes after every line, so a killed process loses at most the line being written.

Pure file I/O only; no serial ports here (see ``thrustmap.protocols.urlhandlers``).
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import math
import os
import stat
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Literal

from thrustmap.core.errors import DataFormatError, ThrustmapError
from thrustmap.core.jsonfile import loads_json

log = logging.getLogger(__name__)

FORMAT_NAME = "thrustmap.transcript"
FORMAT_VERSION = 1

Direction = Literal["w", "r"]


class TranscriptFormatError(DataFormatError):
    """A transcript file is unreadable: names the file, the line and what was expected."""


class TransportError(ThrustmapError):
    """Base of the typed errors raised by thrustmap's own transports."""


@dataclass(frozen=True)
class TranscriptEvent:
    """One line of a transcript after the header. ``data`` is empty for notes."""

    time_s: float
    direction: Direction | None  # None for a note
    data: bytes = b""
    note: str | None = None
    line: int = 0  # 1-based line number in the file (0 when not read from a file)


@dataclass(frozen=True)
class TranscriptHeader:
    inner: str
    created_utc: str
    version: int = FORMAT_VERSION
    extra: Mapping[str, object] = field(default_factory=dict)


@dataclass(frozen=True)
class Transcript:
    path: str
    header: TranscriptHeader
    events: tuple[TranscriptEvent, ...]

    def written(self) -> bytes:
        """Everything the host wrote, concatenated."""
        return b"".join(e.data for e in self.events if e.direction == "w")

    def read(self) -> bytes:
        """Everything the host read, concatenated."""
        return b"".join(e.data for e in self.events if e.direction == "r")

    def notes(self) -> list[tuple[float, str]]:
        return [(e.time_s, e.note) for e in self.events if e.note is not None]


class TranscriptWriter:
    """Appends events to a transcript file, flushing every line.

    ``time_s`` values passed in are absolute clock readings; the writer stores them relative to
    ``origin_s`` (the clock reading at open).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        inner: str,
        origin_s: float,
        extra: Mapping[str, object] | None = None,
    ) -> None:
        self.path = str(path)
        self._origin_s = origin_s
        self._last_t = 0.0
        self._file: IO[str] | None = open(self.path, "w", encoding="utf-8")  # noqa: SIM115
        header: dict[str, object] = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "inner": inner,
            "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        }
        for key, value in (extra or {}).items():
            if key not in header:
                header[key] = value
        self._write_line(header)

    @property
    def closed(self) -> bool:
        return self._file is None

    def _write_line(self, obj: Mapping[str, object]) -> None:
        if self._file is None:
            raise TransportError(f"transcript {self.path} is already closed")
        self._file.write(json.dumps(obj, separators=(",", ":")) + "\n")
        self._file.flush()

    def _relative(self, time_s: float) -> float:
        # Never go backwards, even if a caller's clock does: the format promises monotonic t.
        t = max(self._last_t, time_s - self._origin_s)
        self._last_t = t
        return round(t, 9)

    def event(self, direction: Direction, data: bytes, time_s: float) -> None:
        if not data:
            return
        self._write_line({"t": self._relative(time_s), "dir": direction, "hex": data.hex()})

    def note(self, text: str, time_s: float) -> None:
        self._write_line({"t": self._relative(time_s), "note": text})

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> TranscriptWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _fail(path: str, line: int, message: str) -> TranscriptFormatError:
    return TranscriptFormatError(message, file=path, line=line)


def _parse_header(path: str, text: str) -> TranscriptHeader:
    try:
        obj = loads_json(text, source=path)
    except DataFormatError as exc:
        raise _fail(path, 1, f"expected a JSON header line, got {exc.message}") from None
    if not isinstance(obj, dict) or obj.get("format") != FORMAT_NAME:
        raise _fail(path, 1, f'expected a header object with "format": "{FORMAT_NAME}"')
    version = obj.get("version")
    if not isinstance(version, int) or isinstance(version, bool):
        raise _fail(path, 1, 'expected an integer "version" in the header')
    if version > FORMAT_VERSION or version < 1:
        raise _fail(
            path,
            1,
            f"transcript version {version} is not supported (this reader: 1..{FORMAT_VERSION})",
        )
    inner = obj.get("inner", "")
    created = obj.get("created_utc", "")
    extra = {k: v for k, v in obj.items() if k not in ("format", "version", "inner", "created_utc")}
    return TranscriptHeader(
        inner=str(inner), created_utc=str(created), version=version, extra=extra
    )


def _parse_event(path: str, lineno: int, text: str, last_t: float) -> TranscriptEvent:
    if text.count("{") + text.count("[") > 8:  # events are flat objects: no deep nesting
        raise _fail(path, lineno, "expected one flat JSON event object, got nested JSON")
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise _fail(
            path, lineno, f"expected one JSON event object, got invalid JSON ({exc.msg})"
        ) from None
    if not isinstance(obj, dict):
        raise _fail(path, lineno, "expected a JSON object with keys t, dir, hex (or t, note)")
    t = obj.get("t")
    if not isinstance(t, (int, float)) or isinstance(t, bool) or not math.isfinite(t):
        raise _fail(path, lineno, 'expected a finite number "t" (seconds since open)')
    if t < last_t:
        raise _fail(path, lineno, f"time goes backwards: t={t} after t={last_t}")
    if "note" in obj:
        return TranscriptEvent(time_s=float(t), direction=None, note=str(obj["note"]), line=lineno)
    direction = obj.get("dir")
    if direction not in ("w", "r"):
        raise _fail(path, lineno, f'expected "dir" to be "w" or "r", got {direction!r}')
    hex_text = obj.get("hex")
    if not isinstance(hex_text, str):
        raise _fail(path, lineno, 'expected a "hex" string of bytes')
    try:
        data = bytes.fromhex(hex_text)
    except ValueError:
        raise _fail(
            path, lineno, f'"hex" is not an even-length hex string: {hex_text[:40]!r}'
        ) from None
    if not data:
        raise _fail(path, lineno, '"hex" is empty (events carry at least one byte)')
    return TranscriptEvent(time_s=float(t), direction=direction, data=data, line=lineno)


def iter_transcript(
    path: str | os.PathLike[str], *, drop_truncated_tail: bool = False
) -> Iterator[TranscriptEvent | TranscriptHeader]:
    """Yield the header, then each event. Raises ``TranscriptFormatError`` with file:line.

    ``drop_truncated_tail``: a last line without a newline that fails to parse (the recording
    process died mid-write) is dropped with a warning instead of raising.
    """
    name = str(path)
    for number, text, is_last, complete in _bounded_lines(name):
        if number == 1:
            if not text.strip():
                raise _fail(name, 1, "empty transcript: expected a header line")
            yield _parse_header(name, text)
            last_t = 0.0
            continue
        if not text.strip():
            continue
        try:
            event = _parse_event(name, number, text, last_t)
        except TranscriptFormatError:
            if drop_truncated_tail and is_last and not complete:
                log.warning("%s:%d: dropped a truncated last line", name, number)
                return
            raise
        last_t = event.time_s
        yield event


#: a transcript is read only from a regular file, at most this large; a line at most this long
#: (a day of a 115200-baud link is ~2 GB of hex, but a sweep's transcript is a few MB)
MAX_TRANSCRIPT_BYTES = 256 * 1024 * 1024
MAX_LINE_CHARS = 1024 * 1024


def _bounded_lines(name: str) -> Iterator[tuple[int, str, bool, bool]]:
    """(line number, text, is it the last line, did it end with a newline), streamed.

    Only a regular file is read (never a device, FIFO or socket a path may name), its size is
    checked first and every line is read with a length limit, so no transcript can make the
    reader take unbounded time or memory."""
    try:
        st = os.stat(name)
    except FileNotFoundError:
        raise TranscriptFormatError("transcript file not found", file=name) from None
    except OSError as exc:
        raise TranscriptFormatError(f"cannot read transcript: {exc.strerror}", file=name) from None
    if not stat.S_ISREG(st.st_mode):
        raise TranscriptFormatError("expected a transcript file, not a device or folder", file=name)
    if st.st_size > MAX_TRANSCRIPT_BYTES:
        raise TranscriptFormatError(
            f"transcript is {st.st_size} bytes; expected at most {MAX_TRANSCRIPT_BYTES}", file=name
        )
    try:
        with open(name, encoding="utf-8", newline="\n") as fh:
            number = 0
            current = fh.readline(MAX_LINE_CHARS + 1)
            if not current:
                raise _fail(name, 1, "empty transcript: expected a header line")
            while current:
                number += 1
                complete = current.endswith("\n")
                if not complete and len(current) > MAX_LINE_CHARS:
                    raise _fail(name, number, f"line longer than {MAX_LINE_CHARS} characters")
                nxt = fh.readline(MAX_LINE_CHARS + 1)
                yield number, current.rstrip("\n").rstrip("\r"), not nxt, complete
                current = nxt
    except UnicodeDecodeError as exc:
        raise TranscriptFormatError(f"not UTF-8 text ({exc.reason})", file=name) from None
    except OSError as exc:
        raise TranscriptFormatError(f"cannot read transcript: {exc.strerror}", file=name) from None


def read_transcript(
    path: str | os.PathLike[str], *, drop_truncated_tail: bool = False
) -> Transcript:
    header: TranscriptHeader | None = None
    events: list[TranscriptEvent] = []
    for item in iter_transcript(path, drop_truncated_tail=drop_truncated_tail):
        if isinstance(item, TranscriptHeader):
            header = item
        else:
            events.append(item)
    assert header is not None  # iter_transcript always yields the header first or raises
    return Transcript(path=str(Path(path)), header=header, events=tuple(events))
