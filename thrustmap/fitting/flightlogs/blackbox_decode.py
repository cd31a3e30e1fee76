"""Decoder for Betaflight/Cleanflight/INAV blackbox binary logs (.bbl/.bfl), written from the
format's public description (MIT, like the rest of thrustmap).

A file holds one or more logs; each starts with ASCII header lines ``H key:value`` that define
the frame layouts (``Field I name/signed/predictor/encoding``, ``Field P ...``, ``Field S ...``,
``Field G ...``, ``Field H ...``) followed by binary frames, each introduced by one marker byte:

- ``I`` intra frame (all main fields, predicted only from constants),
- ``P`` inter frame (main fields predicted from the previous one or two main frames),
- ``S`` slow frame (flight mode flags etc.), ``G`` GPS, ``H`` GPS home, ``E`` event
  (``E 0xFF "End of log\\0"`` closes a log).

A frame is accepted when its length is sane and it is followed by another marker (or the end of
the data); otherwise it is counted as corrupt and decoding resynchronises at the next marker.
Inter frames after a corrupt frame are dropped until the next intra frame re-establishes the
history. A truncated tail is reported and everything before it is kept.

For speed each frame layout is compiled once into a small specialised Python function; a clean
log (the usual case) is decoded in bulk by :mod:`blackbox_fast` instead, with the same result.
"""

from __future__ import annotations

import functools
import itertools
import logging
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

log = logging.getLogger(__name__)

LOG_START_MARKER = b"H Product:Blackbox flight data recorder by Nicholas Sherlock"
FRAME_MARKERS = b"IPEGHS"
MAX_FRAME_BYTES = 256
#: plausible header ranges (Betaflight/INAV/Cleanflight logs stay far inside them): a header
#: claiming more is corrupt, and must not drive the decoder's loops or tables
MAX_FIELDS = 256  # per frame type; real main frames have 30..110
MAX_INTERVAL = 0xFFFF  # 'I interval' and the 'P interval' numerator/denominator are 16-bit
#: decoding work budget per input byte (field evaluations, counting failed resync attempts),
#: so a damaged log decodes in time linear in its size whatever its header claims
WORK_PER_BYTE = 64
#: a log with corrupt stretches: back to bulk decoding at an intra frame at least HANDBACK_GAP
#: bytes past where the frame-by-frame decoder took over, with MIN_HANDBACK_BYTES still to go;
#: each bulk pass frames the rest of the log, so all of them frame at most HANDBACK_FRAMING
#: times the log (a log corrupt all over is left to the frame-by-frame decoder)
HANDBACK_GAP = 16_384
MIN_HANDBACK_BYTES = 262_144
HANDBACK_FRAMING = 1
MAX_ITERATION_JUMP = 5000
MAX_TIME_JUMP_US = 10_000_000

# Encodings
ENC_SIGNED_VB = 0
ENC_UNSIGNED_VB = 1
ENC_NEG_14BIT = 3
ENC_TAG8_8SVB = 6
ENC_TAG2_3S32 = 7
ENC_TAG8_4S16 = 8
ENC_NULL = 9
# Predictors
PRED_ZERO = 0
PRED_PREVIOUS = 1
PRED_STRAIGHT_LINE = 2
PRED_AVERAGE_2 = 3
PRED_MINTHROTTLE = 4
PRED_MOTOR_0 = 5
PRED_INC = 6
PRED_HOME_COORD = 7
PRED_1500 = 8
PRED_VBATREF = 9
PRED_LAST_MAIN_FRAME_TIME = 10
PRED_MINMOTOR = 11
PRED_HOME_COORD_1 = 256  # internal: second of a home-coordinate pair

# Events
EVENT_SYNC_BEEP = 0
EVENT_INFLIGHT_ADJUSTMENT = 13
EVENT_LOGGING_RESUME = 14
EVENT_DISARM = 15
EVENT_FLIGHT_MODE = 30
EVENT_LOG_END = 255
END_OF_LOG_TEXT = b"End of log\x00"

FrameParser = Callable[..., tuple[list[int], int]]


class CorruptFrame(Exception):
    """A frame that cannot be decoded (bad varint, unknown event, ...)."""


@dataclass
class FrameDef:
    names: list[str] = field(default_factory=list)
    signed: list[int] = field(default_factory=list)
    predictor: list[int] = field(default_factory=list)
    encoding: list[int] = field(default_factory=list)


@dataclass
class BlackboxEvent:
    frame_index: int  # number of main frames decoded before the event
    kind: int
    data: tuple[float, ...]


@dataclass
class DecodedLog:
    """One log of a blackbox file, decoded to integers in firmware units."""

    index: int
    headers: dict[str, str]
    main_fields: list[str]
    main: npt.NDArray[np.int64]  # (frames, fields)
    slow_fields: list[str]
    slow: npt.NDArray[np.int64]  # (slow frames, fields)
    slow_frame_index: npt.NDArray[np.int64]  # main-frame index each slow frame precedes
    gps_fields: list[str]
    gps: npt.NDArray[np.int64]
    events: list[BlackboxEvent]
    stats: dict[str, int]
    warnings: list[str]
    ended_cleanly: bool
    byte_range: tuple[int, int]


@dataclass
class ResumeState:
    """Where a bulk decoder stopped in a log: the reference decoder carries on from here with
    the state it would have had after decoding everything before ``pos`` itself (the frames
    before ``pos`` were all clean: each parsed, followed by a frame, plausible)."""

    pos: int  # offset in the section of the first frame not yet decoded
    main: npt.NDArray[np.int64]  # the main frames decoded so far (kept fields)
    prev: list[int] | None  # the last main frame (None: none yet)
    prev2: list[int] | None  # the one before it (the last one again after an intra frame)
    last_iter: int
    last_time: int
    home: list[int]
    work_done: int  # work-budget units spent (see WORK_PER_BYTE)
    slow_rows: list[list[int]]
    slow_index: list[int]
    gps_rows: list[list[int]]
    events: list[BlackboxEvent]
    stats: dict[str, int]
    warnings: list[str]


# --- header --------------------------------------------------------------------------------


