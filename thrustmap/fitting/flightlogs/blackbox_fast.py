"""Vectorised decoding of a clean Betaflight blackbox log (numpy), exactly equal to the
per-frame decoder of :mod:`blackbox_decode` (the reference) whenever it applies.

The per-frame Python parser costs ~5 µs a frame (0.3 s of a 2 MB log). Here:

1. **Framing in C.** Every frame layout of the log is a regular language (a varint is
   ``[\\x80-\\xff]{0,4}[\\x00-\\x7f]``; a tagged group is its lead byte's class followed by the
   lengths that lead byte implies), so one compiled regular expression finds all frames with
   ``findall``. The frames must tile the data from the end of the headers to the end of the log
   (or its log-end event): then each one starts where the reference would parse it.
2. **Fields in bulk.** Each field of all I (or all P) frames is read at once with numpy gathers;
   the predictions are applied a step at a time across all I-frame-to-I-frame segments.
3. **The reference's checks, vectorised.** Iteration and time plausibility, 32-bit range, frame
   length and work budget are checked as the reference checks them.

Slow (S), GPS (G) and GPS-home (H) frames and events are framed by the same expression and
parsed one by one by the reference's own frame parsers (a few hundred in a log), with the state
the reference would give them (the home position, the last main frame's time).

A log whose frames tile the data only up to some point (a truncated tail, a corrupt frame, an
implausible one such as a clock rollover) is decoded in bulk up to the last frame before it, and
:func:`decode_log_bulk` returns the state there for the reference decoder to carry on from; the
reference can hand back at an intra frame past a corrupt stretch (``start``, see
:func:`blackbox_decode.decode_log`). Anything else the fast path does not cover (data version
1, home or last-time predictors in main frames, values needing the 32-bit wrap, a damaged start)
leaves the whole log to the reference decoder, so decoded values never depend on which path ran.
"""

from __future__ import annotations

import functools
import logging
import re
import sys
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from thrustmap.fitting.flightlogs import blackbox_decode as bd

log = logging.getLogger(__name__)

I64 = npt.NDArray[np.int64]

#: longest run of inter frames between two intra frames decoded step-wise (real logs: 1..256)
MAX_SEGMENT = 4096
#: predictors an intra frame may use here (none reads the previous frames)
I_PREDICTORS = frozenset(
    {bd.PRED_ZERO, bd.PRED_MINTHROTTLE, bd.PRED_MOTOR_0, bd.PRED_1500, bd.PRED_VBATREF,
     bd.PRED_MINMOTOR}
)  # fmt: skip
P_PREDICTORS = I_PREDICTORS | {
    bd.PRED_PREVIOUS,
    bd.PRED_STRAIGHT_LINE,
    bd.PRED_AVERAGE_2,
    bd.PRED_INC,
}
#: a varint; the possessive {0,4}+ matches the same (a continuation byte can never end it) and
#: saves the regex engine its backtracking bookkeeping (~25 % of the framing time); Python 3.10's
#: re has no possessive quantifiers, and the plain one matches the same frames
_VB = (
    rb"[\x80-\xff]{0,4}+[\x00-\x7f]"
    if sys.version_info >= (3, 11)
    else rb"[\x80-\xff]{0,4}[\x00-\x7f]"
)
_PAD = bytes(16)
_T2LEN = np.asarray(bd._TAG2_3S32_LEN, dtype=np.int64)
_T4LEN = np.asarray(bd._TAG8_4S16_V2_LEN, dtype=np.int64)
#: TAG8_4S16 field kinds 0..3: bits, value mask, sign bit (kind 0 reads 0; 1 gives it 0)
_T4BITS = np.array([0, 4, 8, 16], dtype=np.int64)
_T4MASK = np.array([0, 0xF, 0xFF, 0xFFFF], dtype=np.int64)
_T4SIGN = np.array([1, 0x8, 0x80, 0x8000], dtype=np.int64)


class _Unsupported(Exception):
    """The fast path does not cover this log: the reference decoder decodes it."""


class _CutBefore(Exception):
    """Frame ``frame`` is the first implausible main frame (a time rollover, a jump): the
    frames before it are decoded in bulk, the reference decoder takes over from it."""

    def __init__(self, frame: int) -> None:
        super().__init__(f"implausible main frame at frame {frame}")
        self.frame = frame


# --- framing ---------------------------------------------------------------------------------


