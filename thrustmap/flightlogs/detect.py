"""Which reader opens a flight log: chosen by content (magic bytes, headers), suffix only as a hint.

Every reader is a module exposing two functions::

    def sniff(path: Path, head: bytes) -> bool        # cheap, no optional dependency needed
    def read(path: Path, **options: Any) -> list[FlightLog]   # one file may hold several flights

Readers are registered by module name and imported lazily, so a reader whose module or optional
dependency is missing is simply unavailable (and says so when it is the one a file needs); it
never breaks the others. Other modules may add readers with :func:`register`.
"""

from __future__ import annotations

import importlib
import logging
import struct
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any, cast

from thrustmap.core.errors import DataFormatError, ThrustmapError
from thrustmap.flightlogs.series import FlightLog

log = logging.getLogger(__name__)

#: bytes given to ``sniff``: enough for magic numbers and CSV header lines.
HEAD_BYTES = 8192


@dataclass(frozen=True)
class Reader:
    """A flight-log format: its name, the module that reads it and the suffixes it usually has."""

    name: str
    module: str
    description: str
    suffixes: tuple[str, ...] = ()
    #: the optional package the reader needs, named in the error when it is missing
    requires: str | None = None
    #: function names inside the module (a module may hold more than one reader)
    sniff_fn: str = "sniff"
    read_fn: str = "read"

    def load(self) -> ModuleType | None:
        """The reader module, or None when it (or its dependency) is not installed."""
        try:
            return importlib.import_module(self.module)
        except ImportError as exc:
            log.debug("flight-log reader %s unavailable: %s", self.name, exc)
            return None

    def unavailable_reason(self) -> str | None:
        try:
            importlib.import_module(self.module)
        except ImportError as exc:
            missing = getattr(exc, "name", None) or str(exc)
            if missing == self.module:
                return f"reader module {self.module} is not part of this installation"
            need = f" (pip install {self.requires})" if self.requires else ""
            return f"needs the optional package '{missing}'{need}"
        return None

    def sniff(self, path: Path, head: bytes) -> bool:
        module = self.load()
        if module is None:
            return False
        try:
            return bool(getattr(module, self.sniff_fn)(path, head))
        except Exception as exc:  # a sniffer must never take detection down
            log.debug("sniff %s on %s failed: %s", self.name, path, exc)
            return False

    def read(self, path: Path, **options: Any) -> list[FlightLog]:
        module = self.load()
        if module is None:
            raise DataFormatError(
                f"cannot read {self.description}: {self.unavailable_reason()}", file=str(path)
            )
        try:
            flights = getattr(module, self.read_fn)(path, **options)
        except ThrustmapError as exc:
            if exc.file is None:  # a reader's check deep inside (acc_1G, a scale): name the file
                exc.file = str(path)
            raise
        except _DECODE_ERRORS as exc:
            # A reader meeting bytes it cannot decode (a corrupt or crafted file) says so in one
            # line naming the file, never as an internal error.
            raise DataFormatError(
                f"corrupt or unreadable {self.description}: {_one_line(exc)}", file=str(path)
            ) from None
        return list(cast("list[FlightLog]", flights))


#: what decoding a malformed file raises inside a reader or its third-party parser
_DECODE_ERRORS: tuple[type[BaseException], ...] = (
    ValueError,  # includes UnicodeDecodeError, pandas ParserError, numpy shape errors
    IndexError,
    KeyError,
    struct.error,
    OverflowError,
    RecursionError,
    ZeroDivisionError,
    EOFError,
)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if len(text) > 200:
        text = text[:200] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


_PKG = "thrustmap.flightlogs"