def split_logs(data: bytes) -> list[tuple[int, int]]:
    """Byte ranges of the logs in a file (each begins with the product header line)."""
    starts: list[int] = []
    pos = data.find(LOG_START_MARKER)
    while pos >= 0:
        starts.append(pos)
        pos = data.find(LOG_START_MARKER, pos + len(LOG_START_MARKER))
    return [(s, starts[i + 1] if i + 1 < len(starts) else len(data)) for i, s in enumerate(starts)]


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip() != ""]


def parse_headers(data: bytes) -> tuple[dict[str, str], dict[str, FrameDef], int]:
    """Header lines at the start of ``data``: (key->value, frame defs by marker, data offset)."""
    headers: dict[str, str] = {}
    defs: dict[str, FrameDef] = {}
    pos = 0
    n = len(data)
    while pos + 1 < n and data[pos] == 0x48 and data[pos + 1] == 0x20:  # "H "
        end = data.find(b"\n", pos)
        if end < 0:
            end = n
        line = data[pos + 2 : end].decode("latin-1")
        pos = end + 1
        key, sep, value = line.partition(":")
        if not sep:
            continue
        headers[key] = value
        if key.startswith("Field ") and len(key) > 7:
            marker = key[6]
            what = key[8:]
            fd = defs.setdefault(marker, FrameDef())
            try:
                if what == "name":
                    fd.names = value.split(",")
                elif what == "signed":
                    fd.signed = _ints(value)
                elif what == "predictor":
                    fd.predictor = _ints(value)
                elif what == "encoding":
                    fd.encoding = _ints(value)
            except ValueError:
                raise CorruptFrame(f"header line '{key}' has non-integer values") from None
    for marker, fd in defs.items():
        widest = max(len(fd.names), len(fd.signed), len(fd.predictor), len(fd.encoding))
        if widest > MAX_FIELDS:
            raise CorruptFrame(
                f"header defines {widest} fields for '{marker}' frames; expected at most "
                f"{MAX_FIELDS}"
            )
    return headers, defs, pos


def header_int(headers: dict[str, str], key: str, default: int, position: int = 0) -> int:
    value = headers.get(key)
    if value is None:
        return default
    try:
        parts = value.split(",")
        text = parts[position].strip()
        return int(text, 16) if text.lower().startswith("0x") else int(text)
    except (ValueError, IndexError):
        return default


# --- frame parser generation -----------------------------------------------------------------


def _read_uvb_tail(d: bytes, p: int, first: int) -> tuple[int, int]:
    value = first & 0x7F
    shift = 7
    for _ in range(4):
        b = d[p]
        p += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value, p
        shift += 7
    raise CorruptFrame("variable-byte integer longer than 5 bytes")


#: bits set in each byte value
_POPCOUNT = [bin(v).count("1") for v in range(256)]
#: bytes a TAG2_3S32 group takes, by its lead byte (the lead included)
_TAG2_3S32_LEN = [
    (1, 2, 3)[lead >> 6]
    if lead >> 6 < 3
    else 1 + sum(((lead >> (2 * i)) & 3) + 1 for i in range(3))
    for lead in range(256)
]
#: bytes a TAG8_4S16 group (data version 2) takes after its selector: nibbles 0/1/2/4 per field
_TAG8_4S16_V2_LEN = [
    (sum((0, 1, 2, 4)[(sel >> (2 * i)) & 3] for i in range(4)) + 1) // 2 for sel in range(256)
]


def _skip_vb(d: bytes, p: int, count: int) -> int:
    """Past ``count`` variable-byte integers (their values are not needed)."""
    chunk = d[p : p + count]
    if len(chunk) == count and max(chunk) < 0x80:  # the usual case: one byte each
        return p + count
    for _ in range(count):
        for _ in range(5):
            b = d[p]
            p += 1
            if b < 0x80:
                break
        else:
            raise CorruptFrame("variable-byte integer longer than 5 bytes")
    return p


def _sext(value: int, bits: int) -> int:
    sign = 1 << (bits - 1)
    return (value & (sign - 1)) - (value & sign)


def _read_svb(d: bytes, p: int) -> tuple[int, int]:
    b = d[p]
    p += 1
    u, p = _read_uvb_tail(d, p, b) if b & 0x80 else (b, p)
    return (u >> 1) ^ -(u & 1), p


def _read_tag8_8svb(d: bytes, p: int, count: int) -> tuple[list[int], int]:
    if count == 1:
        v, p = _read_svb(d, p)
        return [v], p
    header = d[p]
    p += 1
    out = [0] * count
    for i in range(count):
        if header & (1 << i):
            out[i], p = _read_svb(d, p)
    return out, p


def _read_tag2_3s32(d: bytes, p: int) -> tuple[list[int], int]:
    lead = d[p]
    p += 1
    sel = lead >> 6
    if sel == 0:  # _sext inlined: ((x & (sign - 1)) - (x & sign))
        return [((lead >> 4) & 1) - ((lead >> 4) & 2), ((lead >> 2) & 1) - ((lead >> 2) & 2),
                (lead & 1) - (lead & 2)], p  # fmt: skip
    if sel == 1:
        b = d[p]
        return [(lead & 7) - (lead & 8), ((b >> 4) & 7) - ((b >> 4) & 8), (b & 7) - (b & 8)], p + 1
    if sel == 2:
        b, c = d[p], d[p + 1]
        return [(lead & 31) - (lead & 32), (b & 31) - (b & 32), (c & 31) - (c & 32)], p + 2
    out = [0, 0, 0]
    for i in range(3):
        nbytes = ((lead >> (2 * i)) & 3) + 1
        out[i] = _sext(int.from_bytes(d[p : p + nbytes], "little"), 8 * nbytes)
        if p + nbytes > len(d):
            raise IndexError("tag2_3s32 past end of data")
        p += nbytes
    return out, p