def _byte_class(values: list[int]) -> bytes:
    out = []
    vs = sorted(values)
    k = 0
    while k < len(vs):
        j = k
        while j + 1 < len(vs) and vs[j + 1] == vs[j] + 1:
            j += 1
        out.append(b"\\x%02x" % vs[k] if j == k else b"\\x%02x-\\x%02x" % (vs[k], vs[j]))
        k = j + 1
    return b"[" + b"".join(out) + b"]"


def _by_length(lengths: list[int], extra: int) -> bytes:
    """A lead byte followed by ``lengths[lead] - extra`` bytes of any value."""
    groups: dict[int, list[int]] = {}
    for lead, ln in enumerate(lengths):
        groups.setdefault(ln - extra, []).append(lead)
    alts = [_byte_class(leads) + (b".{%d}" % ln if ln else b"") for ln, leads in groups.items()]
    return b"(?:" + b"|".join(alts) + b")"


def _units(fd: bd.FrameDef) -> list[tuple[int, list[int]]]:
    """The frame's byte units in order, as (encoding, field indices), consuming bytes exactly as
    :func:`blackbox_decode.compile_frame` does (PRED_INC fields outside groups read nothing)."""
    n = len(fd.names)
    enc = list(fd.encoding) + [bd.ENC_NULL] * (n - len(fd.encoding))
    pred = list(fd.predictor) + [bd.PRED_ZERO] * (n - len(fd.predictor))
    units: list[tuple[int, list[int]]] = []
    i = 0
    while i < n:
        if pred[i] == bd.PRED_INC:
            i += 1
            continue
        e = enc[i]
        if e == bd.ENC_TAG8_8SVB:
            j = i + 1
            while j < min(i + 8, n) and enc[j] == bd.ENC_TAG8_8SVB:
                j += 1
            group = list(range(i, j))
        elif e == bd.ENC_TAG2_3S32:
            group = list(range(i, min(i + 3, n)))
        elif e == bd.ENC_TAG8_4S16:
            group = list(range(i, min(i + 4, n)))
        elif e in (bd.ENC_SIGNED_VB, bd.ENC_UNSIGNED_VB, bd.ENC_NEG_14BIT, bd.ENC_NULL):
            group = [i]
        else:
            raise _Unsupported(f"encoding {e}")
        units.append((e, group))
        i = group[-1] + 1
    return units


@functools.lru_cache(maxsize=64)
def _unit_regex(e: int, count: int) -> bytes:
    if e == bd.ENC_TAG8_8SVB:
        if count == 1:
            return _VB
        mask = (1 << count) - 1
        alts = []
        for c in range(count + 1):
            heads = [h for h in range(256) if bd._POPCOUNT[h & mask] == c]
            alts.append(_byte_class(heads) + (b"(?:" + _VB + b"){%d}" % c if c else b""))
        return b"(?:" + b"|".join(alts) + b")"
    if e == bd.ENC_TAG2_3S32:
        return _by_length(bd._TAG2_3S32_LEN, 1)
    if e == bd.ENC_TAG8_4S16:
        return _by_length(bd._TAG8_4S16_V2_LEN, 0)
    if e == bd.ENC_NULL:
        return b""
    return _VB


def _frame_regex(fd: bd.FrameDef) -> bytes:
    return b"".join(_unit_regex(e, len(g)) for e, g in _units(fd))


#: events as :func:`blackbox_decode._parse_event` reads them
_EVENT_REGEX = (
    b"E(?:\\x00" + _VB
    + b"|\\x0d(?:[\\x80-\\xff].{4}|[\\x00-\\x7f]" + _VB + b")"
    + b"|\\x0e" + _VB + _VB
    + b"|\\x0f" + _VB
    + b"|\\x1e" + _VB + _VB
    + b"|\\xff" + re.escape(bd.END_OF_LOG_TEXT) + b")"
)  # fmt: skip


@functools.lru_cache(maxsize=8)
def _frames_pattern(
    i_re: bytes, p_re: bytes, aux: tuple[tuple[bytes, bytes], ...]
) -> re.Pattern[bytes]:
    """Any one frame: main frames first (most frames), then events and ``aux`` (marker,
    layout regex): slow, GPS and GPS-home frames."""
    alts = [b"P" + p_re, b"I" + i_re, _EVENT_REGEX]
    alts += [re.escape(marker) + layout for marker, layout in aux]
    return re.compile(b"|".join(alts), re.DOTALL)


