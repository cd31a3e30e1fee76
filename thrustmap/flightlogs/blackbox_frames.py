"""Blackbox frame parsers: the field encodings read one frame at a time, and each frame layout
compiled once into a small specialised Python function (:func:`compile_frame`); events.

Used by the per-frame reference decoder (:mod:`blackbox_decode`) and, for the few slow, GPS and
GPS-home frames and events of a log, by the bulk decoder (:mod:`blackbox_fast`).
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from thrustmap.flightlogs.blackbox_format import (
    ENC_NEG_14BIT,
    ENC_NULL,
    ENC_SIGNED_VB,
    ENC_TAG2_3S32,
    ENC_TAG8_4S16,
    ENC_TAG8_8SVB,
    ENC_UNSIGNED_VB,
    END_OF_LOG_TEXT,
    EVENT_DISARM,
    EVENT_FLIGHT_MODE,
    EVENT_INFLIGHT_ADJUSTMENT,
    EVENT_LOG_END,
    EVENT_LOGGING_RESUME,
    EVENT_SYNC_BEEP,
    PRED_1500,
    PRED_AVERAGE_2,
    PRED_HOME_COORD,
    PRED_HOME_COORD_1,
    PRED_INC,
    PRED_LAST_MAIN_FRAME_TIME,
    PRED_MINMOTOR,
    PRED_MINTHROTTLE,
    PRED_MOTOR_0,
    PRED_PREVIOUS,
    PRED_STRAIGHT_LINE,
    PRED_VBATREF,
    PRED_ZERO,
    CorruptFrame,
    FrameDef,
    FrameParser,
)


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
POPCOUNT = [bin(v).count("1") for v in range(256)]
#: bytes a TAG2_3S32 group takes, by its lead byte (the lead included)
TAG2_3S32_LEN = [
    (1, 2, 3)[lead >> 6]
    if lead >> 6 < 3
    else 1 + sum(((lead >> (2 * i)) & 3) + 1 for i in range(3))
    for lead in range(256)
]
#: bytes a TAG8_4S16 group (data version 2) takes after its selector: nibbles 0/1/2/4 per field
TAG8_4S16_V2_LEN = [
    (sum((0, 1, 2, 4)[(sel >> (2 * i)) & 3] for i in range(4)) + 1) // 2 for sel in range(256)
]


def _skip_vb(d: bytes, p: int, count: int) -> int:
    """Past ``count`` variable-byte integers (their values are not needed)."""
    if count <= 0:  # a tagged group whose header flags no field
        return p
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


def prediction_code(i: int, predictor: int, constants: dict[str, int], motor0: int) -> str:
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
    layout = _FrameLayout.of(fd, constants, data_version, motor0, keep)
    lines = layout.body()
    if not wrap:
        lines = [ln for ln in lines if "0xFFFFFFFF" not in ln or "f[" not in ln.split("=")[0]]
    lines = [re.sub(r"\bf\[(\d+)\]", r"f\1", ln) for ln in lines]
    live = layout.live
    if keep is not None:  # rows hold the kept fields only: prev/prev2 are compact too
        slot = {fi: k for k, fi in enumerate(i for i in range(layout.n) if live[i])}
        lines = [
            re.sub(r"\b(prev2?)\[(\d+)\]", lambda m: f"{m.group(1)}[{slot[int(m.group(2))]}]", ln)
            for ln in lines
        ]
    lines.insert(0, "def parse(d, p, prev, prev2, skipped, last_time, home):\n")
    if keep is not None:  # a skipped group is not read: a frame cut short must still raise
        lines.append("    if p > len(d):\n        raise IndexError('frame past end of data')\n")
    lines.append("    return [" + ", ".join(f"f{i}" for i in range(layout.n) if live[i]) + "], p\n")
    return _exec_parser("".join(lines), fd, data_version)


@dataclass(frozen=True)
class _FrameLayout:
    """One frame's fields as the parser is generated from them: encodings, predictors and
    signedness padded to every field, home coordinates paired, and which fields are live."""

    names: list[str]
    enc: list[int]
    pred: list[int]
    signed: list[int]
    live: list[bool]
    constants: dict[str, int]
    data_version: int
    motor0: int

    @property
    def n(self) -> int:
        return len(self.names)

    @classmethod
    def of(
        cls,
        fd: FrameDef,
        constants: dict[str, int],
        data_version: int,
        motor0: int,
        keep: frozenset[int] | None,
    ) -> _FrameLayout:
        n = len(fd.names)
        enc = list(fd.encoding) + [ENC_NULL] * (n - len(fd.encoding))
        pred = list(fd.predictor) + [PRED_ZERO] * (n - len(fd.predictor))
        signed = list(fd.signed) + [0] * (n - len(fd.signed))
        for i in range(1, n):  # home coordinates come in (lat, lon) pairs sharing one predictor
            if pred[i - 1] == PRED_HOME_COORD and pred[i] == PRED_HOME_COORD:
                pred[i] = PRED_HOME_COORD_1
        if keep is not None and motor0 >= 0 and any(pred[i] == PRED_MOTOR_0 for i in keep):
            keep = keep | {motor0}  # a kept field predicted from motor[0] needs its value
        live = [keep is None or i in keep for i in range(n)]
        return cls(list(fd.names), enc, pred, signed, live, constants, data_version, motor0)

    def body(self) -> list[str]:
        """The parser's statements, field by field (``f[i]`` for field i)."""
        lines: list[str] = []
        i = 0
        while i < self.n:
            e = self.enc[i]
            if self.pred[i] == PRED_INC:
                if self.live[i]:
                    lines.append(f"    f[{i}] = prev[{i}] + skipped + 1\n")
                    lines.append(_wrap(i, bool(self.signed[i])))
                i += 1
            elif e in (ENC_TAG8_8SVB, ENC_TAG2_3S32, ENC_TAG8_4S16):
                i = self._group(i, e, lines)
            elif not self.live[i] and e in _VARINT_OR_NULL:
                i = self._skipped_run(i, lines)
            else:
                self._single(i, e, lines)
                i += 1
        return lines

    def _group(self, i: int, e: int, lines: list[str]) -> int:
        """A group of fields sharing one tag header; the index after it."""
        n, live = self.n, self.live
        group: list[int]
        if e == ENC_TAG8_8SVB:
            j = i + 1
            while j < min(i + 8, n) and self.enc[j] == ENC_TAG8_8SVB:
                j += 1
            if not any(live[i:j]):  # no value needed: skip the set fields' varints
                if j - i == 1:
                    lines.append("    p = _skip_vb(d, p, 1)\n")
                else:
                    lines.append(
                        f"    p = _skip_vb(d, p + 1, _popcount[d[p] & {(1 << (j - i)) - 1}])\n"
                    )
                return j
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
                return group[-1] + 1
            lines.append("    g, p = _tag2_3s32(d, p)\n")
        else:
            group = list(range(i, min(i + 4, n)))
            if self.data_version >= 2 and not any(live[k] for k in group):
                lines.append("    p += 1 + _t4len[d[p]]\n")
                return group[-1] + 1
            call = "_t4v2[d[p]](d, p + 1)" if self.data_version >= 2 else "_tag8_4s16_v1(d, p)"
            lines.append(
                f"    if d[p] == 0:\n        g = _zeros; p += 1\n    else:\n        g, p = {call}\n"
            )
        for k, fi in enumerate(group):
            if not live[fi]:
                continue
            pe = prediction_code(fi, self.pred[fi], self.constants, self.motor0)
            lines.append(f"    f[{fi}] = g[{k}]" + ("" if pe == "0" else f" + {pe}") + "\n")
            if pe != "0":
                lines.append(_wrap(fi, bool(self.signed[fi])))
        return group[-1] + 1

    def _skipped_run(self, i: int, lines: list[str]) -> int:
        """A run of fields not kept: their varints are skipped, not decoded; the index after."""
        j = i
        while (
            j < self.n
            and not self.live[j]
            and self.pred[j] != PRED_INC
            and self.enc[j] in _VARINT_OR_NULL
        ):
            j += 1
        count = sum(1 for k in range(i, j) if self.enc[k] != ENC_NULL)
        if 0 < count <= 6:  # inline: most residuals are one byte each
            test = " and ".join(f"d[p + {k}] < 128" for k in range(count))
            lines.append(
                f"    if {test}:\n        p += {count}\n"
                f"    else:\n        p = _skip_vb(d, p, {count})\n"
            )
        elif count:
            lines.append(f"    p = _skip_vb(d, p, {count})\n")
        return j

    def _single(self, i: int, e: int, lines: list[str]) -> None:
        """One field with its own encoding."""
        if e == ENC_SIGNED_VB:
            lines.append(_UVB + "    v = (u >> 1) ^ -(u & 1)\n")
        elif e == ENC_UNSIGNED_VB:
            lines.append(_UVB + "    v = u\n")
        elif e == ENC_NEG_14BIT:
            lines.append(_UVB + "    v = -(u | -0x4000) if u & 0x2000 else -u\n")
        elif e == ENC_NULL:
            lines.append("    v = 0\n")
        else:
            raise CorruptFrame(f"unsupported field encoding {e} for field '{self.names[i]}'")
        if not self.live[i]:
            return
        pe = prediction_code(i, self.pred[i], self.constants, self.motor0)
        if pe == "0":
            lines.append(f"    f[{i}] = v\n")
            if e == ENC_UNSIGNED_VB:
                lines.append(_wrap(i, bool(self.signed[i])))
        else:
            lines.append(f"    f[{i}] = v + {pe}\n")
            lines.append(_wrap(i, bool(self.signed[i])))


