"""Message-level replay: a recording keeps replaying after the driver that made it changes.

A transcript holds bytes; this module reads them as the messages of the protocol they carry
(MAVLink 2/1 or MSP, recognised from the recorded writes) and serves a driver the recorded
replies to the requests it actually sends, so a driver that asks in another order, asks for one
parameter more or one less, or re-sends a motor command at another cadence still replays.

The rules, all in message terms:

- A driver message is a *barrier* when it changes the vehicle's state (a motor command, a stop,
  arming, a parameter write; MSP commands 68, 99 and 200+), else a *query* (a parameter or
  message request, a telemetry poll, a stream-rate request, a heartbeat).
- Barriers keep their recorded order. A barrier matches the next recorded barrier, fields equal
  except the sequence number and the command's ``confirmation`` counter; a motor command's
  throttle may differ by 5 % of its range (a ramp sampled at another instant), never between a
  stop and a run. A barrier equal to the last one matched is a repeat (a keep-alive): it is
  answered with a copy of that one's recorded replies; recorded repeats the driver does not
  send are skipped. A stop is always safe to send and never diverges: it matches the same stop
  later in the recording (the driver stopped sooner, or after a divergence; what lies between is
  skipped), or when the recording runs a motor next, its next stop of the same command; a stop
  the recording lacks (another output, one more retry) is answered as the recording answered a
  stop of the same command (none: no answer, as from a lossy link). A recorded stop a driver
  that has run no motor does not send (a probe needs none) is skipped. Anything else is a
  divergence, reported as "expected <recorded message>,
  driver sent <message>" with the transcript line.
- A query matches the first recorded, not yet used, equal query before the next recorded motor
  run command, in any order; a query asked more often than recorded gets a copy of the latest
  recorded answer; a query the recording never saw gets no answer (as from a lossy link) and is
  counted. A query's replies are the recorded messages that answer it (MAVLink COMMAND_ACK by
  command id, PARAM_VALUE/PARAM_ERROR by parameter name, the message a REQUEST_MESSAGE names;
  MSP the reply with the same command), served with their recorded latency after the request.
- Everything else the device sent (streams, status text, stale replies) is served in recorded
  order, each message when the driver has sent every request recorded before it; with a clock
  also once the recording's time has passed it (a request the driver no longer makes does not
  hold the stream back), except past a motor run command the driver has not sent. The
  recording's timeline is re-anchored to the driver's at every barrier. After a divergence the
  stream goes on by the clock alone (so a driver that stops can still see the device idle).

Pure: no I/O and no clock of its own (times are passed in, relative to the port's opening).
How each protocol's bytes become messages is in ``transcript_messages``.
"""

from __future__ import annotations

import heapq
import logging
from bisect import bisect_left
from collections import Counter, deque
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field
from typing import Any

from thrustmap.protocols.transcript import TranscriptEvent
from thrustmap.protocols.urlhandlers.transcript_messages import Message, Protocol

__all__ = [
    "Divergence",
    "MessageReplay",
    "Unit",
]

log = logging.getLogger(__name__)

#: a read whose request was never sent is released this long after its recorded time, so a
#: driver writing at the very instant of the recording still writes first
_LATE_RELEASE_S = 1e-6
#: a driver within this of the recorded instant is "on time" (transcripts keep nanoseconds)
_ON_TIME_S = 1e-6
#: a recorded reply more than this after its request is not taken as its answer
_MAX_REPLY_LATENCY_S = 5.0


# ---------------------------------------------------------------------------------------------
# The recording as units (frames) and the replay machine
# ---------------------------------------------------------------------------------------------
@dataclass
class Unit:
    pos: int
    direction: str  # "w" or "r"
    data: bytes
    time_s: float
    line: int
    msg: Message | None
    replies: list[int] = field(default_factory=list)  # write: positions of its reply reads
    reply_to: int | None = None  # read: the write it answers
    resolved: bool = False  # write: matched or skipped; read: released
    used: bool = False  # write: matched by a driver message


def _units(events: Sequence[TranscriptEvent], proto: Protocol) -> list[Unit]:
    """Split each direction's stream into frames; a frame takes the time and line of the event
    that completed it (a read) or began it (a write)."""
    units: list[Unit] = []
    pending: dict[str, tuple[bytearray, float, int]] = {}
    for event in events:
        if event.direction is None:
            continue
        buf, t0, line0 = pending.get(event.direction, (bytearray(), event.time_s, event.line))
        if not buf:
            t0, line0 = event.time_s, event.line
        buf += event.data
        chunks, used = proto.split(bytes(buf))
        for chunk in chunks:
            t = t0 if event.direction == "w" else event.time_s
            line = line0 if event.direction == "w" else event.line
            units.append(Unit(len(units), event.direction, chunk, t, line, proto.decode(chunk)))
        del buf[:used]
        pending[event.direction] = (buf, event.time_s, event.line) if chunks else (buf, t0, line0)
    for direction, (buf, t0, line0) in pending.items():
        if buf:  # a frame the recording cut short: served (or matched) as bytes
            units.append(Unit(len(units), direction, bytes(buf), t0, line0, None))
    units.sort(key=lambda u: (u.time_s, u.pos))
    for index, unit in enumerate(units):
        unit.pos = index
    return units