def _read_tag8_4s16_v2(d: bytes, p: int) -> tuple[list[int], int]:
    selector = d[p]
    p += 1
    out = [0, 0, 0, 0]
    nibble = False  # True: the low nibble of ``buf`` is still unread
    buf = 0
    for i in range(4):
        kind = (selector >> (2 * i)) & 3
        if kind == 1:  # 4 bits
            if not nibble:
                buf = d[p]
                p += 1
                out[i] = _sext(buf >> 4, 4)
                nibble = True
            else:
                out[i] = _sext(buf, 4)
                nibble = False
        elif kind == 2:  # 8 bits
            if not nibble:
                out[i] = _sext(d[p], 8)
                p += 1
            else:
                hi = buf & 0x0F
                buf = d[p]
                p += 1
                out[i] = _sext((hi << 4) | (buf >> 4), 8)
        elif kind == 3:  # 16 bits, big-endian in the nibble stream
            if not nibble:
                out[i] = _sext((d[p] << 8) | d[p + 1], 16)
                p += 2
            else:
                c1, c2 = d[p], d[p + 1]
                p += 2
                out[i] = _sext(((buf & 0x0F) << 12) | (c1 << 4) | (c2 >> 4), 16)
                buf = c2
    return out, p


def _sext_expr(x: str, bits: int) -> str:
    sign = 1 << (bits - 1)
    return f"((({x}) & {sign - 1}) - (({x}) & {sign}))"


def _gen_tag8_4s16_v2(selector: int) -> Callable[[bytes, int], tuple[list[int], int]]:
    """Straight-line reader for one selector byte of TAG8_4S16 (data version 2); ``p`` points
    just after the selector. Same nibble-stream semantics as :func:`_read_tag8_4s16_v2`."""
    lines = ["def r(d, p):\n"]
    nibble = False
    for i in range(4):
        kind = (selector >> (2 * i)) & 3
        if kind == 0:
            lines.append(f"    o{i} = 0\n")
        elif kind == 1:
            if not nibble:
                lines.append("    buf = d[p]; p += 1\n")
                lines.append(f"    o{i} = {_sext_expr('buf >> 4', 4)}\n")
            else:
                lines.append(f"    o{i} = {_sext_expr('buf', 4)}\n")
            nibble = not nibble
        elif kind == 2:
            if not nibble:
                lines.append(f"    o{i} = {_sext_expr('d[p]', 8)}; p += 1\n")
            else:
                lines.append("    hi = buf & 0x0F; buf = d[p]; p += 1\n")
                lines.append(f"    o{i} = {_sext_expr('(hi << 4) | (buf >> 4)', 8)}\n")
        else:
            if not nibble:
                lines.append(f"    o{i} = {_sext_expr('(d[p] << 8) | d[p + 1]', 16)}; p += 2\n")
            else:
                lines.append("    c1 = d[p]; c2 = d[p + 1]; p += 2\n")
                expr = "((buf & 0x0F) << 12) | (c1 << 4) | (c2 >> 4)"
                lines.append(f"    o{i} = {_sext_expr(expr, 16)}; buf = c2\n")
    lines.append("    return [o0, o1, o2, o3], p\n")
    namespace: dict[str, Any] = {}
    exec(compile("".join(lines), f"<tag8_4s16 v2 selector {selector:#04x}>", "exec"), namespace)
    reader: Callable[[bytes, int], tuple[list[int], int]] = namespace["r"]
    return reader


class _SelectorReaders(dict[int, Callable[[bytes, int], tuple[list[int], int]]]):
    """One straight-line reader per selector byte (the decoder's hottest path), compiled on the
    selector's first use: a log uses a few dozen of the 256, and compiling all of them cost
    every process ~0.1 s before the first frame."""

    def __missing__(self, selector: int) -> Callable[[bytes, int], tuple[list[int], int]]:
        reader = _gen_tag8_4s16_v2(selector)
        self[selector] = reader
        return reader


@functools.cache
def _tag8_4s16_v2_table() -> _SelectorReaders:
    return _SelectorReaders()


def _read_tag8_4s16_v1(d: bytes, p: int) -> tuple[list[int], int]:
    selector = d[p]
    p += 1
    out = [0, 0, 0, 0]
    i = 0
    while i < 4:
        kind = (selector >> (2 * i)) & 3
        if kind == 1:  # two 4-bit fields in one byte, low nibble first
            b = d[p]
            p += 1
            out[i] = _sext(b, 4)
            if i + 1 < 4:
                out[i + 1] = _sext(b >> 4, 4)
            i += 1
        elif kind == 2:
            out[i] = _sext(d[p], 8)
            p += 1
        elif kind == 3:
            out[i] = _sext(d[p] | (d[p + 1] << 8), 16)
            p += 2
        i += 1
    return out, p


_UVB = (
    "    b = d[p]; p += 1\n"
    "    if b & 0x80:\n"
    "        u, p = _uvb_tail(d, p, b)\n"
    "    else:\n"
    "        u = b\n"
)


def _prediction(i: int, predictor: int, constants: dict[str, int], motor0: int) -> str:
    """Python expression for the value predicted for field ``i`` (added to the residual)."""
    if predictor == PRED_ZERO:
        return "0"
    if predictor == PRED_PREVIOUS:
        return f"prev[{i}]"
    if predictor == PRED_STRAIGHT_LINE:
        return f"2 * prev[{i}] - prev2[{i}]"
    if predictor == PRED_AVERAGE_2:  # C integer division truncates toward zero
        return f"(((_a := prev[{i}] + prev2[{i}]) + (_a < 0)) >> 1)"
    if predictor == PRED_MINTHROTTLE:
        return str(constants["minthrottle"])
    if predictor == PRED_MOTOR_0:
        if motor0 < 0 or motor0 >= i:
            raise CorruptFrame("a field is predicted from motor[0] but motor[0] precedes it not")
        return f"f[{motor0}]"
    if predictor == PRED_HOME_COORD:
        return "home[0]"
    if predictor == PRED_HOME_COORD_1:
        return "home[1]"
    if predictor == PRED_1500:
        return "1500"
    if predictor == PRED_VBATREF:
        return str(constants["vbatref"])
    if predictor == PRED_LAST_MAIN_FRAME_TIME:
        return "last_time"
    if predictor == PRED_MINMOTOR:
        return str(constants["motor_low"])
    raise CorruptFrame(f"unsupported field predictor {predictor}")