_VARINT_OR_NULL = (ENC_SIGNED_VB, ENC_UNSIGNED_VB, ENC_NEG_14BIT, ENC_NULL)


def _exec_parser(source: str, fd: FrameDef, data_version: int) -> FrameParser:
    """The generated parser, compiled with the field readers it calls."""
    namespace: dict[str, Any] = {
        "_uvb_tail": _read_uvb_tail,
        "_skip_vb": _skip_vb,
        "_popcount": POPCOUNT,
        "_t2len": TAG2_3S32_LEN,
        "_t4len": TAG8_4S16_V2_LEN,
        "_tag8_8svb": _read_tag8_8svb,
        "_tag2_3s32": _read_tag2_3s32,
        "_tag8_4s16_v1": _read_tag8_4s16_v1,
        "_tag8_4s16_v2": _read_tag8_4s16_v2,
        "_t4v2": _tag8_4s16_v2_table() if data_version >= 2 else None,
        "_zeros": (0, 0, 0, 0, 0, 0, 0, 0),
    }
    exec(compile(source, f"<blackbox frame {fd.names[:1]}>", "exec"), namespace)
    parser: FrameParser = namespace["parse"]
    return parser


def _uvb(d: bytes, p: int) -> tuple[int, int]:
    b = d[p]
    return _read_uvb_tail(d, p + 1, b) if b & 0x80 else (b, p + 1)


def parse_event(d: bytes, p: int) -> tuple[int, tuple[float, ...], int]:
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
