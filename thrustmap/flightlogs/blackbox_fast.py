"""Vectorised decoding of a clean Betaflight blackbox log (numpy), exactly equal to the
per-frame decoder of :mod:`blackbox_decode` (the reference) whenever it applies.

The per-frame Python parser costs ~5 µs a frame (0.3 s of a 2 MB log). Here:

1. **Framing in C** (:mod:`blackbox_framing`). Every frame layout of the log is a regular
   language (a varint is ``[\\x80-\\xff]{0,4}[\\x00-\\x7f]``; a tagged group is its lead byte's
   class followed by the lengths that lead byte implies), so one compiled regular expression
   finds all frames with ``findall``. The frames must tile the data from the end of the headers
   to the end of the log (or its log-end event): then each one starts where the reference would
   parse it.
2. **Fields in bulk** (:mod:`blackbox_columns`). Each field of all I (or all P) frames is read
   at once with numpy gathers; the predictions are applied a step at a time across all
   I-frame-to-I-frame segments.
3. **The reference's checks, vectorised.** Iteration and time plausibility, frame length and
   work budget are checked as the reference checks them; fields are wrapped to 32 bits as the
   reference wraps them.

Slow (S), GPS (G) and GPS-home (H) frames and events are framed by the same expression and
parsed one by one by the reference's own frame parsers (a few hundred in a log), with the state
the reference would give them (the home position, the last main frame's time).

A log whose frames tile the data only up to some point (a truncated tail, a corrupt frame, an
implausible one such as a clock rollover) is decoded in bulk up to the last frame before it, and
:func:`decode_log_bulk` returns the state there for the reference decoder to carry on from; the
reference can hand back at an intra frame past a corrupt stretch (``start``, see
:func:`blackbox_decode.decode_log`). Anything else the fast path does not cover (data version
1, home or last-time predictors in main frames, a bare residual beyond 32 bits, a damaged start)
leaves the whole log to the reference decoder, so decoded values never depend on which path ran.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from thrustmap.flightlogs import blackbox_format as fmt
from thrustmap.flightlogs import blackbox_frames as bfr
from thrustmap.flightlogs.blackbox_columns import constant_prediction, residuals
from thrustmap.flightlogs.blackbox_framing import (
    Unsupported,
    frame_regex,
    frames_pattern,
    framing,
)

log = logging.getLogger(__name__)

I64 = npt.NDArray[np.int64]

#: longest run of inter frames between two intra frames decoded step-wise (real logs: 1..256)
MAX_SEGMENT = 4096
#: predictors an intra frame may use here (none reads the previous frames)
I_PREDICTORS = frozenset(
    {fmt.PRED_ZERO, fmt.PRED_MINTHROTTLE, fmt.PRED_MOTOR_0, fmt.PRED_1500, fmt.PRED_VBATREF,
     fmt.PRED_MINMOTOR}
)  # fmt: skip
P_PREDICTORS = I_PREDICTORS | {
    fmt.PRED_PREVIOUS,
    fmt.PRED_STRAIGHT_LINE,
    fmt.PRED_AVERAGE_2,
    fmt.PRED_INC,
}
_PAD = bytes(16)


class _CutBefore(Exception):
    """Frame ``frame`` is the first implausible main frame (a time rollover, a jump): the
    frames before it are decoded in bulk, the reference decoder takes over from it."""

    def __init__(self, frame: int) -> None:
        super().__init__(f"implausible main frame at frame {frame}")
        self.frame = frame


# --- the log ---------------------------------------------------------------------------------

#: a clean stretch shorter than this many frames is left to the reference decoder whole
MIN_PREFIX_FRAMES = 64


def decode_log_fast(
    section: bytes,
    index: int = 0,
    offset: int = 0,
    *,
    keep_field: Callable[[str], bool] | None = None,
) -> fmt.DecodedLog | None:
    """What :func:`blackbox_decode.decode_log` returns for ``section`` when the fast path covers
    all of it, else None (the caller then runs the reference decoder)."""
    got = decode_log_bulk(section, index, offset, keep_field=keep_field)
    return got if isinstance(got, fmt.DecodedLog) else None


def decode_log_bulk(
    section: bytes,
    index: int = 0,
    offset: int = 0,
    *,
    keep_field: Callable[[str], bool] | None = None,
    start: fmt.ResumeState | None = None,
) -> fmt.DecodedLog | fmt.ResumeState | None:
    """The log decoded in bulk (a :class:`DecodedLog`); or, when only a first stretch of it is
    clean (a truncated tail, a corrupt frame further on), that stretch decoded in bulk as a
    :class:`ResumeState` for the reference decoder to carry on from; or None (the reference
    decodes it all). ``start``: carry on from where the reference decoder stopped (at an intra
    frame), with its state."""
    declined = (Unsupported, fmt.CorruptFrame, IndexError, ValueError, OverflowError)
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
) -> fmt.FrameParser:
    fd = fmt.FrameDef(*(list(x) for x in layout))  # type: ignore[arg-type]
    return bfr.compile_frame(fd, constants=dict(constants), data_version=2)


def _aux_parser(fd: fmt.FrameDef, constants: dict[str, int]) -> fmt.FrameParser:
    """The reference's parser of a slow, GPS or GPS-home frame layout (data version 2),
    compiled once per layout: a flash dump holds dozens of logs sharing one layout."""
    layout = (tuple(fd.names), tuple(fd.signed), tuple(fd.predictor), tuple(fd.encoding))
    return _compiled(layout, tuple(sorted(constants.items())))


@dataclass(frozen=True)
class _Layout:
    """What the headers say the main, slow, GPS and GPS-home frames are, checked for what the
    bulk decoder supports."""

    headers: dict[str, str]
    defs: dict[str, fmt.FrameDef]
    idef: fmt.FrameDef
    pdef: fmt.FrameDef
    motor0: int
    constants: dict[str, int]
    ipred: list[int]
    ppred: list[int]
    i_interval: int
    skip: I64
    kept: list[int]  # the main-frame fields decoded (columns of the values, in order)
    col: dict[int, int]  # field -> its column
    aux_defs: dict[int, fmt.FrameDef]
    aux_parsers: dict[int, fmt.FrameParser]
    home_idx: list[int]

    @property
    def names(self) -> list[str]:
        return list(self.idef.names)


def _layout(headers: dict[str, str], defs: dict[str, fmt.FrameDef],
            keep_field: Callable[[str], bool] | None) -> _Layout:  # fmt: skip
    idef = defs.get("I")
    if idef is None or not idef.names or not idef.encoding:
        raise Unsupported("no main-frame layout")
    pdef0 = defs.get("P", fmt.FrameDef())
    if not pdef0.encoding:
        raise Unsupported("no inter-frame layout")
    pdef = fmt.FrameDef(idef.names, idef.signed, pdef0.predictor, pdef0.encoding)
    names = idef.names
    nf = len(names)
    if nf < 2 or fmt.header_int(headers, "Data version", 2) < 2:
        raise Unsupported("data version 1 or too few fields")
    motor0 = names.index("motor[0]") if "motor[0]" in names else -1
    minthrottle = fmt.header_int(headers, "minthrottle", 1150)
    constants = {
        "minthrottle": minthrottle,
        "vbatref": fmt.header_int(headers, "vbatref", 4095),
        "motor_low": fmt.header_int(headers, "motorOutput", minthrottle, 0),
    }
    ipred = (list(idef.predictor) + [fmt.PRED_ZERO] * nf)[:nf]
    ppred = (list(pdef.predictor) + [fmt.PRED_ZERO] * nf)[:nf]
    if not set(ipred) <= I_PREDICTORS or not set(ppred) <= P_PREDICTORS:
        raise Unsupported("predictor")
    for preds in (ipred, ppred):
        if any(
            pr == fmt.PRED_MOTOR_0 and (motor0 < 0 or motor0 >= i) for i, pr in enumerate(preds)
        ):
            raise Unsupported("motor[0] prediction out of order")  # the reference raises
    i_interval = max(fmt.header_int(headers, "I interval", 32), 1)
    if i_interval > fmt.MAX_INTERVAL:
        raise Unsupported("I interval")
    p_num, p_den = fmt.p_interval(headers)
    skip = np.asarray(fmt.p_skip_counts(i_interval, p_num, p_den), dtype=np.int64)
    keep = fmt.kept_fields(names, idef, pdef, motor0, keep_field)
    kept = list(range(nf)) if keep is None else sorted(keep)
    # slow (S), GPS (G) and GPS-home (H) frames: few, parsed by the reference's own parsers
    aux_defs = {ord(m): defs[m] for m in "SGH" if m in defs and defs[m].names and defs[m].encoding}
    hdef = defs.get("H", fmt.FrameDef())
    return _Layout(
        headers=headers, defs=defs, idef=idef, pdef=pdef, motor0=motor0, constants=constants,
        ipred=ipred, ppred=ppred, i_interval=i_interval, skip=skip, kept=kept,
        col={fi: c for c, fi in enumerate(kept)}, aux_defs=aux_defs,
        aux_parsers={m: _aux_parser(fd, constants) for m, fd in aux_defs.items()},
        home_idx=[
            hdef.names.index(k) if k in hdef.names else -1 for k in ("GPS_home[0]", "GPS_home[1]")
        ],
    )  # fmt: skip


@dataclass
class _Frames:
    """Where every frame of the stretch is (framing), and which are main frames."""

    buf: npt.NDArray[np.uint8]
    starts: I64
    ends: I64
    kinds: npt.NDArray[np.uint8]
    is_main: npt.NDArray[np.bool_]
    main_at: I64  # frame index of each main frame
    mk: npt.NDArray[np.uint8]  # each main frame's kind
    i_rows: I64  # main-frame rows of intra frames
    p_rows: I64
    complete: bool
    ended: bool
    stop: int  # the byte the frames reach
    work_done: int


def _frame(
    layout: _Layout,
    section: bytes,
    pos: int,
    max_frames: int | None,
    start: fmt.ResumeState | None,
) -> _Frames:
    """Step 1, framing: the frames must tile the data up to the end (or the log-end event), or a
    first stretch of it that the reference decoder carries on from."""
    pattern = frames_pattern(
        frame_regex(layout.idef),
        frame_regex(layout.pdef),
        tuple((bytes([m]), frame_regex(fd)) for m, fd in layout.aux_defs.items()),
    )
    frames, lengths, complete, ended = framing(pattern, section, pos)
    if max_frames is not None and max_frames < len(frames):
        frames, complete, ended = frames[:max_frames], False, False
        lengths = lengths[:max_frames]
    if not complete and len(frames) < MIN_PREFIX_FRAMES:
        raise Unsupported("frames do not tile the data")
    n = len(section)
    if len(frames) and int(lengths.max()) - 1 > fmt.MAX_FRAME_BYTES:
        raise Unsupported("over-long frame")
    ends = pos + np.cumsum(lengths)
    starts = ends - lengths
    buf = np.frombuffer(section + _PAD, dtype=np.uint8)
    kinds = buf[starts]
    is_main = (kinds == ord("I")) | (kinds == ord("P"))
    widths = np.where(is_main, max(len(layout.idef.names), 1), 1)
    for m, fd in layout.aux_defs.items():
        widths[kinds == m] = max(len(fd.names), 1)
    work_done = int(widths.sum()) + (start.work_done if start is not None else 0)
    if work_done + fmt.MAX_FIELDS >= fmt.WORK_PER_BYTE * n + 100_000:
        raise Unsupported("work budget")
    main_at = np.flatnonzero(is_main)
    if len(main_at) and kinds[main_at[0]] != ord("I"):
        raise Unsupported("an inter frame before the first intra frame")
    mk = kinds[main_at]
    return _Frames(
        buf=buf, starts=starts, ends=ends, kinds=kinds, is_main=is_main, main_at=main_at, mk=mk,
        i_rows=np.flatnonzero(mk == ord("I")), p_rows=np.flatnonzero(mk == ord("P")),
        complete=complete, ended=ended, stop=int(ends[-1]) if len(frames) else pos,
        work_done=work_done,
    )  # fmt: skip


@dataclass
class _Aux:
    """The slow, GPS and GPS-home frames and events, and the state each main frame is checked
    against (the previous main frame's iteration and time, or a logging resume's)."""

    slow_rows: list[list[int]] = field(default_factory=list)
    slow_index: list[int] = field(default_factory=list)
    gps_rows: list[list[int]] = field(default_factory=list)
    events: list[fmt.BlackboxEvent] = field(default_factory=list)
    stats: dict[str, int] = field(default_factory=dict)
    home: list[int] = field(default_factory=lambda: [0, 0])
    first_it: int = -1  # the state before the first frame here
    first_t: int = -1
    base: int = 0  # main frames decoded before this stretch
    warnings: list[str] = field(default_factory=list)
    resumed: tuple[int, int, int] | None = None  # (main frames before it, iteration, time)

    @classmethod
    def after(cls, start: fmt.ResumeState | None) -> _Aux:
        stats = fmt.frame_stats(start)
        if start is None:
            return cls(stats=stats)
        return cls(
            list(start.slow_rows), list(start.slow_index), list(start.gps_rows),
            list(start.events), stats, list(start.home), start.last_iter, start.last_time,
            len(start.main), list(start.warnings),
        )  # fmt: skip


def _decode(
    section: bytes,
    index: int,
    offset: int,
    keep_field: Callable[[str], bool] | None,
    max_frames: int | None = None,
    *,
    start: fmt.ResumeState | None = None,
) -> fmt.DecodedLog | fmt.ResumeState | None:
    """The log decoded in bulk, or its first ``max_frames`` frames (a :class:`ResumeState`);
    from ``start`` on when given."""
    headers, defs, pos = fmt.parse_headers(section)
    if start is not None:
        pos = start.pos
    layout = _layout(headers, defs, keep_field)
    fr = _frame(layout, section, pos, max_frames, start)
    # 2. main frames: residuals, then predictions segment by segment
    vals = np.empty((len(fr.main_at), len(layout.kept)), dtype=np.int64)
    if len(fr.main_at):
        _main_values(layout, fr, vals)
    aux = _Aux.after(start)
    aux.stats["I"] += len(fr.i_rows)
    aux.stats["P"] += len(fr.p_rows)
    last_it, last_t = _aux_frames(layout, fr, section, vals, aux)
    _check_main(fr, vals, last_it, last_t, index, aux)
    _wrap_32bit(vals, layout.kept, layout.idef, layout.pdef, layout.constants, layout.motor0)
    main = vals if start is None else np.concatenate((start.main, vals))
    if not fr.complete:
        log.debug("log %d: bulk decoded up to byte %d of %d", index + 1, fr.stop, len(section))
        return _resume_state(fr, vals, main, aux, start)
    if start is not None and (summary := fmt.corruption_summary(index, aux.stats)) is not None:
        aux.warnings.append(summary)  # the reference's closing warning on the stretch it decoded
    sdef = defs.get("S", fmt.FrameDef())
    gdef = defs.get("G", fmt.FrameDef())
    return fmt.DecodedLog(
        index=index,
        headers=headers,
        main_fields=[layout.names[k] for k in layout.kept],
        main=main,
        slow_fields=list(sdef.names),
        slow=fmt.rows_to_table(aux.slow_rows, len(sdef.names)),
        slow_frame_index=np.array(aux.slow_index, dtype=np.int64),
        gps_fields=list(gdef.names),
        gps=fmt.rows_to_table(aux.gps_rows, len(gdef.names)),
        events=aux.events,
        stats=aux.stats,
        warnings=aux.warnings,
        ended_cleanly=fr.ended,
        byte_range=(offset, offset + len(section)),
    )


def _aux_frames(
    layout: _Layout, fr: _Frames, section: bytes, vals: I64, aux: _Aux
) -> tuple[I64, I64]:
    """Step 3: slow, GPS and GPS-home frames and events, few: the reference's own parsers, in
    order, with the state they see there (the last main frame's time, or a resume event's).
    Returns the iteration and time each main frame is checked against."""
    it, t = vals[:, 0], vals[:, 1]
    main_starts = fr.starts[fr.main_at]
    # the history each main frame is checked against: the previous one, or a logging resume
    last_it = np.concatenate(([aux.first_it], it[:-1]))
    last_t = np.concatenate(([aux.first_t], t[:-1]))
    aux_at = np.flatnonzero(~fr.is_main)
    aux_starts = fr.starts[aux_at]
    for at, end, kind, before in zip(
        aux_starts.tolist(),
        fr.ends[aux_at].tolist(),
        fr.kinds[aux_at].tolist(),
        np.searchsorted(main_starts, aux_starts).tolist(),
        strict=True,
    ):
        if kind == ord("E"):
            ev, payload, p = bfr.parse_event(section, at + 1)
            if ev == fmt.EVENT_LOGGING_RESUME:
                aux.resumed = (before, int(payload[0]), int(payload[1]))
                if before < len(fr.main_at):
                    if fr.mk[before] != ord("I"):
                        raise Unsupported("an inter frame right after logging resumed")
                    last_it[before], last_t[before] = aux.resumed[1], aux.resumed[2]
            aux.stats["E"] += 1
            aux.events.append(fmt.BlackboxEvent(aux.base + before, ev, payload))
        else:
            if aux.resumed is not None and aux.resumed[0] == before:
                last_time = aux.resumed[2]
            else:
                last_time = int(t[before - 1]) if before else aux.first_t
            fd = layout.aux_defs[kind]
            row, p = layout.aux_parsers[kind](
                section, at + 1, [0] * len(fd.names), [], 0, last_time, aux.home
            )
            if kind == ord("S"):
                aux.stats["S"] += 1
                aux.slow_rows.append(row)
                aux.slow_index.append(aux.base + before)
            elif kind == ord("G"):
                aux.stats["G"] += 1
                aux.gps_rows.append(row)
            else:
                aux.stats["H"] += 1
                aux.home = [row[j] if j >= 0 else 0 for j in layout.home_idx]
        if p != end:
            raise Unsupported("slow frame or event length disagrees")
    return last_it, last_t


def _check_main(fr: _Frames, vals: I64, last_it: I64, last_t: I64, index: int, aux: _Aux) -> None:
    """Step 4, the reference's plausibility checks: the frames before the first main frame
    failing one (a time rollover, an iteration or time jump) are decoded in bulk, the rest by
    the reference (``_CutBefore``). A long gap is a warning."""
    it, t = vals[:, 0], vals[:, 1]
    di = it - last_it
    dt = t - last_t
    ip, tp = di[fr.p_rows], dt[fr.p_rows]
    bad = (t < 0) | (t > 0xFFFFFFFF)  # time outside 32 bits: a rollover
    bad[fr.p_rows] |= (
        (ip < 0) | (ip >= fmt.MAX_ITERATION_JUMP) | (tp < 0) | (tp >= fmt.MAX_TIME_JUMP_US)
    )
    checked = fr.i_rows[last_it[fr.i_rows] >= 0]
    bad[checked] |= (di[checked] < 0) | (dt[checked] < 0)
    if bad.any():
        raise _CutBefore(int(fr.main_at[int(np.argmax(bad))]))
    aux.warnings += [
        f"log {index + 1}: {1e-6 * (int(t[r]) - int(last_t[r])):.1f} s gap in the data "
        f"after t = {1e-6 * int(last_t[r]):.3f} s"
        for r in checked[dt[checked] >= fmt.MAX_TIME_JUMP_US].tolist()
    ]


def _resume_state(
    fr: _Frames, vals: I64, main: I64, aux: _Aux, start: fmt.ResumeState | None
) -> fmt.ResumeState:
    """Where the reference decoder carries on from, after the stretch decoded in bulk."""
    it, t = vals[:, 0], vals[:, 1]
    last_iter, last_time = (int(it[-1]), int(t[-1])) if len(it) else (aux.first_it, aux.first_t)
    if aux.resumed is not None and aux.resumed[0] == len(fr.main_at):
        last_iter, last_time = aux.resumed[1], aux.resumed[2]
    prev = vals[-1].tolist() if len(vals) else None
    prev2 = None
    if len(vals):
        prev2 = prev if fr.mk[-1] == ord("I") else vals[-2].tolist()
    elif start is not None:
        prev, prev2 = start.prev, start.prev2
    return fmt.ResumeState(
        pos=fr.stop, main=main, prev=prev, prev2=prev2, last_iter=last_iter,
        last_time=last_time, home=aux.home, work_done=fr.work_done, slow_rows=aux.slow_rows,
        slow_index=aux.slow_index, gps_rows=aux.gps_rows, events=aux.events, stats=aux.stats,
        warnings=aux.warnings,
    )  # fmt: skip


def _wrapped_by_reference(
    fd: fmt.FrameDef, fi: int, constants: dict[str, int], motor0: int
) -> bool:
    """Whether the reference's parser of ``fd`` wraps field ``fi`` to 32 bits in every frame
    (as :func:`blackbox_frames.compile_frame` writes it): a predicted field, an incremented one,
    an unsigned varint; not a bare signed residual."""
    n = len(fd.names)
    pred = (list(fd.predictor) + [fmt.PRED_ZERO] * n)[fi]
    if pred == fmt.PRED_INC:
        return True
    if bfr.prediction_code(fi, pred, constants, motor0) != "0":
        return True
    enc = (list(fd.encoding) + [fmt.ENC_NULL] * n)[fi]
    return enc == fmt.ENC_UNSIGNED_VB


def _wrap_32bit(
    vals: I64,
    kept: list[int],
    idef: fmt.FrameDef,
    pdef: fmt.FrameDef,
    constants: dict[str, int],
    motor0: int,
) -> None:
    """The firmware's 32-bit wrap-around of the fields that left their range, in place.

    The reference wraps a field to 32 bits after each prediction. Every prediction but the
    average of the previous two (previous, straight line, increment, constants, motor[0]) is a
    sum, and a sum commutes with the reduction modulo 2**32, so a field the reference wraps in
    both intra and inter frames is wrapped once here, at the end, with the same result; averaged
    fields were wrapped at every step already when they needed it (:func:`_main_values`). Betaflight 3.x logs
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
        ppred = (list(pdef.predictor) + [fmt.PRED_ZERO] * len(names))[fi]
        if (
            fi == 0
            or ppred == fmt.PRED_AVERAGE_2  # in range when wrapped at every step: it was not
            or not _wrapped_by_reference(idef, fi, constants, motor0)
            or not _wrapped_by_reference(pdef, fi, constants, motor0)
        ):
            raise Unsupported("a value needs the 32-bit wrap")
        if signed[fi]:
            vals[:, c] = ((col + 0x80000000) & 0xFFFFFFFF) - 0x80000000
        else:
            vals[:, c] = col & 0xFFFFFFFF