def _wrap(i: int, signed: bool) -> str:
    if signed:
        return f"    f[{i}] = ((f[{i}] + 0x80000000) & 0xFFFFFFFF) - 0x80000000\n"
    return f"    f[{i}] &= 0xFFFFFFFF\n"


def compile_frame(
    fd: FrameDef,
    *,
    constants: dict[str, int],
    data_version: int,
    motor0: int = -1,
    wrap: bool = True,
    keep: frozenset[int] | None = None,
) -> FrameParser:
    """A function ``(d, p, prev, prev2, skipped, last_time, home) -> (values, new_p)``.

    ``wrap=False`` leaves out the per-field 32-bit wrap-around: the values are then exact
    whenever none leaves the 32-bit range, which :func:`decode_log` checks afterwards (it
    decodes again with the wraps when one does). Fields are local variables, not list items:
    both save most of the per-field cost of the pure-Python decoder. ``keep``: the only fields
    whose values are computed (the others are parsed for their length and read as 0)."""
    n = len(fd.names)
    enc = list(fd.encoding) + [ENC_NULL] * (n - len(fd.encoding))
    pred = list(fd.predictor) + [PRED_ZERO] * (n - len(fd.predictor))
    signed = list(fd.signed) + [0] * (n - len(fd.signed))
    for i in range(1, n):  # home coordinates come in (lat, lon) pairs sharing one predictor id
        if pred[i - 1] == PRED_HOME_COORD and pred[i] == PRED_HOME_COORD:
            pred[i] = PRED_HOME_COORD_1
    if keep is not None and motor0 >= 0 and any(pred[i] == PRED_MOTOR_0 for i in keep):
        keep = keep | {motor0}  # a kept field predicted from motor[0] needs its value
    live = [keep is None or i in keep for i in range(n)]
    lines = [
        "def parse(d, p, prev, prev2, skipped, last_time, home):\n",
        f"    f = [0] * {n}\n",
    ]
    i = 0
    while i < n:
        if pred[i] == PRED_INC:
            if live[i]:
                lines.append(f"    f[{i}] = prev[{i}] + skipped + 1\n")
                lines.append(_wrap(i, bool(signed[i])))
            i += 1
            continue
        e = enc[i]
        group: list[int]
        if e in (ENC_TAG8_8SVB, ENC_TAG2_3S32, ENC_TAG8_4S16):
            if e == ENC_TAG8_8SVB:
                j = i + 1
                while j < min(i + 8, n) and enc[j] == ENC_TAG8_8SVB:
                    j += 1
                if not any(live[i:j]):  # no value needed: skip the set fields' varints
                    if j - i == 1:
                        lines.append("    p = _skip_vb(d, p, 1)\n")
                    else:
                        lines.append(
                            f"    p = _skip_vb(d, p + 1, _popcount[d[p] & {(1 << (j - i)) - 1}])\n"
                        )
                    i = j
                    continue
                if j - i == 1:
                    lines.append("    g, p = _tag8_8svb(d, p, 1)\n")
                else:  # most groups are all zero: one header byte of 0
                    lines.append(
                        "    if d[p] == 0:\n        g = _zeros; p += 1\n"
                        f"    else:\n        g, p = _tag8_8svb(d, p, {j - i})\n"
                    )
                group = list(range(i, j))
            elif e == ENC_TAG2_3S32:
                group = list(range(i, min(i + 3, n)))
                if not any(live[k] for k in group):
                    lines.append("    p += _t2len[d[p]]\n")
                    i = group[-1] + 1
                    continue
                lines.append("    g, p = _tag2_3s32(d, p)\n")
            else:
                group = list(range(i, min(i + 4, n)))
                if data_version >= 2 and not any(live[k] for k in group):
                    lines.append("    p += 1 + _t4len[d[p]]\n")
                    i = group[-1] + 1
                    continue
                call = "_t4v2[d[p]](d, p + 1)" if data_version >= 2 else "_tag8_4s16_v1(d, p)"
                lines.append(
                    f"    if d[p] == 0:\n        g = _zeros; p += 1\n    else:\n        g, p = {call}\n"
                )
                group = list(range(i, min(i + 4, n)))
            for k, fi in enumerate(group):
                if not live[fi]:
                    continue
                pe = _prediction(fi, pred[fi], constants, motor0)
                lines.append(f"    f[{fi}] = g[{k}]" + ("" if pe == "0" else f" + {pe}") + "\n")
                if pe != "0":
                    lines.append(_wrap(fi, bool(signed[fi])))
            i = group[-1] + 1
            continue
        if not live[i] and e in (ENC_SIGNED_VB, ENC_UNSIGNED_VB, ENC_NEG_14BIT, ENC_NULL):
            j = i  # a run of fields not kept: their varints are skipped, not decoded
            while (
                j < n
                and not live[j]
                and pred[j] != PRED_INC
                and enc[j] in (ENC_SIGNED_VB, ENC_UNSIGNED_VB, ENC_NEG_14BIT, ENC_NULL)
            ):
                j += 1
            count = sum(1 for k in range(i, j) if enc[k] != ENC_NULL)
            if 0 < count <= 6:  # inline: most residuals are one byte each
                test = " and ".join(f"d[p + {k}] < 128" for k in range(count))
                lines.append(
                    f"    if {test}:\n        p += {count}\n"
                    f"    else:\n        p = _skip_vb(d, p, {count})\n"
                )
            elif count:
                lines.append(f"    p = _skip_vb(d, p, {count})\n")
            i = j
            continue
        if e == ENC_SIGNED_VB:
            lines.append(_UVB + "    v = (u >> 1) ^ -(u & 1)\n")
        elif e == ENC_UNSIGNED_VB:
            lines.append(_UVB + "    v = u\n")
        elif e == ENC_NEG_14BIT:
            lines.append(_UVB + "    v = -(u | -0x4000) if u & 0x2000 else -u\n")
        elif e == ENC_NULL:
            lines.append("    v = 0\n")
        else:
            raise CorruptFrame(f"unsupported field encoding {e} for field '{fd.names[i]}'")
        if not live[i]:
            i += 1
            continue
        pe = _prediction(i, pred[i], constants, motor0)
        if pe == "0":
            lines.append(f"    f[{i}] = v\n")
            if e == ENC_UNSIGNED_VB:
                lines.append(_wrap(i, bool(signed[i])))
        else:
            lines.append(f"    f[{i}] = v + {pe}\n")
            lines.append(_wrap(i, bool(signed[i])))
        i += 1
    if not wrap:
        lines = [ln for ln in lines if "0xFFFFFFFF" not in ln or "f[" not in ln.split("=")[0]]
    lines = [re.sub(r"\bf\[(\d+)\]", r"f\1", ln) for ln in lines[2:]]
    if keep is not None:  # rows hold the kept fields only: prev/prev2 are compact too
        slot = {fi: k for k, fi in enumerate(i for i in range(n) if live[i])}
        lines = [
            re.sub(r"\b(prev2?)\[(\d+)\]", lambda m: f"{m.group(1)}[{slot[int(m.group(2))]}]", ln)
            for ln in lines
        ]
    lines.insert(0, "def parse(d, p, prev, prev2, skipped, last_time, home):\n")
    if keep is not None:  # a skipped group is not read: a frame cut short must still raise
        lines.append("    if p > len(d):\n        raise IndexError('frame past end of data')\n")
    lines.append("    return [" + ", ".join(f"f{i}" for i in range(n) if live[i]) + "], p\n")
    namespace: dict[str, Any] = {
        "_uvb_tail": _read_uvb_tail,
        "_skip_vb": _skip_vb,
        "_popcount": _POPCOUNT,
        "_t2len": _TAG2_3S32_LEN,
        "_t4len": _TAG8_4S16_V2_LEN,
        "_tag8_8svb": _read_tag8_8svb,
        "_tag2_3s32": _read_tag2_3s32,
        "_tag8_4s16_v1": _read_tag8_4s16_v1,
        "_tag8_4s16_v2": _read_tag8_4s16_v2,
        "_t4v2": _tag8_4s16_v2_table() if data_version >= 2 else None,
        "_zeros": (0, 0, 0, 0, 0, 0, 0, 0),
    }
    exec(compile("".join(lines), f"<blackbox frame {fd.names[:1]}>", "exec"), namespace)
    parser: FrameParser = namespace["parse"]
    return parser