def _assign_replies(units: list[Unit]) -> None:
    """Each reply read goes to the earliest earlier request that asked for it and has no such
    reply yet, else to the latest one that asked (a duplicate answer); else it is stream."""
    open_asks: dict[Hashable, deque[int]] = {}
    answered: set[tuple[int, Hashable]] = set()
    for unit in units:
        msg = unit.msg
        if msg is None:
            continue
        if unit.direction == "w":
            for key in msg.asks:
                open_asks.setdefault(key, deque()).append(unit.pos)
            continue
        for key in sorted(msg.answers, key=repr):  # a stable order whatever the hash seed
            pending = open_asks.get(key)
            if not pending:
                continue
            # requests too old to be answered now are dropped (linear time on long sweeps)
            while pending and unit.time_s - units[pending[0]].time_s > _MAX_REPLY_LATENCY_S:
                answered.discard((pending.popleft(), key))
            askers = list(pending)
            if not askers:
                continue
            fresh = [p for p in askers if (p, key) not in answered]
            owner = fresh[0] if fresh else askers[-1]
            answered.add((owner, key))
            unit.reply_to = owner
            units[owner].replies.append(unit.pos)
            break


def _stop_kind(unit: Unit) -> tuple[str, Any] | None:
    """(message, command) of a recorded stop; None for anything else."""
    msg = unit.msg
    if msg is None or msg.run or msg.throttle_field is None:
        return None
    return (msg.name, dict(msg.fields).get("command"))


def _is_run(unit: Unit) -> bool:
    """A recorded barrier that may make a motor turn (an undecodable write counts as one)."""
    return unit.msg is None or unit.msg.run


class Divergence(Exception):
    """The driver sent a message the recording cannot answer in its order."""

    def __init__(self, expected: Unit | None, actual: Message | None, actual_bytes: bytes) -> None:
        self.expected = expected
        self.actual = actual
        self.actual_bytes = actual_bytes
        want = expected.msg.text if expected is not None and expected.msg else None
        if expected is not None and want is None:
            want = f"bytes {expected.data[:16].hex()}"
        got = actual.text if actual is not None else f"bytes {actual_bytes[:16].hex()}"
        super().__init__(f"expected {want or 'end of recording'}, driver sent {got}")


