"""Framing a clean blackbox log in C: every frame layout of a log is a regular language (a varint
is ``[\\x80-\\xff]{0,4}[\\x00-\\x7f]``; a tagged group is its lead byte's class followed by the
lengths that lead byte implies), so one compiled regular expression finds all frames with
``findall``; they must tile the data from the end of the headers (see :func:`framing`).

Part of the bulk decoder (:mod:`blackbox_fast`).
"""

from __future__ import annotations

import functools
import re
import sys

import numpy as np
import numpy.typing as npt

from thrustmap.flightlogs import blackbox_format as fmt
from thrustmap.flightlogs import blackbox_frames as bfr

#: a varint; the possessive {0,4}+ matches the same (a continuation byte can never end it) and
#: saves the regex engine its backtracking bookkeeping (~25 % of the framing time); Python 3.10's
#: re has no possessive quantifiers, and the plain one matches the same frames
#: (the bytes themselves, not escapes: the expressions are parsed ~15 % faster, on every run)
_VB = (
    b"[\x80-\xff]{0,4}+[\x00-\x7f]"
    if sys.version_info >= (3, 11)
    else b"[\x80-\xff]{0,4}[\x00-\x7f]"
)
#: bytes a class must escape: its own syntax, and what Python warns of as a possible nested set
_CLASS_SPECIAL = frozenset(b"[]\\^-&~|")


def _class_byte(value: int) -> bytes:
    return (b"\\" if value in _CLASS_SPECIAL else b"") + bytes([value])


class Unsupported(Exception):
    """The fast path does not cover this log: the reference decoder decodes it."""


def _byte_class(values: list[int]) -> bytes:
    out = []
    vs = sorted(values)
    k = 0
    while k < len(vs):
        j = k
        while j + 1 < len(vs) and vs[j + 1] == vs[j] + 1:
            j += 1
        first, last = _class_byte(vs[k]), _class_byte(vs[j])
        out.append(first if j == k else first + b"-" + last)
        k = j + 1
    return b"[" + b"".join(out) + b"]"


def _by_length(lengths: list[int], extra: int) -> bytes:
    """A lead byte followed by ``lengths[lead] - extra`` bytes of any value."""
    groups: dict[int, list[int]] = {}
    for lead, ln in enumerate(lengths):
        groups.setdefault(ln - extra, []).append(lead)
    alts = [_byte_class(leads) + (b".{%d}" % ln if ln else b"") for ln, leads in groups.items()]
    return b"(?:" + b"|".join(alts) + b")"


def units(fd: fmt.FrameDef) -> list[tuple[int, list[int]]]:
    """The frame's byte units in order, as (encoding, field indices), consuming bytes exactly as
    :func:`blackbox_frames.compile_frame` does (PRED_INC fields outside groups read nothing)."""
    n = len(fd.names)
    enc = list(fd.encoding) + [fmt.ENC_NULL] * (n - len(fd.encoding))
    pred = list(fd.predictor) + [fmt.PRED_ZERO] * (n - len(fd.predictor))
    units: list[tuple[int, list[int]]] = []
    i = 0
    while i < n:
        if pred[i] == fmt.PRED_INC:
            i += 1
            continue
        e = enc[i]
        if e == fmt.ENC_TAG8_8SVB:
            j = i + 1
            while j < min(i + 8, n) and enc[j] == fmt.ENC_TAG8_8SVB:
                j += 1
            group = list(range(i, j))
        elif e == fmt.ENC_TAG2_3S32:
            group = list(range(i, min(i + 3, n)))
        elif e == fmt.ENC_TAG8_4S16:
            group = list(range(i, min(i + 4, n)))
        elif e in (fmt.ENC_SIGNED_VB, fmt.ENC_UNSIGNED_VB, fmt.ENC_NEG_14BIT, fmt.ENC_NULL):
            group = [i]
        else:
            raise Unsupported(f"encoding {e}")
        units.append((e, group))
        i = group[-1] + 1
    return units


@functools.lru_cache(maxsize=64)
def _unit_regex(e: int, count: int) -> bytes:
    if e == fmt.ENC_TAG8_8SVB:
        if count == 1:
            return _VB
        mask = (1 << count) - 1
        alts = []
        for c in range(count + 1):
            heads = [h for h in range(256) if bfr.POPCOUNT[h & mask] == c]
            alts.append(_byte_class(heads) + (b"(?:" + _VB + b"){%d}" % c if c else b""))
        return b"(?:" + b"|".join(alts) + b")"
    if e == fmt.ENC_TAG2_3S32:
        return _by_length(bfr.TAG2_3S32_LEN, 1)
    if e == fmt.ENC_TAG8_4S16:
        return _by_length(bfr.TAG8_4S16_V2_LEN, 0)
    if e == fmt.ENC_NULL:
        return b""
    return _VB