# --- field decoding --------------------------------------------------------------------------


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
    raise _Unsupported("variable-byte integer longer than 5 bytes")


def _read_svb(buf: npt.NDArray[np.uint8], p: I64) -> tuple[I64, I64]:
    u, p = _read_uvb(buf, p)
    return (u >> 1) ^ -(u & 1), p


def _read_unit(buf: npt.NDArray[np.uint8], p: I64, e: int, count: int) -> tuple[list[I64], I64]:
    """Residuals of one unit for every frame (``count`` fields), and the positions after it."""
    if e in (bd.ENC_SIGNED_VB, bd.ENC_UNSIGNED_VB, bd.ENC_NEG_14BIT):
        u, p = _read_uvb(buf, p)
        if e == bd.ENC_SIGNED_VB:
            return [(u >> 1) ^ -(u & 1)], p
        if e == bd.ENC_NEG_14BIT:
            return [np.where(u & 0x2000, -(u | -0x4000), -u)], p
        return [u], p
    if e == bd.ENC_NULL:
        return [np.zeros(len(p), dtype=np.int64)], p
    if e == bd.ENC_TAG8_8SVB:
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
    if e == bd.ENC_TAG2_3S32:
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
    if e == bd.ENC_TAG8_4S16:  # data version 2: a big-endian nibble stream after the selector
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
    raise _Unsupported(f"encoding {e}")


_VARINTS = (bd.ENC_SIGNED_VB, bd.ENC_UNSIGNED_VB, bd.ENC_NEG_14BIT)


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


def _residuals(
    buf: npt.NDArray[np.uint8], starts: I64, fd: bd.FrameDef, col: dict[int, int]
) -> tuple[I64, I64]:
    """Residuals of the fields in ``col`` (field index -> column) of every frame of one layout,
    and each frame's end. Units holding no such field are only measured."""
    res = np.zeros((len(starts), len(col)), dtype=np.int64)
    p = starts + 1
    skip_run = 0  # varints (one field each) not needed, to skip at once
    for e, group in _units(fd):
        needed = any(fi in col for fi in group)
        if not needed and e in _VARINTS:
            skip_run += 1
            continue
        if skip_run:
            p = _skip_varints(buf, p, skip_run)
            skip_run = 0
        if not needed and e == bd.ENC_TAG2_3S32:
            p = p + _T2LEN[buf[p]]
        elif not needed and e == bd.ENC_TAG8_4S16:
            p = p + 1 + _T4LEN[buf[p]]
        elif needed or e != bd.ENC_NULL:
            vals, p = _read_unit(buf, p, e, len(group))
            for fi, v in zip(group, vals, strict=False):
                if fi in col:
                    res[:, col[fi]] = v
    if skip_run:
        p = _skip_varints(buf, p, skip_run)
    return res, p


def _constant(pred: int, constants: dict[str, int]) -> int | None:
    return {
        bd.PRED_ZERO: 0,
        bd.PRED_MINTHROTTLE: constants["minthrottle"],
        bd.PRED_1500: 1500,
        bd.PRED_VBATREF: constants["vbatref"],
        bd.PRED_MINMOTOR: constants["motor_low"],
    }.get(pred)


# --- the log ---------------------------------------------------------------------------------

#: a clean stretch shorter than this many frames is left to the reference decoder whole
MIN_PREFIX_FRAMES = 64


def decode_log_fast(
    section: bytes,
    index: int = 0,
    offset: int = 0,
    *,
    keep_field: Callable[[str], bool] | None = None,
) -> bd.DecodedLog | None:
    """What :func:`blackbox_decode.decode_log` returns for ``section`` when the fast path covers
    all of it, else None (the caller then runs the reference decoder)."""
    got = decode_log_bulk(section, index, offset, keep_field=keep_field)
    return got if isinstance(got, bd.DecodedLog) else None


