"""Reading the fields of every frame of one layout at once (numpy gathers), from the frame
starts :mod:`blackbox_framing` found: the residuals before any prediction.

Part of the bulk decoder (:mod:`blackbox_fast`).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from thrustmap.flightlogs import blackbox_format as fmt
from thrustmap.flightlogs import blackbox_frames as bfr
from thrustmap.flightlogs.blackbox_framing import Unsupported, units

I64 = npt.NDArray[np.int64]

_T2LEN = np.asarray(bfr.TAG2_3S32_LEN, dtype=np.int64)
_T4LEN = np.asarray(bfr.TAG8_4S16_V2_LEN, dtype=np.int64)
#: TAG8_4S16 field kinds 0..3: bits, value mask, sign bit (kind 0 reads 0; 1 gives it 0)
_T4BITS = np.array([0, 4, 8, 16], dtype=np.int64)
_T4MASK = np.array([0, 0xF, 0xFF, 0xFFFF], dtype=np.int64)
_T4SIGN = np.array([1, 0x8, 0x80, 0x8000], dtype=np.int64)


def _sext(v: I64, bits: int | I64) -> I64:
    sign = np.left_shift(1, np.asarray(bits, dtype=np.int64) - 1)
    return (v & (sign - 1)) - (v & sign)  # type: ignore[no-any-return]


def _read_uvb(buf: npt.NDArray[np.uint8], p: I64) -> tuple[I64, I64]:
    b = buf[p].astype(np.int64)
    u = b & 0x7F
    cont = np.flatnonzero(b >= 0x80)
    if not len(cont):
        return u, p + 1
    ln = np.ones_like(p)
    for k in range(1, 5):
        bb = buf[p[cont] + k].astype(np.int64)
        u[cont] |= (bb & 0x7F) << (7 * k)
        ln[cont] += 1
        cont = cont[bb >= 0x80]
        if not len(cont):
            return u, p + ln
    raise Unsupported("variable-byte integer longer than 5 bytes")


def _read_svb(buf: npt.NDArray[np.uint8], p: I64) -> tuple[I64, I64]:
    u, p = _read_uvb(buf, p)
    return (u >> 1) ^ -(u & 1), p


def _read_unit(buf: npt.NDArray[np.uint8], p: I64, e: int, count: int) -> tuple[list[I64], I64]:
    """Residuals of one unit for every frame (``count`` fields), and the positions after it."""
    if e in (fmt.ENC_SIGNED_VB, fmt.ENC_UNSIGNED_VB, fmt.ENC_NEG_14BIT):
        u, p = _read_uvb(buf, p)
        if e == fmt.ENC_SIGNED_VB:
            return [(u >> 1) ^ -(u & 1)], p
        if e == fmt.ENC_NEG_14BIT:
            return [np.where(u & 0x2000, -(u | -0x4000), -u)], p
        return [u], p
    if e == fmt.ENC_NULL:
        return [np.zeros(len(p), dtype=np.int64)], p
    if e == fmt.ENC_TAG8_8SVB:
        if count == 1:
            v, p = _read_svb(buf, p)
            return [v], p
        head = buf[p].astype(np.int64)
        p = p + 1
        out = []
        for i in range(count):
            v = np.zeros(len(p), dtype=np.int64)
            has = np.flatnonzero(head & (1 << i))
            if len(has):
                v[has], p[has] = _read_svb(buf, p[has])
            out.append(v)
        return out, p
    if e == fmt.ENC_TAG2_3S32:
        lead = buf[p].astype(np.int64)
        b1 = buf[p + 1].astype(np.int64)
        b2 = buf[p + 2].astype(np.int64)
        sel = lead >> 6
        o0 = np.empty(len(p), dtype=np.int64)
        o1 = np.empty_like(o0)
        o2 = np.empty_like(o0)
        for s, (x0, x1, x2, bits) in enumerate(
            (
                ((lead >> 4) & 3, (lead >> 2) & 3, lead & 3, 2),
                (lead & 0xF, b1 >> 4, b1 & 0xF, 4),
                (lead & 0x3F, b1 & 0x3F, b2 & 0x3F, 6),
            )
        ):
            m = sel == s
            o0[m] = _sext(x0[m], bits)
            o1[m] = _sext(x1[m], bits)
            o2[m] = _sext(x2[m], bits)
        big = np.flatnonzero(sel == 3)
        if len(big):
            q = p[big] + 1
            lb = lead[big]
            for k, o in enumerate((o0, o1, o2)):
                nbytes = ((lb >> (2 * k)) & 3) + 1
                word = np.zeros(len(big), dtype=np.int64)
                for j in range(4):
                    byte = buf[q + j].astype(np.int64) << (8 * j)
                    word |= np.where(j < nbytes, byte, 0)
                o[big] = _sext(word, 8 * nbytes)
                q = q + nbytes
        return [o0, o1, o2][:count], p + _T2LEN[lead]
    if e == fmt.ENC_TAG8_4S16:  # data version 2: a big-endian nibble stream after the selector
        selector = buf[p].astype(np.int64)
        nib = np.zeros(len(p), dtype=np.int64)
        outs = []
        for i in range(4):
            kind = (selector >> (2 * i)) & 3
            bits = _T4BITS[kind]
            at = p + 1 + (nib >> 1)
            word = (
                (buf[at].astype(np.int64) << 16)
                | (buf[at + 1].astype(np.int64) << 8)
                | buf[at + 2].astype(np.int64)
            )
            raw = (word >> (24 - 4 * (nib & 1) - bits)) & _T4MASK[kind]
            sign = _T4SIGN[kind]  # raw < 2 * sign: (raw ^ sign) - sign sign-extends it
            outs.append((raw ^ sign) - sign)
            nib += bits >> 2
        return outs[:count], p + 1 + ((nib + 1) >> 1)
    raise Unsupported(f"encoding {e}")


_VARINTS = (fmt.ENC_SIGNED_VB, fmt.ENC_UNSIGNED_VB, fmt.ENC_NEG_14BIT)


def _skip_varints(buf: npt.NDArray[np.uint8], p: I64, count: int) -> I64:
    """Positions after ``count`` varints whose values are not needed."""
    bits = buf[p]  # OR of the bytes: one gather a byte (a 2-D gather costs ~5x more)
    for k in range(1, count):
        bits = bits | buf[p + k]
    out = p + count
    slow = np.flatnonzero(bits >= 0x80)  # some varint longer than one byte
    if len(slow):
        q = p[slow]
        for _ in range(count):
            q = _read_uvb(buf, q)[1]
        out[slow] = q
    return out


def residuals(
    buf: npt.NDArray[np.uint8], starts: I64, fd: fmt.FrameDef, col: dict[int, int]
) -> tuple[I64, I64]:
    """Residuals of the fields in ``col`` (field index -> column) of every frame of one layout,
    and each frame's end. Units holding no such field are only measured."""
    res = np.zeros((len(starts), len(col)), dtype=np.int64)
    p = starts + 1
    skip_run = 0  # varints (one field each) not needed, to skip at once
    for e, group in units(fd):
        needed = any(fi in col for fi in group)
        if not needed and e in _VARINTS:
            skip_run += 1
            continue
        if skip_run:
            p = _skip_varints(buf, p, skip_run)
            skip_run = 0
        if not needed and e == fmt.ENC_TAG2_3S32:
            p = p + _T2LEN[buf[p]]
        elif not needed and e == fmt.ENC_TAG8_4S16:
            p = p + 1 + _T4LEN[buf[p]]
        elif needed or e != fmt.ENC_NULL:
            vals, p = _read_unit(buf, p, e, len(group))
            for fi, v in zip(group, vals, strict=False):
                if fi in col:
                    res[:, col[fi]] = v
    if skip_run:
        p = _skip_varints(buf, p, skip_run)
    return res, p


def constant_prediction(pred: int, constants: dict[str, int]) -> int | None:
    return {
        fmt.PRED_ZERO: 0,
        fmt.PRED_MINTHROTTLE: constants["minthrottle"],
        fmt.PRED_1500: 1500,
        fmt.PRED_VBATREF: constants["vbatref"],
        fmt.PRED_MINMOTOR: constants["motor_low"],
    }.get(pred)
