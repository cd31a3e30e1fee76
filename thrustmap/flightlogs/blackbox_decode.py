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

import logging
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thrustmap.flightlogs import blackbox_fast
from thrustmap.flightlogs.blackbox_format import (
    EVENT_LOG_END,
    EVENT_LOGGING_RESUME,
    FRAME_MARKERS,
    HANDBACK_FRAMING,
    HANDBACK_GAP,
    MAX_FRAME_BYTES,
    MAX_INTERVAL,
    MAX_ITERATION_JUMP,
    MAX_TIME_JUMP_US,
    MIN_HANDBACK_BYTES,
    WORK_PER_BYTE,
    BlackboxEvent,
    CorruptFrame,
    DecodedLog,
    FrameDef,
    FrameParser,
    ResumeState,
    corruption_summary,
    frame_stats,
    header_int,
    in_32bit_range,
    kept_fields,
    p_interval,
    p_skip_counts,
    parse_headers,
    rows_to_table,
    split_logs,
)
from thrustmap.flightlogs.blackbox_frames import compile_frame, parse_event

log = logging.getLogger(__name__)


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

    got = blackbox_fast.decode_log_bulk(section, index, offset, keep_field=keep_field)
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
            # with the 32-bit wrap, as the bulk passes around it do (blackbox_fast._wrap_32bit):
            # without it a stretch of Betaflight 3.x motors below their low end left the whole
            # log to the reference, a 4 MB log at 2 MB/s
            ref = _decode_log(
                section, index, offset, wrap=True, keep_field=keep_field, resume=state,
                handback_after=after,
            )  # fmt: skip
        except OverflowError:
            break
        if isinstance(ref, DecodedLog):
            if _in_32bit_range(ref):
                return ref
            break
        framing_left -= n - ref.pos
        got = blackbox_fast.decode_log_bulk(
            section, index, offset, keep_field=keep_field, start=ref
        )
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


@dataclass(frozen=True)
class _RefLayout:
    """A log's frame layouts as the per-frame decoder uses them: a compiled parser per marker,
    the skipped-frame counts of the P interval, and each frame's work."""

    headers: dict[str, str]
    defs: dict[str, FrameDef]
    names: list[str]  # the main-frame fields
    keep: frozenset[int] | None
    parsers: dict[int, FrameParser]
    i_interval: int
    skip_table: tuple[int, ...]
    home_idx: list[int]
    widths: dict[int, int]  # marker -> fields (the work budget)
    zeros: list[int]  # a main frame of zeros (the history before the first one)

    @property
    def columns(self) -> int:
        return len(self.names) if self.keep is None else len(self.keep)

    def parse(
        self,
        d: bytes,
        pos: int,
        prev: list[int] | None,
        prev2: list[int],
        last_iter: int,
        last_time: int,
        home: list[int],
    ) -> tuple[list[int], int, tuple[int, tuple[float, ...]] | None]:
        """The frame at ``pos`` (any marker): its values, where it ends, and its event (for an
        ``E`` frame). Raises ``IndexError`` at the end of the data, ``CorruptFrame``."""
        m = d[pos]
        zeros = self.zeros
        if m == MARK_P:
            if prev is None:
                vals, p = self.parsers[m](d, pos + 1, zeros, zeros, 0, 0, home)
            else:
                skipped = self.skip_table[last_iter % self.i_interval]
                vals, p = self.parsers[m](d, pos + 1, prev, prev2, skipped, last_time, home)
        elif m == MARK_I:
            vals, p = self.parsers[m](d, pos + 1, prev or zeros, zeros, 0, last_time, home)
        elif m == MARK_E:
            kind, payload, p = parse_event(d, pos + 1)
            return [], p, (kind, payload)
        else:
            fd = self.defs[chr(m)]
            vals, p = self.parsers[m](d, pos + 1, [0] * len(fd.names), [], 0, last_time, home)
        return vals, p, None


MARK_I, MARK_P, MARK_E, MARK_S, MARK_G, MARK_H = (ord(c) for c in "IPESGH")