def decode_log_bulk(
    section: bytes,
    index: int = 0,
    offset: int = 0,
    *,
    keep_field: Callable[[str], bool] | None = None,
    start: bd.ResumeState | None = None,
) -> bd.DecodedLog | bd.ResumeState | None:
    """The log decoded in bulk (a :class:`DecodedLog`); or, when only a first stretch of it is
    clean (a truncated tail, a corrupt frame further on), that stretch decoded in bulk as a
    :class:`ResumeState` for the reference decoder to carry on from; or None (the reference
    decodes it all). ``start``: carry on from where the reference decoder stopped (at an intra
    frame), with its state."""
    declined = (_Unsupported, bd.CorruptFrame, IndexError, ValueError, OverflowError)
    try:
        try:
            return _decode(section, index, offset, keep_field, start=start)
        except _CutBefore as cut:
            return _decode(section, index, offset, keep_field, cut.frame, start=start)
    except (*declined, _CutBefore) as exc:
        # the reference decoder decodes (or rejects) it, however odd the log
        log.debug("log %d: bulk decoding declined (%s)", index + 1, exc)
        return None


@functools.lru_cache(maxsize=32)
def _compiled(
    layout: tuple[tuple[str, ...], tuple[int, ...], tuple[int, ...], tuple[int, ...]],
    constants: tuple[tuple[str, int], ...],
) -> bd.FrameParser:
    fd = bd.FrameDef(*(list(x) for x in layout))  # type: ignore[arg-type]
    return bd.compile_frame(fd, constants=dict(constants), data_version=2)


def _aux_parser(fd: bd.FrameDef, constants: dict[str, int]) -> bd.FrameParser:
    """The reference's parser of a slow, GPS or GPS-home frame layout (data version 2),
    compiled once per layout: a flash dump holds dozens of logs sharing one layout."""
    layout = (tuple(fd.names), tuple(fd.signed), tuple(fd.predictor), tuple(fd.encoding))
    return _compiled(layout, tuple(sorted(constants.items())))


def _framing(
    pattern: re.Pattern[bytes], section: bytes, pos: int
) -> tuple[list[bytes], bool, bool]:
    """The frames from ``pos`` on, whether they tile the whole log (to its end or its log-end
    event), and whether it ended with that event. When they do not, only the frames that tile
    the data up to the first byte no frame covers are returned, less the last of them (the
    reference checks a frame by what follows it, so it takes over one frame early)."""
    n = len(section)
    # erased flash (0xFF) after a log cut off by a power loss: no frame there to look for
    data_end = len(section.rstrip(b"\xff")) if section.endswith(b"\xff\xff") else n
    frames: list[bytes] = pattern.findall(section, pos, data_end)
    end_marker = b"E\xff" + bd.END_OF_LOG_TEXT
    ended = False
    if end_marker in frames:
        frames = frames[: frames.index(end_marker) + 1]
        ended = True
    joined = b"".join(frames)
    if section.startswith(joined, pos) and (ended or pos + len(joined) == n):
        return frames, True, ended
    a = np.frombuffer(joined, dtype=np.uint8)
    b = np.frombuffer(section, dtype=np.uint8)[pos : pos + len(a)]
    differ = np.flatnonzero(a[: len(b)] != b)
    first_bad = int(differ[0]) if len(differ) else len(b)
    ends = np.cumsum(np.fromiter(map(len, frames), dtype=np.int64, count=len(frames)))
    count = int(np.searchsorted(ends, first_bad, side="right")) - 1
    return frames[: max(count, 0)], False, False