# --- log decoding ----------------------------------------------------------------------------


def _uvb(d: bytes, p: int) -> tuple[int, int]:
    b = d[p]
    return _read_uvb_tail(d, p + 1, b) if b & 0x80 else (b, p + 1)


def _parse_event(d: bytes, p: int) -> tuple[int, tuple[float, ...], int]:
    kind = d[p]
    p += 1
    if kind == EVENT_SYNC_BEEP:
        t, p = _uvb(d, p)
        return kind, (float(t),), p
    if kind == EVENT_INFLIGHT_ADJUSTMENT:
        func = d[p]
        p += 1
        if func > 127:
            if p + 4 > len(d):
                raise IndexError("event past end of data")
            value = float(np.frombuffer(d[p : p + 4], dtype="<f4")[0])
            return kind, (float(func), value), p + 4
        v, p = _read_svb(d, p)
        return kind, (float(func), float(v)), p
    if kind == EVENT_LOGGING_RESUME:
        it, p = _uvb(d, p)
        t, p = _uvb(d, p)
        return kind, (float(it), float(t)), p
    if kind == EVENT_DISARM:
        reason, p = _uvb(d, p)
        return kind, (float(reason),), p
    if kind == EVENT_FLIGHT_MODE:
        flags, p = _uvb(d, p)
        last, p = _uvb(d, p)
        return kind, (float(flags), float(last)), p
    if kind == EVENT_LOG_END:
        text = d[p : p + len(END_OF_LOG_TEXT)]
        if len(text) < len(END_OF_LOG_TEXT):
            raise IndexError("log-end event past end of data")
        if text != END_OF_LOG_TEXT:
            raise CorruptFrame("log-end event without its 'End of log' text")
        return kind, (), p + len(END_OF_LOG_TEXT)
    raise CorruptFrame(f"unknown event type {kind}")


def _p_interval(headers: dict[str, str]) -> tuple[int, int]:
    """(num, denom): log ``num`` of every ``denom`` loop iterations ("1/16" or, newer, "16")."""
    text = headers.get("P interval", "1/1").strip()
    try:
        if "/" in text:
            num_text, den_text = text.split("/", 1)
            num, den = max(int(num_text), 1), max(int(den_text), 1)
        else:
            num, den = 1, max(int(text), 1)
    except ValueError:
        return 1, 1
    if num > MAX_INTERVAL or den > MAX_INTERVAL:
        raise CorruptFrame(
            f"header 'P interval: {text[:20]}' is out of range; expected values up to {MAX_INTERVAL}"
        )
    return num, den


@functools.lru_cache(maxsize=16)
def _skip_table(i_interval: int, p_num: int, p_den: int) -> tuple[int, ...]:
    """For each iteration (mod I interval): iterations skipped before the next logged one
    (cached: the logs of a file share their intervals)."""

    def logged(idx: int) -> bool:
        return (idx % i_interval + p_num - 1) % p_den < p_num

    # One backward pass over two periods (logged() repeats every I interval): the distance from
    # each iteration to the next logged one, capped as before at I interval + P denominator.
    cap = i_interval + p_den
    span = 2 * i_interval + 1
    next_gap = [cap + 1] * (span + 1)
    for idx in range(span - 1, -1, -1):
        next_gap[idx] = 0 if logged(idx) else min(next_gap[idx + 1] + 1, cap + 1)
    return tuple(min(next_gap[r + 1] + 1, cap + 1) - 1 for r in range(i_interval))