class MessageReplay:
    """Serves a recording to a driver message by message (see the module docstring)."""

    def __init__(self, events: Sequence[TranscriptEvent], proto: Protocol) -> None:
        self.proto = proto
        self.units = _units(events, proto)
        _assign_replies(self.units)
        self._writes = [u.pos for u in self.units if u.direction == "w"]
        self._barriers = [
            u.pos for u in self.units if u.direction == "w" and (u.msg is None or u.msg.barrier)
        ]
        self._runs = [p for p in self._barriers if _is_run(self.units[p])]
        self._stream = [u.pos for u in self.units if u.direction == "r" and u.reply_to is None]
        self._queries: dict[Hashable, list[int]] = {}
        for pos in self._writes:
            msg = self.units[pos].msg
            if msg is not None and not msg.barrier:
                self._queries.setdefault(msg.exact_key(), []).append(pos)
        self._query_next: dict[Hashable, int] = {}
        self._w = 0  # index into _writes: first unresolved write (the frontier)
        self._b = 0  # index into _barriers: next unresolved barrier
        self._r = 0  # index into _runs: next unresolved run barrier
        self._s = 0  # index into _stream: next stream read not released
        self._last_barrier: Unit | None = None
        self._driver_ran = False  # the driver sent a motor run command (not only stops)
        self._offset_s = 0.0
        self._pending: list[tuple[float, int, int, bytes]] = []  # (time, pos, seq, bytes)
        self._seq = 0
        self._driver_buf = bytearray()
        self.written = 0  # driver bytes accepted
        self.served = 0  # bytes handed to the driver
        self.unanswered: Counter[str] = Counter()
        self.repeats = 0
        self.divergences = 0
        self._frontier_update()

    # -- positions ------------------------------------------------------------------------
    def _frontier(self) -> int:
        return self._writes[self._w] if self._w < len(self._writes) else len(self.units)

    def _frontier_update(self) -> None:
        while self._w < len(self._writes) and self.units[self._writes[self._w]].resolved:
            self._w += 1
        while self._b < len(self._barriers) and self.units[self._barriers[self._b]].resolved:
            self._b += 1
        while self._r < len(self._runs) and self.units[self._runs[self._r]].resolved:
            self._r += 1

    def _next_barrier(self) -> Unit | None:
        return self.units[self._barriers[self._b]] if self._b < len(self._barriers) else None

    def _run_limit(self) -> int:
        if self.divergences:  # off the recording's path: its stream goes on by the clock
            return len(self.units)
        return self._runs[self._r] if self._r < len(self._runs) else len(self.units)

    # -- serving --------------------------------------------------------------------------
    def _schedule(self, time_s: float, unit: Unit) -> None:
        heapq.heappush(self._pending, (time_s, unit.pos, self._seq, unit.data))
        self._seq += 1

    def _serve_replies(self, request: Unit, now_s: float | None, *, copy: bool) -> None:
        anchored = now_s is None or abs(now_s - (request.time_s + self._offset_s)) < _ON_TIME_S
        for pos in request.replies:
            reply = self.units[pos]
            if not copy and reply.resolved:
                continue
            if anchored or now_s is None:
                when = reply.time_s + self._offset_s
            else:
                when = now_s + (reply.time_s - request.time_s)
            reply.resolved = True
            self._schedule(when, reply)

    def _release_stream(self, now_s: float | None, eps: float = 0.0) -> None:
        frontier = self._frontier()
        run_limit = self._run_limit()
        while self._s < len(self._stream):
            unit = self.units[self._stream[self._s]]
            when = unit.time_s + self._offset_s
            late_ok = (
                now_s is not None and unit.pos < run_limit and when + _LATE_RELEASE_S <= now_s + eps
            )
            if unit.pos >= frontier and not late_ok:
                break
            unit.resolved = True
            self._schedule(when if unit.pos < frontier else when + _LATE_RELEASE_S, unit)
            self._s += 1

    def next_stream_time(self) -> float | None:
        """When the next held-back stream message becomes due by the clock (None: never)."""
        if self._s >= len(self._stream):
            return None
        unit = self.units[self._stream[self._s]]
        if unit.pos >= self._run_limit():
            return None
        return unit.time_s + self._offset_s + _LATE_RELEASE_S

    def take_due(self, now_s: float | None, eps: float) -> bytes:
        """Bytes due by ``now_s`` (all released bytes without a clock), in time order."""
        self._release_stream(now_s, eps)
        out = bytearray()
        while self._pending and (now_s is None or self._pending[0][0] <= now_s + eps):
            out += heapq.heappop(self._pending)[3]
        return bytes(out)

    def next_due(self) -> float | None:
        candidates = [t for t in (self._pending[0][0] if self._pending else None,) if t is not None]
        stream = self.next_stream_time()
        if stream is not None:
            candidates.append(stream)
        return min(candidates) if candidates else None

    # -- the driver's side ----------------------------------------------------------------
    def write(self, data: bytes, now_s: float | None, *, strict: bool) -> list[Divergence]:
        """Take driver bytes; returns the divergences (raised by the caller in strict mode)."""
        self._driver_buf += data
        chunks, used = self.proto.split(bytes(self._driver_buf))
        del self._driver_buf[:used]
        problems: list[Divergence] = []
        for chunk in chunks:
            try:
                self._on_message(chunk, self.proto.decode(chunk), now_s)
                self.written += len(chunk)
            except Divergence as exc:
                self.divergences += 1
                problems.append(exc)
                if strict:
                    break
        return problems

    def _on_message(self, chunk: bytes, msg: Message | None, now_s: float | None) -> None:
        log.debug("replay: t=%s driver sent %s", now_s, msg.text if msg else chunk.hex())
        if msg is None:
            raise Divergence(self._next_barrier(), None, chunk)
        if msg.barrier:
            self._on_barrier(chunk, msg, now_s)
        else:
            self._on_query(msg, now_s)

    def _on_barrier(self, chunk: bytes, msg: Message, now_s: float | None) -> None:
        last = self._last_barrier
        while True:
            nxt = self._next_barrier()
            if nxt is not None and nxt.msg is not None and nxt.msg.same_as(msg):
                self._match_barrier(nxt, now_s)
                return
            if last is not None and last.msg is not None and last.msg.same_as(msg):
                self.repeats += 1
                self._serve_replies(last, now_s, copy=True)
                return
            if (
                nxt is not None
                and last is not None
                and nxt.msg is not None
                and last.msg is not None
                and last.msg.same_as(nxt.msg)
            ):
                nxt.resolved = True  # a recorded repeat the driver did not send
                self._frontier_update()
                continue
            if not msg.run and msg.throttle_field is not None:
                self._on_stop(msg, nxt, now_s)
                return
            if nxt is not None and not self._driver_ran and _stop_kind(nxt) is not None:
                # a driver that never ran a motor needs no stop (a probe): the recorded one is
                # skipped, and the driver's message matched against what follows it
                nxt.resolved = True
                self._frontier_update()
                continue
            raise Divergence(nxt, msg, chunk)

    def _on_stop(self, msg: Message, nxt: Unit | None, now_s: float | None) -> None:
        """A stop is always safe to send, so it never diverges: it matches the same stop later in
        the recording (the driver stopped sooner, or after a divergence), or, when the recording
        runs a motor next, its next stop of the same command; else it is answered as the
        recording answered a stop of the same command (another output, one more retry)."""
        kind = (msg.name, dict(msg.fields).get("command"))
        ahead = [self.units[p] for p in self._barriers[self._b :]]
        exact = next((u for u in ahead if u.msg is not None and u.msg.same_as(msg)), None)
        if exact is None and nxt is not None and _is_run(nxt):
            exact = next((u for u in ahead if _stop_kind(u) == kind), None)
        if exact is not None:
            for unit in ahead:
                if unit is exact:
                    break
                unit.resolved = True  # recorded, not sent: the driver stopped before it
            self._match_barrier(exact, now_s)
            return
        like = self._recorded_stop(msg)
        if like is None:
            self.unanswered[msg.text] += 1
        else:
            self.repeats += 1
            self._serve_replies(like, now_s, copy=True)

    def _recorded_stop(self, msg: Message) -> Unit | None:
        """The recorded stop of the same command nearest before the next barrier."""
        kind = (msg.name, dict(msg.fields).get("command"))
        limit = self._barriers[self._b] if self._b < len(self._barriers) else len(self.units)
        best: Unit | None = None
        for pos in self._barriers:
            unit = self.units[pos]
            other = unit.msg
            if other is None or other.run or other.throttle_field is None or not unit.replies:
                continue
            if (other.name, dict(other.fields).get("command")) != kind:
                continue
            if best is None or pos < limit:
                best = unit
            if pos >= limit:
                break
        return best

    def _match_barrier(self, unit: Unit, now_s: float | None) -> None:
        self._driver_ran = self._driver_ran or _is_run(unit)
        for pos in self._writes[self._w :]:
            if pos >= unit.pos:
                break
            self.units[pos].resolved = True  # recorded before it and not sent: skipped
        if now_s is not None:
            shift = now_s - unit.time_s
            self._offset_s = 0.0 if abs(shift) < _ON_TIME_S else shift
        unit.resolved = unit.used = True
        self._last_barrier = unit
        self._frontier_update()
        self._serve_replies(unit, now_s, copy=False)

    def _on_query(self, msg: Message, now_s: float | None) -> None:
        key = msg.exact_key()
        positions = self._queries.get(key, [])
        limit = self._run_limit()
        index = self._query_next.get(key, 0)
        while index < len(positions) and self.units[positions[index]].resolved:
            index += 1
        self._query_next[key] = index
        if index < len(positions) and positions[index] < limit:
            unit = self.units[positions[index]]
            unit.resolved = unit.used = True
            self._frontier_update()
            self._serve_replies(unit, now_s, copy=False)
            return
        before = bisect_left(positions, limit) - 1
        if before >= 0:
            self.repeats += 1
            self._serve_replies(self.units[positions[before]], now_s, copy=True)
            return
        if msg.asks:
            self.unanswered[msg.text] += 1

    # -- the account ----------------------------------------------------------------------
    def unused_writes(self) -> list[Unit]:
        return [self.units[p] for p in self._writes if not self.units[p].used]

    def remaining_write_bytes(self) -> int:
        return sum(len(u.data) for u in self.unused_writes())

    def remaining_read_bytes(self) -> int:
        unserved = sum(len(u.data) for u in self.units if u.direction == "r" and not u.resolved)
        return unserved + sum(len(item[3]) for item in self._pending)

    def next_expected(self) -> Unit | None:
        return self._next_barrier()

    def describe_unused(self, limit: int = 3) -> str:
        names = Counter(u.msg.text if u.msg else "bytes" for u in self.unused_writes())
        return _summary(names, limit)

    def describe_unanswered(self, limit: int = 3) -> str:
        return _summary(self.unanswered, limit)


def _summary(names: Counter[str], limit: int) -> str:
    items = [f"{n} x{c}" if c > 1 else n for n, c in names.most_common(limit)]
    more = len(names) - limit
    return ", ".join(items) + (f" and {more} more" if more > 0 else "")