def _decode(
    section: bytes,
    index: int,
    offset: int,
    keep_field: Callable[[str], bool] | None,
    max_frames: int | None = None,
    *,
    start: bd.ResumeState | None = None,
) -> bd.DecodedLog | bd.ResumeState | None:
    """The log decoded in bulk, or its first ``max_frames`` frames (a :class:`ResumeState`);
    from ``start`` on when given."""
    headers, defs, pos = bd.parse_headers(section)
    if start is not None:
        pos = start.pos
    idef = defs.get("I")
    if idef is None or not idef.names or not idef.encoding:
        raise _Unsupported("no main-frame layout")
    pdef0 = defs.get("P", bd.FrameDef())
    if not pdef0.encoding:
        raise _Unsupported("no inter-frame layout")
    pdef = bd.FrameDef(idef.names, idef.signed, pdef0.predictor, pdef0.encoding)
    names = idef.names
    nf = len(names)
    if nf < 2 or bd.header_int(headers, "Data version", 2) < 2:
        raise _Unsupported("data version 1 or too few fields")
    motor0 = names.index("motor[0]") if "motor[0]" in names else -1
    minthrottle = bd.header_int(headers, "minthrottle", 1150)
    constants = {
        "minthrottle": minthrottle,
        "vbatref": bd.header_int(headers, "vbatref", 4095),
        "motor_low": bd.header_int(headers, "motorOutput", minthrottle, 0),
    }
    ipred = (list(idef.predictor) + [bd.PRED_ZERO] * nf)[:nf]
    ppred = (list(pdef.predictor) + [bd.PRED_ZERO] * nf)[:nf]
    if not set(ipred) <= I_PREDICTORS or not set(ppred) <= P_PREDICTORS:
        raise _Unsupported("predictor")
    for preds in (ipred, ppred):
        if any(pr == bd.PRED_MOTOR_0 and (motor0 < 0 or motor0 >= i) for i, pr in enumerate(preds)):
            raise _Unsupported("motor[0] prediction out of order")  # the reference raises
    i_interval = max(bd.header_int(headers, "I interval", 32), 1)
    if i_interval > bd.MAX_INTERVAL:
        raise _Unsupported("I interval")
    p_num, p_den = bd._p_interval(headers)
    skip = np.asarray(bd._skip_table(i_interval, p_num, p_den), dtype=np.int64)
    keep = bd._kept_fields(names, idef, pdef, motor0, keep_field)
    # slow (S), GPS (G) and GPS-home (H) frames: few, parsed by the reference's own parsers
    aux_defs = {ord(m): defs[m] for m in "SGH" if m in defs and defs[m].names and defs[m].encoding}
    aux_parsers = {m: _aux_parser(fd, constants) for m, fd in aux_defs.items()}
    pattern = _frames_pattern(
        _frame_regex(idef),
        _frame_regex(pdef),
        tuple((bytes([m]), _frame_regex(fd)) for m, fd in aux_defs.items()),
    )
    hdef = defs.get("H", bd.FrameDef())
    home_idx = [
        hdef.names.index(k) if k in hdef.names else -1 for k in ("GPS_home[0]", "GPS_home[1]")
    ]

    # 1. framing: the frames must tile the data up to the end (or the log-end event), or a
    #    first stretch of it that the reference decoder carries on from
    frames, complete, ended = _framing(pattern, section, pos)
    if max_frames is not None and max_frames < len(frames):
        frames, complete, ended = frames[:max_frames], False, False
    if not complete and len(frames) < MIN_PREFIX_FRAMES:
        raise _Unsupported("frames do not tile the data")
    n = len(section)
    lengths = np.fromiter(map(len, frames), dtype=np.int64, count=len(frames))
    if len(frames) and int(lengths.max()) - 1 > bd.MAX_FRAME_BYTES:
        raise _Unsupported("over-long frame")
    ends = pos + np.cumsum(lengths)
    starts = ends - lengths
    stop = int(ends[-1]) if len(frames) else pos
    buf = np.frombuffer(section + _PAD, dtype=np.uint8)
    kinds = buf[starts]
    is_main = (kinds == ord("I")) | (kinds == ord("P"))
    widths = np.where(is_main, max(nf, 1), 1)
    for m, fd in aux_defs.items():
        widths[kinds == m] = max(len(fd.names), 1)
    work_done = int(widths.sum()) + (start.work_done if start is not None else 0)
    if work_done + bd.MAX_FIELDS >= bd.WORK_PER_BYTE * n + 100_000:
        raise _Unsupported("work budget")

    # 2. main frames: residuals, then predictions segment by segment
    main_at = np.flatnonzero(is_main)
    if len(main_at) and kinds[main_at[0]] != ord("I"):
        raise _Unsupported("an inter frame before the first intra frame")
    mk = kinds[main_at]
    i_rows = np.flatnonzero(mk == ord("I"))
    p_rows = np.flatnonzero(mk == ord("P"))
    kept = list(range(nf)) if keep is None else sorted(keep)
    col = {fi: c for c, fi in enumerate(kept)}
    vals = np.empty((len(main_at), len(kept)), dtype=np.int64)
    if len(main_at):
        _main_values(buf, starts, ends, main_at, i_rows, p_rows, idef, pdef, col, kept, vals,
                     ipred, ppred, constants, motor0, skip, i_interval)  # fmt: skip

    # 3. slow, GPS and GPS-home frames and events, few: the reference's own parsers, in order,
    #    with the state they see there (the last main frame's time, or a resume event's)
    it = vals[:, 0]
    t = vals[:, 1]
    main_starts = starts[main_at]
    slow_rows: list[list[int]] = []
    slow_index: list[int] = []
    gps_rows: list[list[int]] = []
    events: list[bd.BlackboxEvent] = []
    stats = {k: 0 for k in ("I", "P", "S", "G", "H", "E")}
    stats.update(corrupt=0, dropped_p=0, invalid_main=0, skipped_bytes=0)
    home = [0, 0]
    first_it, first_t, base = -1, -1, 0  # the state before the first frame here
    if start is not None:
        slow_rows, slow_index = list(start.slow_rows), list(start.slow_index)
        gps_rows, events = list(start.gps_rows), list(start.events)
        stats.update(start.stats)
        home = list(start.home)
        first_it, first_t, base = start.last_iter, start.last_time, len(start.main)
    stats["I"] += len(i_rows)
    stats["P"] += len(p_rows)
    # the history each main frame is checked against: the previous one, or a logging resume
    last_it = np.concatenate(([first_it], it[:-1]))
    last_t = np.concatenate(([first_t], t[:-1]))
    resumed: tuple[int, int, int] | None = None  # (main frames before it, iteration, time)
    aux_at = np.flatnonzero(~is_main)
    aux_starts = starts[aux_at]
    for at, end, kind, before in zip(
        aux_starts.tolist(),
        ends[aux_at].tolist(),
        kinds[aux_at].tolist(),
        np.searchsorted(main_starts, aux_starts).tolist(),
        strict=True,
    ):
        if kind == ord("E"):
            ev, payload, p = bd._parse_event(section, at + 1)
            if ev == bd.EVENT_LOGGING_RESUME:
                resumed = (before, int(payload[0]), int(payload[1]))
                if before < len(main_at):
                    if mk[before] != ord("I"):
                        raise _Unsupported("an inter frame right after logging resumed")
                    last_it[before], last_t[before] = resumed[1], resumed[2]
            stats["E"] += 1
            events.append(bd.BlackboxEvent(base + before, ev, payload))
        else:
            if resumed is not None and resumed[0] == before:
                last_time = resumed[2]
            else:
                last_time = int(t[before - 1]) if before else first_t
            fd = aux_defs[kind]
            row, p = aux_parsers[kind](section, at + 1, [0] * len(fd.names), [], 0, last_time, home)
            if kind == ord("S"):
                stats["S"] += 1
                slow_rows.append(row)
                slow_index.append(base + before)
            elif kind == ord("G"):
                stats["G"] += 1
                gps_rows.append(row)
            else:
                stats["H"] += 1
                home = [row[j] if j >= 0 else 0 for j in home_idx]
        if p != end:
            raise _Unsupported("slow frame or event length disagrees")

    # 4. the reference's plausibility checks: the frames before the first main frame failing
    #    one (a time rollover, an iteration or time jump) are decoded in bulk, the rest by the
    #    reference
    di = it - last_it
    dt = t - last_t
    ip, tp = di[p_rows], dt[p_rows]
    bad = (t < 0) | (t > 0xFFFFFFFF)  # time outside 32 bits: a rollover
    bad[p_rows] |= (ip < 0) | (ip >= bd.MAX_ITERATION_JUMP) | (tp < 0) | (tp >= bd.MAX_TIME_JUMP_US)
    checked = i_rows[last_it[i_rows] >= 0]
    bad[checked] |= (di[checked] < 0) | (dt[checked] < 0)
    if bad.any():
        raise _CutBefore(int(main_at[int(np.argmax(bad))]))
    warnings = list(start.warnings) if start is not None else []
    warnings += [
        f"log {index + 1}: {1e-6 * (int(t[r]) - int(last_t[r])):.1f} s gap in the data "
        f"after t = {1e-6 * int(last_t[r]):.3f} s"
        for r in checked[dt[checked] >= bd.MAX_TIME_JUMP_US].tolist()
    ]
    _wrap_32bit(vals, kept, idef, pdef, constants, motor0)

    main = vals if start is None else np.concatenate((start.main, vals))
    if not complete:
        log.debug("log %d: bulk decoded up to byte %d of %d", index + 1, stop, n)
        last_iter, last_time = (int(it[-1]), int(t[-1])) if len(it) else (first_it, first_t)
        if resumed is not None and resumed[0] == len(main_at):
            last_iter, last_time = resumed[1], resumed[2]
        prev = vals[-1].tolist() if len(vals) else None
        prev2 = None
        if len(vals):
            prev2 = prev if mk[-1] == ord("I") else vals[-2].tolist()
        elif start is not None:
            prev, prev2 = start.prev, start.prev2
        return bd.ResumeState(
            pos=stop, main=main, prev=prev, prev2=prev2, last_iter=last_iter,
            last_time=last_time, home=home, work_done=work_done, slow_rows=slow_rows,
            slow_index=slow_index, gps_rows=gps_rows, events=events, stats=stats,
            warnings=warnings,
        )  # fmt: skip
    if start is not None and (summary := bd.corruption_summary(index, stats)) is not None:
        warnings.append(summary)  # the reference's closing warning on the stretch it decoded
    sdef = defs.get("S", bd.FrameDef())
    gdef = defs.get("G", bd.FrameDef())
    return bd.DecodedLog(
        index=index,
        headers=headers,
        main_fields=[names[k] for k in kept],
        main=main,
        slow_fields=list(sdef.names),
        slow=bd._table(slow_rows, len(sdef.names)),
        slow_frame_index=np.array(slow_index, dtype=np.int64),
        gps_fields=list(gdef.names),
        gps=bd._table(gps_rows, len(gdef.names)),
        events=events,
        stats=stats,
        warnings=warnings,
        ended_cleanly=ended,
        byte_range=(offset, offset + n),
    )


