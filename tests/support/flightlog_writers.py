"""Minimal binary writers for the flight-log formats the project reads (for simulated fixtures).

They write what the real firmware writes for the fields the readers use, following the public
format descriptions (PX4 ULog file format, ArduPilot DataFlash FMT messages, MAVLink .tlog =
8-byte big-endian µs timestamp + frame). They are not general-purpose log writers.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

# -- PX4 ULog ----------------------------------------------------------------------------------

_ULOG_CODES = {
    "uint64_t": "Q",
    "int64_t": "q",
    "uint32_t": "I",
    "int32_t": "i",
    "uint16_t": "H",
    "int16_t": "h",
    "uint8_t": "B",
    "int8_t": "b",
    "bool": "?",
    "float": "f",
    "double": "d",
}


@dataclass
class ULogTopic:
    """One topic: its fields (type, name, array length or 0) and rows (timestamp µs first)."""

    name: str
    fields: list[tuple[str, str, int]]
    rows: list[tuple[Any, ...]] = field(default_factory=list)
    multi_id: int = 0

    @property
    def struct(self) -> struct.Struct:
        codes = "".join(
            (str(n) if n else "") + _ULOG_CODES[t]
            for t, _, n in [("uint64_t", "", 0)] + self.fields
        )
        return struct.Struct("<" + codes)

    def format_text(self) -> bytes:
        parts = ["uint64_t timestamp;"] + [
            f"{t}[{n}] {name};" if n else f"{t} {name};" for t, name, n in self.fields
        ]
        return (self.name + ":" + "".join(parts)).encode("ascii")


def _ulog_msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def write_ulog(
    path: str | Path,
    topics: Sequence[ULogTopic],
    *,
    info: dict[str, str | int] | None = None,
    params: dict[str, float | int] | None = None,
    start_us: int = 1_000_000,
) -> None:
    """Write a ULog (version 1) with the given topics, info strings/ints and parameters."""
    out = bytearray(b"ULog\x01\x12\x35" + b"\x01" + struct.pack("<Q", start_us))
    out += _ulog_msg(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    for t in {t.name: t for t in topics}.values():
        out += _ulog_msg(b"F", t.format_text())
    for key, value in (info or {}).items():
        if isinstance(value, int):
            k = f"uint32_t {key}".encode()
            out += _ulog_msg(b"I", bytes([len(k)]) + k + struct.pack("<I", value))
        else:
            k = f"char[{len(value)}] {key}".encode()
            out += _ulog_msg(b"I", bytes([len(k)]) + k + value.encode())
    for key, pvalue in (params or {}).items():
        if isinstance(pvalue, int):
            k = f"int32_t {key}".encode()
            out += _ulog_msg(b"P", bytes([len(k)]) + k + struct.pack("<i", pvalue))
        else:
            k = f"float {key}".encode()
            out += _ulog_msg(b"P", bytes([len(k)]) + k + struct.pack("<f", pvalue))
    items: list[tuple[int, int, bytes]] = []
    for msg_id, t in enumerate(topics):
        out += _ulog_msg(b"A", struct.pack("<BH", t.multi_id, msg_id) + t.name.encode())
        st = t.struct
        for row in t.rows:
            flat: list[Any] = []
            for v in row:
                flat.extend(v if isinstance(v, (list, tuple)) else [v])
            items.append((int(row[0]), msg_id, struct.pack("<H", msg_id) + st.pack(*flat)))
    items.sort(key=lambda x: (x[0], x[1]))
    for _, _, payload in items:
        out += _ulog_msg(b"D", payload)
    Path(path).write_bytes(bytes(out))


# -- ArduPilot DataFlash -----------------------------------------------------------------------

_DF_CODES = {
    "b": "b", "B": "B", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "d": "d",
    "n": "4s", "N": "16s", "Z": "64s", "c": "h", "C": "H", "e": "i", "E": "I", "L": "i",
    "M": "B", "q": "q", "Q": "Q",
}  # fmt: skip


class DataFlashWriter:
    """Writes FMT messages on first use, then messages (values given in stored units)."""

    def __init__(self, f: BinaryIO) -> None:
        self.f = f
        self.types: dict[str, tuple[int, struct.Struct]] = {}
        self._next_type = 129
        self._define("FMT", 128, "BBnNZ", "Type,Length,Name,Format,Columns")

    def _define(self, name: str, type_id: int, fmt: str, columns: str) -> None:
        st = struct.Struct("<" + "".join(_DF_CODES[c] for c in fmt))
        self.types[name] = (type_id, st)
        fmt_st = struct.Struct("<BBB" + "BB4s16s64s")
        self.f.write(
            fmt_st.pack(
                0xA3, 0x95, 128, type_id, st.size + 3, name.encode(), fmt.encode(), columns.encode()
            )
        )

    def define(self, name: str, fmt: str, columns: str) -> None:
        if name not in self.types:
            self._define(name, self._next_type, fmt, columns)
            self._next_type += 1

    def write(self, name: str, *values: Any) -> None:
        type_id, st = self.types[name]
        self.f.write(bytes((0xA3, 0x95, type_id)) + st.pack(*values))


# -- MAVLink tlog ------------------------------------------------------------------------------


class TlogWriter:
    """Writes MAVLink 2 frames with the .tlog timestamp prefix (µs since the Unix epoch)."""

    def __init__(self, f: BinaryIO, *, system_id: int = 1, component_id: int = 1) -> None:
        from pymavlink.dialects.v20 import common

        self.f = f
        self.mav = common.MAVLink(None, srcSystem=system_id, srcComponent=component_id)

    def write(self, t_unix_s: float, msg: Any) -> None:
        self.f.write(struct.pack(">Q", int(round(t_unix_s * 1e6))) + msg.pack(self.mav))

    def encoder(self) -> Any:
        return self.mav


def as_int(x: float | np.floating[Any]) -> int:
    return int(round(float(x)))