def _reference_layout(
    section: bytes, wrap: bool, keep_field: Callable[[str], bool] | None
) -> tuple[_RefLayout, int]:
    """The layout from the headers, and where the frames begin."""
    headers, defs, pos = parse_headers(section)
    idef = defs.get("I")
    if idef is None or not idef.names:
        raise CorruptFrame("the header defines no main-frame fields ('H Field I name')")
    pdef = defs.get("P", FrameDef())
    pdef = FrameDef(idef.names, idef.signed, pdef.predictor, pdef.encoding)
    names = idef.names
    motor0 = names.index("motor[0]") if "motor[0]" in names else -1
    minthrottle = header_int(headers, "minthrottle", 1150)
    constants = {
        "minthrottle": minthrottle,
        "vbatref": header_int(headers, "vbatref", 4095),
        "motor_low": header_int(headers, "motorOutput", minthrottle, 0),
    }
    version = header_int(headers, "Data version", 2)
    keep = kept_fields(names, idef, pdef, motor0, keep_field)
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
    p_num, p_den = p_interval(headers)
    widths = {ord(k): max(len(fd.names), 1) for k, fd in defs.items()}
    widths[MARK_I] = widths[MARK_P] = max(len(names), 1)
    layout = _RefLayout(
        headers=headers, defs=defs, names=list(names), keep=keep, parsers=parsers,
        i_interval=i_interval, skip_table=p_skip_counts(i_interval, p_num, p_den),
        home_idx=[
            defs["H"].names.index(k) if "H" in defs and k in defs["H"].names else -1
            for k in ("GPS_home[0]", "GPS_home[1]")
        ],
        widths=widths, zeros=[0] * len(names),
    )  # fmt: skip
    return layout, pos