def _wrapped_by_reference(fd: bd.FrameDef, fi: int, constants: dict[str, int], motor0: int) -> bool:
    """Whether the reference's parser of ``fd`` wraps field ``fi`` to 32 bits in every frame
    (as :func:`blackbox_decode.compile_frame` writes it): a predicted field, an incremented one,
    an unsigned varint; not a bare signed residual."""
    n = len(fd.names)
    pred = (list(fd.predictor) + [bd.PRED_ZERO] * n)[fi]
    if pred == bd.PRED_INC:
        return True
    if bd._prediction(fi, pred, constants, motor0) != "0":
        return True
    enc = (list(fd.encoding) + [bd.ENC_NULL] * n)[fi]
    return enc == bd.ENC_UNSIGNED_VB


def _wrap_32bit(
    vals: I64,
    kept: list[int],
    idef: bd.FrameDef,
    pdef: bd.FrameDef,
    constants: dict[str, int],
    motor0: int,
) -> None:
    """The firmware's 32-bit wrap-around of the fields that left their range, in place.

    The reference wraps a field to 32 bits after each prediction. Every prediction but the
    average of the previous two (previous, straight line, increment, constants, motor[0]) is a
    sum, and a sum commutes with the reduction modulo 2**32, so a field the reference wraps in
    both intra and inter frames is wrapped once here, at the end, with the same result; averaged
    fields were wrapped at every step already (:func:`_main_values`). Betaflight 3.x logs
    rcCommand[3] below minthrottle, and motors below their low end when disarmed, as unsigned
    residuals that only the wrap brings back (1025 + (2**32 - 25) -> 1000). A field read bare
    (no prediction) or the loop iteration out of range: left to the reference."""
    if not len(vals):
        return
    names = idef.names
    signed = (list(idef.signed) + [0] * len(names))[: len(names)]
    for c, fi in enumerate(kept):
        if fi == 1:  # time: its rollovers are checked as the reference does (step 4)
            continue
        col = vals[:, c]
        lo, hi = (-(1 << 31), (1 << 31) - 1) if signed[fi] else (0, (1 << 32) - 1)
        if int(col.min()) >= lo and int(col.max()) <= hi:
            continue
        if (
            fi == 0
            or not _wrapped_by_reference(idef, fi, constants, motor0)
            or not _wrapped_by_reference(pdef, fi, constants, motor0)
        ):
            raise _Unsupported("a value needs the 32-bit wrap")
        if signed[fi]:
            vals[:, c] = ((col + 0x80000000) & 0xFFFFFFFF) - 0x80000000
        else:
            vals[:, c] = col & 0xFFFFFFFF