_SCALAR_VARINTS = (fmt.ENC_SIGNED_VB, fmt.ENC_UNSIGNED_VB, fmt.ENC_NEG_14BIT)


def _varint_run(count: int) -> bytes:
    """``count`` varints in a row. When they are all one byte long (most residuals are small)
    the first alternative, one repeat of a byte class, matches them at once; otherwise the
    second one, a varint at a time. Both match exactly the same bytes (a run of varints has one
    parse), so the frames found are the same; ~20 % less framing time on real logs."""
    if count == 1:
        return _VB
    return b"(?:[\x00-\x7f]{%d}|%s)" % (count, _VB * count)


def frame_regex(fd: fmt.FrameDef) -> bytes:
    """One frame of layout ``fd`` (its marker byte excluded)."""
    parts: list[bytes] = []
    run = 0  # scalar varints in a row, not yet written
    for e, group in units(fd):
        if e in _SCALAR_VARINTS:
            run += 1
            continue
        if run:
            parts.append(_varint_run(run))
            run = 0
        parts.append(_unit_regex(e, len(group)))
    if run:
        parts.append(_varint_run(run))
    return b"".join(parts)


#: events as :func:`blackbox_frames.parse_event` reads them
_EVENT_REGEX = (
    b"E(?:\\x00" + _VB
    + b"|\\x0d(?:[\\x80-\\xff].{4}|[\\x00-\\x7f]" + _VB + b")"
    + b"|\\x0e" + _VB + _VB
    + b"|\\x0f" + _VB
    + b"|\\x1e" + _VB + _VB
    + b"|\\xff" + re.escape(fmt.END_OF_LOG_TEXT) + b")"
)  # fmt: skip


@functools.lru_cache(maxsize=8)
def frames_pattern(
    i_re: bytes, p_re: bytes, aux: tuple[tuple[bytes, bytes], ...]
) -> re.Pattern[bytes]:
    """Any one frame: main frames first (most frames), then events and ``aux`` (marker,
    layout regex): slow, GPS and GPS-home frames."""
    alts = [b"P" + p_re, b"I" + i_re, _EVENT_REGEX]
    alts += [re.escape(marker) + layout for marker, layout in aux]
    return re.compile(b"|".join(alts), re.DOTALL)


def framing(
    pattern: re.Pattern[bytes], section: bytes, pos: int
) -> tuple[list[bytes], npt.NDArray[np.int64], bool, bool]:
    """The frames from ``pos`` on, their lengths, whether they tile the whole log (to its end or
    its log-end event), and whether it ended with that event. When they do not, only the frames
    that tile the data up to the first byte no frame covers are returned, less the last of them
    (the reference checks a frame by what follows it, so it takes over one frame early)."""
    n = len(section)
    # erased flash (0xFF) after a log cut off by a power loss: no frame there to look for
    data_end = len(section.rstrip(b"\xff")) if section.endswith(b"\xff\xff") else n
    frames: list[bytes] = pattern.findall(section, pos, data_end)
    lengths = np.fromiter(map(len, frames), dtype=np.int64, count=len(frames))
    # the matches are disjoint and lie in [pos, data_end): when their lengths add up to all of
    # it, they tile it (the usual case, checked without joining them back together)
    gapless = pos + int(lengths.sum()) == data_end
    try:
        last = frames.index(b"E\xff" + fmt.END_OF_LOG_TEXT)
    except ValueError:
        last = -1
    ended = last >= 0
    if ended:
        frames, lengths = frames[: last + 1], lengths[: last + 1]
    if gapless and (ended or data_end == n):
        return frames, lengths, True, ended
    joined = b"".join(frames)
    if section.startswith(joined, pos) and (ended or pos + len(joined) == n):
        return frames, lengths, True, ended
    a = np.frombuffer(joined, dtype=np.uint8)
    b = np.frombuffer(section, dtype=np.uint8)[pos : pos + len(a)]
    differ = np.flatnonzero(a[: len(b)] != b)
    first_bad = int(differ[0]) if len(differ) else len(b)
    count = max(int(np.searchsorted(np.cumsum(lengths), first_bad, side="right")) - 1, 0)
    return frames[:count], lengths[:count], False, False