def decode_log(
    section: bytes,
    index: int = 0,
    offset: int = 0,
    *,
    keep_field: Callable[[str], bool] | None = None,
) -> DecodedLog:
    """Decode one log (``section`` starts at its ``H Product`` line).

    Main frames are decoded first without the per-field 32-bit wrap-around (the pure-Python
    decoder's largest avoidable cost); when any decoded value lies outside the 32-bit range of
    its field the wrap mattered, and the log is decoded again with it, so the result is always
    what the firmware's 32-bit arithmetic gives.

    ``keep_field``: decode only the main-frame fields it accepts (and loopIteration and time):
    the others are still parsed for their length, but their values are neither predicted nor
    stored, and ``main_fields`` lists only the kept ones (a reader needing a handful of the
    40-odd fields saves most of the decoding).

    A clean log (no corrupt frame, rollover, ...) is decoded in bulk by :mod:`blackbox_fast`,
    ~10x faster; a log that is clean up to some point (a truncated tail, a corrupt stretch, a
    rollover) is decoded in bulk up to there and frame by frame from there on, back in bulk from
    an intra frame past a corrupt stretch (see HANDBACK_GAP); any other by the reference alone. All give the same result (tests/test_blackbox_fast.py compares them
    frame by frame)."""

    from thrustmap.fitting.flightlogs.blackbox_fast import decode_log_bulk

    got = decode_log_bulk(section, index, offset, keep_field=keep_field)
    if isinstance(got, DecodedLog):
        return got
    if got is None:
        return decode_log_reference(section, index, offset, keep_field=keep_field)
    # a corrupt stretch: frame by frame from there, back to bulk at an intra frame past it
    state = got
    n = len(section)
    framing_left = HANDBACK_FRAMING * n  # bytes the bulk decoder may frame again, in all
    while True:  # ends: each pass starts further on, or is the reference's last
        after: int | None = state.pos + HANDBACK_GAP
        if n - state.pos < MIN_HANDBACK_BYTES or framing_left < n - state.pos:
            after = None
        try:
            ref = _decode_log(
                section, index, offset, wrap=False, keep_field=keep_field, resume=state,
                handback_after=after,
            )  # fmt: skip
        except OverflowError:
            break
        if isinstance(ref, DecodedLog):
            if _in_32bit_range(ref):
                return ref
            break
        framing_left -= n - ref.pos
        got = decode_log_bulk(section, index, offset, keep_field=keep_field, start=ref)
        if isinstance(got, DecodedLog):
            if _in_32bit_range(got):
                return got
            break
        state = ref if got is None else got  # declined there: the reference carries on
    # a value needing the 32-bit wrap somewhere: the reference with the wrap, from the start
    return decode_log_reference(section, index, offset, keep_field=keep_field)


def decode_log_reference(
    section: bytes,
    index: int = 0,
    offset: int = 0,
    *,
    keep_field: Callable[[str], bool] | None = None,
    resume: ResumeState | None = None,
) -> DecodedLog:
    """:func:`decode_log` frame by frame in pure Python: every log, however damaged.

    ``resume``: start where a bulk decoder stopped, with its state (its frames are in range of
    their fields, so they are the same with or without the 32-bit wrap)."""
    fast: DecodedLog | ResumeState | None
    try:
        fast = _decode_log(section, index, offset, wrap=False, keep_field=keep_field, resume=resume)
    except OverflowError:  # a value beyond int64: certainly out of range
        fast = None
    if not isinstance(fast, DecodedLog) or not _in_32bit_range(fast):
        fast = _decode_log(section, index, offset, wrap=True, keep_field=keep_field, resume=resume)
    assert isinstance(fast, DecodedLog)  # no handback asked
    return fast


def _in_32bit_range(log: DecodedLog) -> bool:
    """True when every main-frame value (but time, kept with its rollovers) fits its field."""
    return in_32bit_range(log.headers, log.main_fields, log.main)


def in_32bit_range(
    headers: dict[str, str], main_fields: list[str], main: npt.NDArray[np.int64]
) -> bool:
    """True when every value of ``main`` (columns ``main_fields``) but time fits its field."""
    if not len(main):
        return True
    names = [x.strip() for x in headers.get("Field I name", "").split(",")]
    sign_of = dict(zip(names, _main_signed(headers, len(names)), strict=True))
    for k, name in enumerate(main_fields):
        if k == 1:
            continue
        col = main[:, k]
        lo, hi = (-(1 << 31), (1 << 31) - 1) if sign_of.get(name, 0) else (0, (1 << 32) - 1)
        if int(col.min()) < lo or int(col.max()) > hi:
            return False
    return True


def _main_signed(headers: dict[str, str], n: int) -> list[int]:
    signed = _ints(headers.get("Field I signed", ""))
    return (signed + [0] * n)[:n]


def _kept_fields(
    names: list[str],
    idef: FrameDef,
    pdef: FrameDef,
    motor0: int,
    keep_field: Callable[[str], bool] | None,
) -> frozenset[int] | None:
    """Indices of the main fields to decode (None: all): loopIteration, time, the fields
    ``keep_field`` accepts, and motor[0] when a kept field is predicted from it."""
    if keep_field is None:
        return None
    keep = frozenset(k for k, name in enumerate(names) if k < 2 or keep_field(name))
    if motor0 >= 0:  # a kept field predicted from motor[0] needs it
        preds = list(idef.predictor) + list(pdef.predictor)
        width = len(idef.predictor)
        if any(
            preds[k] == PRED_MOTOR_0
            or (width + k < len(preds) and preds[width + k] == PRED_MOTOR_0)
            for k in keep
            if k < width
        ):
            keep = keep | {motor0}
    return keep


def _table(rows: list[list[int]], width: int) -> npt.NDArray[np.int64]:
    if not rows:
        return np.zeros((0, width), dtype=np.int64)
    if sum(map(len, rows)) != len(rows) * width:  # ragged: let numpy say so
        return np.array(rows, dtype=np.int64)
    flat = itertools.chain.from_iterable(rows)  # ~1.7x faster than np.array on lists
    return np.fromiter(flat, dtype=np.int64, count=len(rows) * width).reshape(-1, width)