def _main_values(
    buf: npt.NDArray[np.uint8],
    starts: I64,
    ends: I64,
    main_at: I64,
    i_rows: I64,
    p_rows: I64,
    idef: bd.FrameDef,
    pdef: bd.FrameDef,
    col: dict[int, int],
    kept: list[int],
    vals: I64,
    ipred: list[int],
    ppred: list[int],
    constants: dict[str, int],
    motor0: int,
    skip: I64,
    i_interval: int,
) -> None:
    """Every main frame's values into ``vals`` (rows in frame order, columns ``kept``)."""
    ires, iend = _residuals(buf, starts[main_at[i_rows]], idef, col)
    pres, pend = _residuals(buf, starts[main_at[p_rows]], pdef, col)
    if not (
        np.array_equal(iend, ends[main_at[i_rows]]) and np.array_equal(pend, ends[main_at[p_rows]])
    ):
        raise _Unsupported("frame lengths disagree")  # not expected: the regex is the layout
    for fi in kept:  # intra frames: constants and motor[0] (which precedes its users)
        c = _constant(ipred[fi], constants)
        ires[:, col[fi]] += ires[:, col[motor0]] if c is None else c
    for fi in kept:  # inter frames: the constant part of their predictions
        c = _constant(ppred[fi], constants)
        if c:
            pres[:, col[fi]] += c
    signed = (list(idef.signed) + [0] * len(idef.names))[: len(idef.names)]
    for fi in kept:  # the 32-bit wrap of intra frames (see _wrap_32bit), but iteration and time
        if fi < 2:
            continue
        c = col[fi]
        lo, hi = (-(1 << 31), (1 << 31) - 1) if signed[fi] else (0, (1 << 32) - 1)
        if len(ires) and (int(ires[:, c].min()) < lo or int(ires[:, c].max()) > hi):
            if not _wrapped_by_reference(idef, fi, constants, motor0):
                raise _Unsupported("a value needs the 32-bit wrap")
            off = 1 << 31 if signed[fi] else 0
            ires[:, c] = ((ires[:, c] + off) & 0xFFFFFFFF) - off
    vals[i_rows] = ires
    vals[p_rows] = pres
    seg_len = np.diff(np.append(i_rows, len(main_at)))
    if int(seg_len.max()) > MAX_SEGMENT:
        raise _Unsupported("long run of inter frames")

    def cols(pred: int) -> list[int]:
        return [col[fi] for fi in kept if ppred[fi] == pred]

    prev_c, line_c = cols(bd.PRED_PREVIOUS), cols(bd.PRED_STRAIGHT_LINE)
    avg_c, inc_c, mot_c = cols(bd.PRED_AVERAGE_2), cols(bd.PRED_INC), cols(bd.PRED_MOTOR_0)
    # an average of the previous two does not commute with the 32-bit wrap as sums do: those
    # fields are wrapped at every step, as the reference wraps them (intra frames above)
    avg_off = np.array([1 << 31 if signed[kept[c]] else 0 for c in avg_c], dtype=np.int64)

    def predict(cur: I64, prev: I64, prev2: I64) -> None:
        """Add their predictions to inter frames ``cur`` (residuals) in place."""
        if prev_c:
            cur[:, prev_c] += prev[:, prev_c]
        if line_c:
            cur[:, line_c] += 2 * prev[:, line_c] - prev2[:, line_c]
        if avg_c:
            a = prev[:, avg_c] + prev2[:, avg_c]
            w = cur[:, avg_c] + ((a + (a < 0)) >> 1) + avg_off
            cur[:, avg_c] = (w & 0xFFFFFFFF) - avg_off
        if inc_c:
            last_iter = prev[:, 0]
            cur[:, inc_c] += (last_iter + skip[last_iter % i_interval] + 1)[:, None]
        if mot_c:
            cur[:, mot_c] += cur[:, [col[motor0]]]

    # all segments' step-th inter frame at once (after an intra frame, prev2 is prev)
    longest = int(seg_len.max())
    if len(i_rows) * longest <= 2 * len(vals) + 4096:
        # segments (nearly) all of one length, as in real logs: laid out on a grid (segment,
        # step) each step is a view, not a gather; the padding rows are never read back
        at = np.repeat(np.arange(len(i_rows)) * longest - i_rows, seg_len) + np.arange(len(vals))
        grid = np.zeros((len(i_rows) * longest, vals.shape[1]), dtype=np.int64)
        grid[at] = vals
        g = grid.reshape(len(i_rows), longest, vals.shape[1])
        for step in range(1, longest):
            predict(g[:, step], g[:, step - 1], g[:, step - 1 if step == 1 else step - 2])
        vals[:] = grid[at]
        return
    for step in range(1, longest):
        rows = i_rows[seg_len > step] + step
        cur = vals[rows]
        prev = vals[rows - 1]
        predict(cur, prev, prev if step == 1 else vals[rows - 2])
        vals[rows] = cur