def _main_values(layout: _Layout, fr: _Frames, vals: I64) -> None:
    """Every main frame's values into ``vals`` (rows in frame order, columns ``kept``)."""
    wrapped_intra = _residual_values(layout, fr, vals)
    _predict(layout, fr, vals, wrapped_intra)


def _residual_values(layout: _Layout, fr: _Frames, vals: I64) -> set[int]:
    """The frames' residuals into ``vals``, intra frames complete (their predictions are
    constants and motor[0]), inter frames with the constant part of theirs; the intra-frame
    fields that needed the 32-bit wrap."""
    buf, starts, ends, main_at = fr.buf, fr.starts, fr.ends, fr.main_at
    i_rows, p_rows, col, kept = fr.i_rows, fr.p_rows, layout.col, layout.kept
    idef, constants, motor0 = layout.idef, layout.constants, layout.motor0
    ires, iend = residuals(buf, starts[main_at[i_rows]], idef, col)
    pres, pend = residuals(buf, starts[main_at[p_rows]], layout.pdef, col)
    if not (
        np.array_equal(iend, ends[main_at[i_rows]]) and np.array_equal(pend, ends[main_at[p_rows]])
    ):
        raise Unsupported("frame lengths disagree")  # not expected: the regex is the layout
    for fi in kept:  # intra frames: constants and motor[0] (which precedes its users)
        c = constant_prediction(layout.ipred[fi], constants)
        ires[:, col[fi]] += ires[:, col[motor0]] if c is None else c
    for fi in kept:  # inter frames: the constant part of their predictions
        c = constant_prediction(layout.ppred[fi], constants)
        if c:
            pres[:, col[fi]] += c
    signed = (list(idef.signed) + [0] * len(idef.names))[: len(idef.names)]
    wrapped_intra: set[int] = set()
    for fi in kept:  # the 32-bit wrap of intra frames (see _wrap_32bit), but iteration and time
        if fi < 2:
            continue
        c = col[fi]
        lo, hi = (-(1 << 31), (1 << 31) - 1) if signed[fi] else (0, (1 << 32) - 1)
        if len(ires) and (int(ires[:, c].min()) < lo or int(ires[:, c].max()) > hi):
            if not _wrapped_by_reference(idef, fi, constants, motor0):
                raise Unsupported("a value needs the 32-bit wrap")
            off = 1 << 31 if signed[fi] else 0
            ires[:, c] = ((ires[:, c] + off) & 0xFFFFFFFF) - off
            wrapped_intra.add(fi)
    vals[i_rows] = ires
    vals[p_rows] = pres
    return wrapped_intra