@dataclass
class _RefState:
    """What the per-frame decoder collects besides the main frames (and carries over from a
    ``ResumeState``)."""

    slow_rows: list[list[int]] = field(default_factory=list)
    slow_index: list[int] = field(default_factory=list)
    gps_rows: list[list[int]] = field(default_factory=list)
    events: list[BlackboxEvent] = field(default_factory=list)
    stats: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    home: list[int] = field(default_factory=lambda: [0, 0])
    main_offset: int = 0  # main frames decoded before ``resume.pos`` (not in main_rows)
    ended: bool = False

    @classmethod
    def after(cls, resume: ResumeState | None) -> _RefState:
        stats = frame_stats(resume)
        if resume is None:
            return cls(stats=stats)
        return cls(
            list(resume.slow_rows), list(resume.slow_index), list(resume.gps_rows),
            list(resume.events), stats, list(resume.warnings), list(resume.home),
            len(resume.main),
        )  # fmt: skip

    def event(self, event: tuple[int, tuple[float, ...]], main_rows: int) -> bool:
        """An event frame; True when it ends the log."""
        self.stats["E"] += 1
        kind, payload = event
        self.events.append(BlackboxEvent(self.main_offset + main_rows, kind, payload))
        self.ended = kind == EVENT_LOG_END
        return self.ended

    def aux_frame(self, m: int, vals: list[int], main_rows: int, home_idx: list[int]) -> None:
        """A slow, GPS or GPS-home frame."""
        if m == MARK_S:
            self.stats["S"] += 1
            self.slow_rows.append(vals)
            self.slow_index.append(self.main_offset + main_rows)
        elif m == MARK_G:
            self.stats["G"] += 1
            self.gps_rows.append(vals)
        elif m == MARK_H:
            self.stats["H"] += 1
            self.home = [vals[k] if k >= 0 else 0 for k in home_idx]

    def main_table(self, rows: list[list[int]], lay: _RefLayout, resume: ResumeState | None) -> Any:
        main = rows_to_table(rows, lay.columns)
        if resume is not None and self.main_offset:
            main = np.concatenate((resume.main, main)) if len(main) else resume.main
        return main


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
    lay, pos = _reference_layout(section, wrap, keep_field)
    st = _RefState.after(resume)
    d, n = section, len(section)
    markers = frozenset(FRAME_MARKERS)
    main_rows: list[list[int]] = []
    pos, prev, prev2, last_iter, last_time, budget = _start(lay, pos, n, resume)
    rollover, tail_start, out_of_budget, garbage_run = 0, -1, -1, False
    handback_at = handback_after if handback_after is not None else n + 1
    skip_run = _garbage_pattern(lay, markers)
    parse_p, skip_table, i_interval = lay.parsers.get(MARK_P), lay.skip_table, lay.i_interval
    width_main = lay.widths[MARK_P]
    append = main_rows.append
    while pos < n:
        m = d[pos]
        if m == MARK_P and prev is not None and parse_p is not None and budget > width_main:
            # the common case, an inter frame after a good frame: the general path below, with
            # every check, in one place; anything unusual falls through to it (and is re-read)
            try:
                vals, p = parse_p(
                    d, pos + 1, prev, prev2, skip_table[last_iter % i_interval], last_time, st.home
                )
            except (IndexError, CorruptFrame):
                p = -1
            if p > pos and p - pos - 1 <= MAX_FRAME_BYTES and (p >= n or d[p] in markers):
                t = (vals[1] & 0xFFFFFFFF) + rollover
                roll = _rollover(t, last_time)
                t += roll
                it = vals[0]
                if (
                    last_iter <= it < last_iter + MAX_ITERATION_JUMP
                    and last_time <= t < last_time + MAX_TIME_JUMP_US
                ):
                    budget -= width_main
                    rollover += roll
                    vals[1] = t
                    st.stats["P"] += 1
                    append(vals)
                    prev2 = prev
                    prev = vals
                    last_iter, last_time = it, t
                    garbage_run = False
                    pos = p
                    continue
        if m == MARK_I and pos >= handback_at and not (garbage_run or rollover):
            work_done = WORK_PER_BYTE * n + 100_000 - budget
            history = (prev, prev2, last_iter, last_time, work_done)
            return _handback(st, lay, resume, pos, main_rows, history)
        if m not in markers or m not in lay.parsers and m != MARK_E:
            # a run of bytes no frame starts with (erased flash after a cut-off log: megabytes
            # of 0xFF) is skipped at once, as byte by byte
            run = found.end() - pos if (found := skip_run(d, pos)) is not None else 1
            st.stats["skipped_bytes"] += run
            if not garbage_run and (main_rows or st.main_offset):
                prev = None
            garbage_run = True
            pos += run
            continue
        start = pos
        budget -= lay.widths.get(m, 1)
        if budget < 0:
            out_of_budget = start
            break
        try:
            vals, p, event = lay.parse(d, pos, prev, prev2, last_iter, last_time, st.home)
        except IndexError:
            tail_start = start
            break
        except CorruptFrame:
            p, event = -1, None
        bad = p < 0 or p - start - 1 > MAX_FRAME_BYTES or (p < n and d[p] not in markers)
        if bad and (event is None or event[0] != EVENT_LOG_END):
            st.stats["corrupt"] += 1
            prev = None
            pos = start + 1
            garbage_run = True
            continue
        garbage_run = False
        pos = p
        if m in (MARK_I, MARK_P):
            t = (vals[1] & 0xFFFFFFFF) + rollover
            roll = _rollover(t, last_time)
            rollover += roll
            t += roll
            vals[1] = t
            it = vals[0]
            if m == MARK_P and prev is None:
                st.stats["dropped_p"] += 1
                continue
            if not _plausible(m, it, t, last_iter, last_time, index, st.warnings):
                st.stats["invalid_main"] += 1
                prev = None
                continue
            st.stats["P" if m == MARK_P else "I"] += 1
            main_rows.append(vals)
            prev2 = vals if m == MARK_I else (prev or vals)
            prev = vals
            last_iter, last_time = it, t
        elif event is not None:
            if st.event(event, len(main_rows)):  # the end of the log
                break
            if event[0] == EVENT_LOGGING_RESUME:
                last_iter, last_time = int(event[1][0]), int(event[1][1]) + rollover
        else:
            st.aux_frame(m, vals, len(main_rows), lay.home_idx)
    return _finish(st, lay, resume, main_rows, (index, offset, n, tail_start, out_of_budget))


def _start(
    lay: _RefLayout, pos: int, n: int, resume: ResumeState | None
) -> tuple[int, list[int] | None, list[int], int, int, int]:
    """Where decoding starts: position, the last two main frames, the last iteration and time,
    and the work budget left (all from ``resume`` when given)."""
    budget = WORK_PER_BYTE * n + 100_000
    if resume is None:
        return pos, None, lay.zeros, -1, -1, budget
    prev2 = lay.zeros if resume.prev2 is None else resume.prev2
    return (resume.pos, resume.prev, prev2, resume.last_iter, resume.last_time,
            budget - resume.work_done)  # fmt: skip