def corruption_summary(index: int, stats: dict[str, int]) -> str | None:
    """The warning closing a log with corrupt or implausible frames (None when it has none)."""
    if not (stats["corrupt"] or stats["invalid_main"]):
        return None
    return (
        f"log {index + 1}: {stats['corrupt']} corrupt frame(s) and {stats['invalid_main']} "
        f"implausible main frame(s) skipped, resynchronised at the next frame marker "
        f"({stats['dropped_p']} inter frames dropped until the next intra frame, "
        f"{stats['skipped_bytes']} unparseable bytes)"
    )


def _decode_log(
    section: bytes,
    index: int,
    offset: int,
    *,
    wrap: bool,
    keep_field: Callable[[str], bool] | None = None,
    resume: ResumeState | None = None,
    handback_after: int | None = None,
) -> DecodedLog | ResumeState:
    """Decode frame by frame (from ``resume`` when given). ``handback_after``: stop at the first
    intra frame from that byte on that follows a good frame (no rollover so far), and return
    the state there for the bulk decoder to carry on from."""
    headers, defs, pos = parse_headers(section)
    warnings: list[str] = []
    idef = defs.get("I")
    if idef is None or not idef.names:
        raise CorruptFrame("the header defines no main-frame fields ('H Field I name')")
    pdef = defs.get("P", FrameDef())
    pdef = FrameDef(idef.names, idef.signed, pdef.predictor, pdef.encoding)
    names = idef.names
    nfields = len(names)
    motor0 = names.index("motor[0]") if "motor[0]" in names else -1
    minthrottle = header_int(headers, "minthrottle", 1150)
    constants = {
        "minthrottle": minthrottle,
        "vbatref": header_int(headers, "vbatref", 4095),
        "motor_low": header_int(headers, "motorOutput", minthrottle, 0),
    }
    version = header_int(headers, "Data version", 2)
    keep = _kept_fields(names, idef, pdef, motor0, keep_field)
    parsers: dict[int, FrameParser] = {}
    for marker, fd in (("I", idef), ("P", pdef)):
        if fd.encoding:
            parsers[ord(marker)] = compile_frame(
                fd, constants=constants, data_version=version, motor0=motor0, wrap=wrap,
                keep=keep,
            )  # fmt: skip
    for marker in "SGH":
        if marker in defs and defs[marker].names and defs[marker].encoding:
            parsers[ord(marker)] = compile_frame(
                defs[marker], constants=constants, data_version=version
            )
    i_interval = max(header_int(headers, "I interval", 32), 1)
    if i_interval > MAX_INTERVAL:
        raise CorruptFrame(
            f"header 'I interval: {i_interval}' is out of range; expected 1..{MAX_INTERVAL}"
        )
    p_num, p_den = _p_interval(headers)
    skip_table = _skip_table(i_interval, p_num, p_den)
    home_idx = [
        defs["H"].names.index(k) if "H" in defs and k in defs["H"].names else -1
        for k in ("GPS_home[0]", "GPS_home[1]")
    ]

    d = section
    n = len(d)
    markers = frozenset(FRAME_MARKERS)
    zeros = [0] * nfields
    main_rows: list[list[int]] = []
    slow_rows: list[list[int]] = []
    slow_index: list[int] = []
    gps_rows: list[list[int]] = []
    events: list[BlackboxEvent] = []
    stats = {k: 0 for k in ("I", "P", "S", "G", "H", "E")}
    stats.update(corrupt=0, dropped_p=0, invalid_main=0, skipped_bytes=0)
    prev: list[int] | None = None
    prev2: list[int] = zeros
    last_iter = -1
    last_time = -1
    rollover = 0
    home = [0, 0]
    ended = False
    tail_start = -1
    garbage_run = False
    mark_i, mark_p, mark_e = ord("I"), ord("P"), ord("E")
    mark_s, mark_g, mark_h = ord("S"), ord("G"), ord("H")
    widths = {ord(k): max(len(fd.names), 1) for k, fd in defs.items()}
    widths[mark_i] = widths[mark_p] = max(nfields, 1)
    budget = WORK_PER_BYTE * n + 100_000
    out_of_budget = -1
    main_offset = 0  # main frames decoded before ``resume.pos`` (not in main_rows)
    if resume is not None:
        pos, prev, last_iter, last_time, home = (
            resume.pos, resume.prev, resume.last_iter, resume.last_time, list(resume.home)
        )  # fmt: skip
        prev2 = zeros if resume.prev2 is None else resume.prev2
        budget -= resume.work_done
        main_offset = len(resume.main)
        slow_rows, slow_index = list(resume.slow_rows), list(resume.slow_index)
        gps_rows, events = list(resume.gps_rows), list(resume.events)
        stats.update(resume.stats)
        warnings = list(resume.warnings)
    starts_frame = bytes(sorted({*parsers, mark_e} & set(markers)))
    skip_run = re.compile(b"[^" + re.escape(starts_frame) + b"]+").match
    parse_p = parsers.get(mark_p)
    width_main = widths[mark_p]
    append = main_rows.append

    while pos < n:
        m = d[pos]
        if m == mark_p and prev is not None and parse_p is not None and budget > width_main:
            # the common case, an inter frame after a good frame: the general path below, with
            # every check, in one place; anything unusual falls through to it (and is re-read)
            try:
                vals, p = parse_p(
                    d, pos + 1, prev, prev2, skip_table[last_iter % i_interval], last_time, home
                )
            except (IndexError, CorruptFrame):
                p = -1
            if p > pos and p - pos - 1 <= MAX_FRAME_BYTES and (p >= n or d[p] in markers):
                t = (vals[1] & 0xFFFFFFFF) + rollover
                roll = 0
                if (
                    last_time >= 0
                    and t < last_time
                    and ((t - last_time) & 0xFFFFFFFF) < MAX_TIME_JUMP_US
                ):
                    roll = 1 << 32
                    t += roll
                it = vals[0]
                if (
                    last_iter <= it < last_iter + MAX_ITERATION_JUMP
                    and last_time <= t < last_time + MAX_TIME_JUMP_US
                ):
                    budget -= width_main
                    rollover += roll
                    vals[1] = t
                    stats["P"] += 1
                    append(vals)
                    prev2 = prev
                    prev = vals
                    last_iter, last_time = it, t
                    garbage_run = False
                    pos = p
                    continue
        if (
            m == mark_i
            and handback_after is not None
            and pos >= handback_after
            and not garbage_run
            and not rollover
        ):
            main_now = _table(main_rows, nfields if keep is None else len(keep))
            if resume is not None and main_offset:
                main_now = np.concatenate((resume.main, main_now))
            return ResumeState(
                pos=pos, main=main_now, prev=prev, prev2=prev2, last_iter=last_iter,
                last_time=last_time, home=list(home),
                work_done=WORK_PER_BYTE * n + 100_000 - budget, slow_rows=slow_rows,
                slow_index=slow_index, gps_rows=gps_rows, events=events, stats=dict(stats),
                warnings=list(warnings),
            )  # fmt: skip
        if m not in markers or m not in parsers and m != mark_e:
            # a run of bytes no frame starts with (erased flash after a cut-off log: megabytes
            # of 0xFF) is skipped at once, as byte by byte
            found = skip_run(d, pos)
            run = found.end() - pos if found is not None else 1
            stats["skipped_bytes"] += run
            if not garbage_run and (main_rows or main_offset):
                prev = None
            garbage_run = True
            pos += run
            continue
        start = pos
        budget -= widths.get(m, 1)
        if budget < 0:
            out_of_budget = start
            break
        event: tuple[int, tuple[float, ...]] | None = None
        try:
            if m == mark_p:
                if prev is None:
                    vals, p = parsers[m](d, pos + 1, zeros, zeros, 0, 0, home)
                else:
                    skipped = skip_table[last_iter % i_interval]
                    vals, p = parsers[m](d, pos + 1, prev, prev2, skipped, last_time, home)
            elif m == mark_i:
                vals, p = parsers[m](d, pos + 1, prev or zeros, zeros, 0, last_time, home)
            elif m == mark_e:
                kind, payload, p = _parse_event(d, pos + 1)
                vals = []
                event = (kind, payload)
            else:
                fd = defs[chr(m)]
                vals, p = parsers[m](d, pos + 1, [0] * len(fd.names), [], 0, last_time, home)
        except IndexError:
            tail_start = start
            break
        except CorruptFrame:
            p = -1
        bad = p < 0 or p - start - 1 > MAX_FRAME_BYTES or (p < n and d[p] not in markers)
        if bad and (event is None or event[0] != EVENT_LOG_END):
            stats["corrupt"] += 1
            prev = None
            pos = start + 1
            garbage_run = True
            continue
        garbage_run = False
        pos = p
        if m in (mark_i, mark_p):
            t = (vals[1] & 0xFFFFFFFF) + rollover
            if (
                last_time >= 0
                and t < last_time
                and ((t - last_time) & 0xFFFFFFFF) < MAX_TIME_JUMP_US
            ):
                rollover += 1 << 32
                t += 1 << 32
            vals[1] = t
            it = vals[0]
            if m == mark_p:
                if prev is None:
                    stats["dropped_p"] += 1
                    continue
                ok = last_iter <= it < last_iter + MAX_ITERATION_JUMP and (
                    last_time <= t < last_time + MAX_TIME_JUMP_US
                )
            else:
                ok = last_iter < 0 or (it >= last_iter and t >= last_time)
                if ok and last_iter >= 0 and t - last_time >= MAX_TIME_JUMP_US:
                    warnings.append(
                        f"log {index + 1}: {1e-6 * (t - last_time):.1f} s gap in the data "
                        f"after t = {1e-6 * last_time:.3f} s"
                    )
            if not ok:
                stats["invalid_main"] += 1
                prev = None
                continue
            stats["P" if m == mark_p else "I"] += 1
            main_rows.append(vals)
            prev2 = vals if m == mark_i else (prev or vals)
            prev = vals
            last_iter, last_time = it, t
        elif event is not None:
            stats["E"] += 1
            kind, payload = event
            events.append(BlackboxEvent(main_offset + len(main_rows), kind, payload))
            if kind == EVENT_LOGGING_RESUME:
                last_iter, last_time = int(payload[0]), int(payload[1]) + rollover
            elif kind == EVENT_LOG_END:
                ended = True
                break
        elif m == mark_s:
            stats["S"] += 1
            slow_rows.append(vals)
            slow_index.append(main_offset + len(main_rows))
        elif m == mark_g:
            stats["G"] += 1
            gps_rows.append(vals)
        elif m == mark_h:
            stats["H"] += 1
            home = [vals[k] if k >= 0 else 0 for k in home_idx]

    if tail_start >= 0:
        warnings.append(
            f"log {index + 1}: truncated or corrupt tail at byte {offset + tail_start} "
            f"({n - tail_start} bytes ignored); the data before it is used"
        )
    if out_of_budget >= 0:
        warnings.append(
            f"log {index + 1}: too corrupt to resynchronise economically; decoding stopped at "
            f"byte {offset + out_of_budget} ({n - out_of_budget} bytes ignored)"
        )
    if (summary := corruption_summary(index, stats)) is not None:
        warnings.append(summary)

    sdef = defs.get("S", FrameDef())
    gdef = defs.get("G", FrameDef())
    main = _table(main_rows, nfields if keep is None else len(keep))
    if resume is not None and main_offset:
        main = np.concatenate((resume.main, main)) if len(main) else resume.main
    return DecodedLog(
        index=index,
        headers=headers,
        main_fields=[name for k, name in enumerate(names) if keep is None or k in keep],
        main=main,
        slow_fields=list(sdef.names),
        slow=_table(slow_rows, len(sdef.names)),
        slow_frame_index=np.array(slow_index, dtype=np.int64),
        gps_fields=list(gdef.names),
        gps=_table(gps_rows, len(gdef.names)),
        events=events,
        stats=stats,
        warnings=warnings,
        ended_cleanly=ended,
        byte_range=(offset, offset + n),
    )


def decode_file(data: bytes) -> list[DecodedLog]:
    """Every log in a blackbox file, in order (a log that cannot be decoded raises)."""
    return [decode_log(data[a:b], index=i, offset=a) for i, (a, b) in enumerate(split_logs(data))]