def _predict(layout: _Layout, fr: _Frames, vals: I64, wrapped_intra: set[int]) -> None:
    """The inter frames' predictions, segment by segment (an intra frame and the inter frames
    after it), added to their residuals in ``vals``."""
    i_rows, main_at, col, kept, ppred = fr.i_rows, fr.main_at, layout.col, layout.kept, layout.ppred
    motor0, skip, i_interval = layout.motor0, layout.skip, layout.i_interval
    idef = layout.idef
    signed = (list(idef.signed) + [0] * len(idef.names))[: len(idef.names)]
    seg_len = np.diff(np.append(i_rows, len(main_at)))
    if int(seg_len.max()) > MAX_SEGMENT:
        raise Unsupported("long run of inter frames")

    def cols(pred: int) -> list[int]:
        return [col[fi] for fi in kept if ppred[fi] == pred]

    prev_c, line_c = cols(fmt.PRED_PREVIOUS), cols(fmt.PRED_STRAIGHT_LINE)
    avg_c, inc_c, mot_c = cols(fmt.PRED_AVERAGE_2), cols(fmt.PRED_INC), cols(fmt.PRED_MOTOR_0)
    # an average of the previous two does not commute with the 32-bit wrap as sums do: when an
    # intra frame needed the wrap (above), those fields are wrapped at every step as the reference
    # wraps them; otherwise they must stay in range (_wrap_32bit checks) and need no wrap
    avg_wrap = any(kept[c] in wrapped_intra for c in avg_c)
    avg_off = np.array([1 << 31 if signed[kept[c]] else 0 for c in avg_c], dtype=np.int64)

    def predict(cur: I64, prev: I64, prev2: I64, sums: bool = True) -> None:
        """Add their predictions to inter frames ``cur`` (residuals) in place (``sums``: the
        previous-frame and straight-line ones too)."""
        if prev_c and sums:
            cur[:, prev_c] += prev[:, prev_c]
        if line_c and sums:
            cur[:, line_c] += 2 * prev[:, line_c] - prev2[:, line_c]
        if avg_c:
            a = prev[:, avg_c] + prev2[:, avg_c]
            if avg_wrap:
                w = cur[:, avg_c] + ((a + (a < 0)) >> 1) + avg_off
                cur[:, avg_c] = (w & 0xFFFFFFFF) - avg_off
            else:
                cur[:, avg_c] += (a + (a < 0)) >> 1
        if inc_c:
            last_iter = prev[:, 0]
            cur[:, inc_c] += (last_iter + skip[last_iter % i_interval] + 1)[:, None]
        if mot_c:
            cur[:, mot_c] += cur[:, [col[motor0]]]

    def predict_grid(g: I64) -> None:
        """Every inter frame of segments laid out as ``g[segment, step, column]`` (step 0: the
        intra frame; after it, prev2 is prev). A previous-frame prediction is a running sum
        along the segment, a straight line a running sum of running sums (its step from the
        previous frame is a running sum): both at once; the others a step at a time."""
        if prev_c:
            g[:, :, prev_c] = np.cumsum(g[:, :, prev_c], axis=1)
        if line_c and g.shape[1] > 1:
            step_sizes = np.cumsum(g[:, 1:, line_c], axis=1)
            g[:, 1:, line_c] = np.cumsum(step_sizes, axis=1) + g[:, :1, line_c]
        if avg_c or inc_c or mot_c:
            for step in range(1, g.shape[1]):
                prev2 = g[:, step - 1 if step == 1 else step - 2]
                predict(g[:, step], g[:, step - 1], prev2, sums=False)

    longest = int(seg_len.max())
    width = vals.shape[1]
    if (seg_len[:-1] == longest).all():
        # every segment but the last of one length, as in real logs: the frames are already a
        # grid (segment, step) in place, each step a view
        full = (len(i_rows) - 1) * longest
        if full:
            predict_grid(vals[:full].reshape(len(i_rows) - 1, longest, width))
        predict_grid(vals[full:].reshape(1, len(vals) - full, width))
        return
    if len(i_rows) * longest <= 2 * len(vals) + 4096:
        # segments of nearly one length: laid out on a grid with padding rows, never read back
        at = np.repeat(np.arange(len(i_rows)) * longest - i_rows, seg_len) + np.arange(len(vals))
        grid = np.zeros((len(i_rows) * longest, width), dtype=np.int64)
        grid[at] = vals
        predict_grid(grid.reshape(len(i_rows), longest, width))
        vals[:] = grid[at]
        return
    for step in range(1, longest):
        rows = i_rows[seg_len > step] + step
        cur = vals[rows]
        prev = vals[rows - 1]
        predict(cur, prev, prev if step == 1 else vals[rows - 2])
        vals[rows] = cur