def _rollover(t: int, last_time: int) -> int:
    """``1 << 32`` when a time below the last one is the 32-bit timer wrapping, else 0."""
    if last_time >= 0 and t < last_time and ((t - last_time) & 0xFFFFFFFF) < MAX_TIME_JUMP_US:
        return 1 << 32
    return 0


def _garbage_pattern(lay: _RefLayout, markers: frozenset[int]) -> Callable[..., Any]:
    """Matches a run of bytes no frame starts with (skipped at once)."""
    starts_frame = bytes(sorted({*lay.parsers, MARK_E} & set(markers)))
    return re.compile(b"[^" + re.escape(starts_frame) + b"]+").match


def _plausible(
    m: int, it: int, t: int, last_iter: int, last_time: int, index: int, warnings: list[str]
) -> bool:
    """A main frame's iteration and time against the last good frame's (the reference's
    checks); an intra frame after a long gap is kept, with a warning."""
    if m == MARK_P:
        return last_iter <= it < last_iter + MAX_ITERATION_JUMP and (
            last_time <= t < last_time + MAX_TIME_JUMP_US
        )
    ok = last_iter < 0 or (it >= last_iter and t >= last_time)
    if ok and last_iter >= 0 and t - last_time >= MAX_TIME_JUMP_US:
        warnings.append(
            f"log {index + 1}: {1e-6 * (t - last_time):.1f} s gap in the data "
            f"after t = {1e-6 * last_time:.3f} s"
        )
    return ok


def _handback(
    st: _RefState,
    lay: _RefLayout,
    resume: ResumeState | None,
    pos: int,
    main_rows: list[list[int]],
    history: tuple[list[int] | None, list[int], int, int, int],
) -> ResumeState:
    """The state at ``pos`` for the bulk decoder to carry on from."""
    prev, prev2, last_iter, last_time, work_done = history
    main_now = rows_to_table(main_rows, lay.columns)
    if resume is not None and st.main_offset:
        main_now = np.concatenate((resume.main, main_now))
    return ResumeState(
        pos=pos, main=main_now, prev=prev, prev2=prev2, last_iter=last_iter,
        last_time=last_time, home=list(st.home), work_done=work_done, slow_rows=st.slow_rows,
        slow_index=st.slow_index, gps_rows=st.gps_rows, events=st.events, stats=dict(st.stats),
        warnings=list(st.warnings),
    )  # fmt: skip


def _finish(
    st: _RefState,
    lay: _RefLayout,
    resume: ResumeState | None,
    main_rows: list[list[int]],
    where: tuple[int, int, int, int, int],
) -> DecodedLog:
    """The decoded log, with what was skipped said once."""
    index, offset, n, tail_start, out_of_budget = where
    warnings = st.warnings
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
    if (summary := corruption_summary(index, st.stats)) is not None:
        warnings.append(summary)
    sdef = lay.defs.get("S", FrameDef())
    gdef = lay.defs.get("G", FrameDef())
    return DecodedLog(
        index=index,
        headers=lay.headers,
        main_fields=[name for k, name in enumerate(lay.names) if lay.keep is None or k in lay.keep],
        main=st.main_table(main_rows, lay, resume),
        slow_fields=list(sdef.names),
        slow=rows_to_table(st.slow_rows, len(sdef.names)),
        slow_frame_index=np.array(st.slow_index, dtype=np.int64),
        gps_fields=list(gdef.names),
        gps=rows_to_table(st.gps_rows, len(gdef.names)),
        events=st.events,
        stats=st.stats,
        warnings=warnings,
        ended_cleanly=st.ended,
        byte_range=(offset, offset + n),
    )


def decode_file(data: bytes) -> list[DecodedLog]:
    """Every log in a blackbox file, in order (a log that cannot be decoded raises)."""
    return [decode_log(data[a:b], index=i, offset=a) for i, (a, b) in enumerate(split_logs(data))]