#: Ordered: more specific magic first; the generic CSV reader last.
READERS: list[Reader] = [
    Reader("ulog", f"{_PKG}.ulog", "PX4 ULog", (".ulg",), requires="pyulog"),
    Reader("dataflash", f"{_PKG}.dataflash", "ArduPilot DataFlash log", (".bin",)),
    Reader("tlog", f"{_PKG}.tlog", "MAVLink telemetry log", (".tlog",), requires="pymavlink"),
    Reader("blackbox", f"{_PKG}.blackbox", "Betaflight blackbox log", (".bbl", ".bfl", ".txt")),
    Reader(
        "blackbox-csv",
        f"{_PKG}.blackbox_csv",
        "Betaflight blackbox_decode CSV",
        (".csv",),
    ),
    Reader("rosbag", f"{_PKG}.rosbag", "ROS 2 bag (Aerostack2)", (".db3", ".mcap"), "rosbags"),
    Reader("paper-csv", f"{_PKG}.paper_csv", "seed paper flight CSV", (".csv",)),
    Reader(
        "csv",
        f"{_PKG}.paper_csv",
        "generic flight CSV (column map)",
        (".csv",),
        sniff_fn="sniff_generic",
        read_fn="read_generic",
    ),
]


def register(reader: Reader, *, before: str | None = None) -> None:
    """Add (or replace, by name) a reader; ``before`` puts it ahead of another in sniff order."""
    for i, existing in enumerate(READERS):
        if existing.name == reader.name:
            READERS[i] = reader
            return
    if before is not None:
        for i, existing in enumerate(READERS):
            if existing.name == before:
                READERS.insert(i, reader)
                return
    READERS.append(reader)


def get_reader(name: str) -> Reader:
    for reader in READERS:
        if reader.name == name:
            return reader
    known = ", ".join(r.name for r in READERS)
    from thrustmap.core.errors import ConfigError

    raise ConfigError(f"unknown flight-log format '{name}'; expected one of: {known}")


def read_head(path: Path, n: int = HEAD_BYTES) -> bytes:
    if path.is_dir():
        return b""
    try:
        with open(path, "rb") as f:
            return f.read(n)
    except OSError as exc:
        raise DataFormatError(f"cannot open flight log: {exc.strerror}", file=str(path)) from None


def detect(path: str | Path) -> Reader:
    """The reader for ``path``, by content; raises DataFormatError naming what was tried."""
    p = Path(path)
    if not p.exists():
        raise DataFormatError("flight log not found", file=str(p))
    head = read_head(p)
    if not p.is_dir() and not head:
        raise DataFormatError("flight log is empty (0 bytes)", file=str(p))
    for reader in READERS:
        if reader.sniff(p, head):
            log.debug("%s: detected %s", p, reader.name)
            return reader
    # Nothing matched by content. If the suffix names a reader that is unavailable, say why.
    suffix = p.suffix.lower()
    for reader in READERS:
        if suffix in reader.suffixes:
            reason = reader.unavailable_reason()
            if reason is not None and "not part of this installation" not in reason:
                raise DataFormatError(
                    f"looks like a {reader.description} but {reason}", file=str(p)
                )
    if p.is_dir():  # only a ROS 2 bag is read as a folder
        raise DataFormatError(
            "is a folder, not a ROS 2 bag: name the log files in it (thrustmap fleet extract "
            "FOLDER reads every log in a folder)",
            file=str(p),
        )
    known = "; ".join(f"{r.name} ({r.description})" for r in READERS)
    raise DataFormatError(
        f"unrecognised flight-log format (first bytes {head[:16]!r}); readers tried: {known}",
        file=str(p),
    )


def read_log(path: str | Path, *, format: str | None = None, **options: Any) -> list[FlightLog]:
    """Read every flight in ``path`` (auto-detected unless ``format`` names a reader)."""
    p = Path(path)
    reader = get_reader(format) if format else detect(p)
    if format and not p.exists():
        raise DataFormatError("flight log not found", file=str(p))
    flights = reader.read(p, **options)
    if not flights:
        raise DataFormatError(f"{reader.description} holds no flight data", file=str(p))
    return flights


def available() -> list[tuple[Reader, str | None]]:
    """Every registered reader with the reason it is unavailable (None when usable)."""
    return [(r, r.unavailable_reason()) for r in READERS]
