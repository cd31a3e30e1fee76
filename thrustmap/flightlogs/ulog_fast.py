"""A vectorised ULog reader for the topics Df needs (pyulog stays the fallback).

pyulog decodes every message in a Python loop (a 4 MB log holds ~130 000), which made
``flightlog extract`` slower than a plain pyulog load once the integrity walk was added. Here one
tight loop records where each message starts (and checks the chain as the walk did); the data
messages of each needed topic are then gathered and decoded by numpy as packed little-endian
records, with pyulog's field names (arrays flattened to ``name[i]``, trailing padding dropped).

Anything unusual returns None so that the caller uses pyulog: appended data, unknown
incompatible flags, nested types in a needed topic, unknown message types (corruption). The
values are those pyulog gives (tests compare both on every fixture and shared log).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

#: pyulog's type table: ULog type -> (numpy dtype, size)
_TYPES: dict[str, tuple[str, int]] = {
    "int8_t": ("i1", 1), "uint8_t": ("u1", 1), "int16_t": ("<i2", 2), "uint16_t": ("<u2", 2),
    "int32_t": ("<i4", 4), "uint32_t": ("<u4", 4), "int64_t": ("<i8", 8), "uint64_t": ("<u8", 8),
    "float": ("<f4", 4), "double": ("<f8", 8), "bool": ("i1", 1), "char": ("i1", 1),
}  # fmt: skip
_STRUCT = {
    "int8_t": "b", "uint8_t": "B", "int16_t": "h", "uint16_t": "H", "int32_t": "i",
    "uint32_t": "I", "int64_t": "q", "uint64_t": "Q", "float": "f", "double": "d", "bool": "?",
}  # fmt: skip
_KNOWN = frozenset(b"BFIMPQARDLCSO")
_KNOWN_TYPES = np.frombuffer(bytes(sorted(_KNOWN)), dtype=np.uint8)
_DEFINITION_END = frozenset(b"ALC")


@dataclass
class FastData:
    name: str
    multi_id: int
    data: dict[str, npt.NDArray[Any]]


@dataclass
class FastULog:
    start_timestamp: int
    last_timestamp: int
    initial_parameters: dict[str, Any] = field(default_factory=dict)
    msg_info_dict: dict[str, Any] = field(default_factory=dict)
    data_list: list[FastData] = field(default_factory=list)
    file_corruption: bool = False
    problem: str | None = None  # a truncated tail, as the integrity walk words it


def _text(b: bytes) -> str:
    return b.decode("utf-8", "replace")


def _info(payload: bytes) -> tuple[str, Any] | None:
    key_len = payload[0]
    type_key = _text(payload[1 : 1 + key_len]).split(" ")
    if len(type_key) < 2:
        return None
    kind, key = type_key[0], type_key[1]
    raw = payload[1 + key_len :]
    if kind.startswith("char["):
        return key, _text(raw)
    code = _STRUCT.get(kind)
    if code is None:
        return key, raw
    size = struct.calcsize("<" + code)
    if len(raw) != size:
        return None
    return key, struct.unpack("<" + code, raw)[0]


def _format(payload: bytes) -> tuple[str, list[tuple[str, int, str]]] | None:
    name, sep, body = _text(payload).partition(":")
    if not sep:
        return None
    fields = []
    for item in body.split(";"):
        if not item:
            continue
        parts = item.split(" ")
        if len(parts) < 2:
            return None
        type_str, fname = parts[0], parts[1]
        count = 0
        if "[" in type_str:
            type_str, _, rest = type_str.partition("[")
            digits = rest.partition("]")[0]
            if not digits.isdigit():
                return None
            count = int(digits)
        fields.append((type_str, count, fname))
    return name, fields


def _dtype(fields: list[tuple[str, int, str]]) -> np.dtype[Any] | None:
    """The packed record of a flat format (None for nested types: pyulog handles those)."""
    if sum(_TYPES.get(t, ("", 1 << 16))[1] * max(c, 1) for t, c, _ in fields) > 0xFFFF:
        return None  # larger than a ULog message can be (a corrupt or crafted format)
    flat: list[tuple[str, str]] = []
    for type_str, count, fname in fields:
        t = _TYPES.get(type_str)
        if t is None:
            return None
        if count:
            flat.extend((f"{fname}[{i}]", t[0]) for i in range(count))
        else:
            flat.append((fname, t[0]))
    while flat and flat[-1][0].startswith("_padding"):
        flat.pop()
    if not flat or len({n for n, _ in flat}) != len(flat):
        return None
    return np.dtype(flat)


def parse(raw: bytes, topics: list[str]) -> FastULog | None:
    """The needed topics of a ULog (``raw`` starts with its 16-byte header), or None."""
    n = len(raw)
    if n < 16:
        return None
    start_ts = int.from_bytes(raw[8:16], "little")
    starts: list[int] = []
    append = starts.append
    pos = 16
    problem = None
    last = n - 3
    while pos <= last:  # the one Python loop: message sizes only (types checked below at once)
        after = pos + 3 + (raw[pos] | (raw[pos + 1] << 8))
        if after > n:
            if raw[pos + 2] not in _KNOWN:
                return None  # corruption: pyulog resynchronises, the walk reports it
            problem = f"corrupt tail: last message truncated at byte {n}; ignored"
            break
        append(pos)
        pos = after
    if pos < n and problem is None:
        problem = f"corrupt tail: {n - pos} stray bytes at the end; ignored"
    buf = np.frombuffer(raw, dtype=np.uint8)
    at = np.asarray(starts, dtype=np.int64)
    kinds = buf[at + 2] if len(at) else np.zeros(0, np.uint8)
    if not np.isin(kinds, _KNOWN_TYPES).all():
        return None  # corruption: pyulog resynchronises, the walk reports it
    sizes = (buf[at].astype(np.int64) | (buf[at + 1].astype(np.int64) << 8)) if len(at) else at
    out = FastULog(start_ts, start_ts, problem=problem)
    formats: dict[str, list[tuple[str, int, str]]] = {}
    subs: dict[int, tuple[str, int, np.dtype[Any], int]] = {}  # msg_id -> name, multi, dtype, max
    wanted = set(topics)
    in_definitions = True
    for k in np.flatnonzero(kinds != ord("D")).tolist():
        kind = int(kinds[k])
        a = int(at[k]) + 3
        payload = raw[a : a + int(sizes[k])]
        if in_definitions and kind in _DEFINITION_END:
            in_definitions = False
        if kind == ord("B"):
            if len(payload) < 16 or payload[8] or any(payload[9:16]):
                return None  # appended data or unknown incompatible flags: pyulog
        elif kind == ord("F"):
            parsed = _format(payload)
            if parsed is None:
                return None
            formats[parsed[0]] = parsed[1]
        elif kind == ord("I"):
            info = _info(payload)
            if info is None:
                return None
            out.msg_info_dict[info[0]] = info[1]
        elif kind == ord("P") and in_definitions:
            info = _info(payload)
            if info is None:
                return None
            out.initial_parameters[info[0]] = info[1]
        elif kind == ord("A"):
            if len(payload) < 3:
                return None
            name = _text(payload[3:])
            if name not in wanted:
                continue
            fmt = formats.get(name, [])
            dt = _dtype(fmt) if fmt else None
            if dt is None:
                return None
            max_size = sum(_TYPES[t][1] * max(c, 1) for t, c, _ in fmt)
            subs[int.from_bytes(payload[1:3], "little")] = (name, payload[0], dt, max_size)
    is_data = kinds == ord("D")
    d_at = at[is_data]
    d_size = sizes[is_data] - 2
    d_id = buf[d_at + 3].astype(np.int64) | (buf[d_at + 4].astype(np.int64) << 8)
    last = start_ts
    for msg_id, (name, multi, dt, max_size) in subs.items():
        sel = d_id == msg_id
        ok = sel & (d_size >= dt.itemsize) & (d_size <= max_size)
        if (sel & ~ok).any():
            out.file_corruption = True
        first = d_at[ok] + 5
        if not len(first):
            continue
        rows = np.lib.stride_tricks.sliding_window_view(buf, dt.itemsize)[first]  # a copy
        records = np.ascontiguousarray(rows).view(dt).reshape(-1)
        data = {name_: records[name_] for name_ in dt.names or ()}
        if "timestamp" in data and len(data["timestamp"]):
            last = max(last, int(np.max(data["timestamp"])))
        out.data_list.append(FastData(name, multi, data))
    out.last_timestamp = last
    return out
