"""The vectorised ULog reader's message walk: message types are checked all at once after the
sizes are walked, with the same outcome as checking each message as it is reached (an unknown
type anywhere, even in a truncated last message: None, so that pyulog decides)."""

from __future__ import annotations

from pathlib import Path

from thrustmap.flightlogs import ulog_fast
from thrustmap.flightlogs.ulog import TOPICS

ULOG = Path(__file__).resolve().parent.parent / "fixtures" / "flightlogs" / "sim_hover.ulg"


def _message_starts(raw: bytes) -> list[int]:
    starts, pos = [], 16
    while pos + 3 <= len(raw):
        starts.append(pos)
        pos += 3 + (raw[pos] | (raw[pos + 1] << 8))
    return starts


def test_a_clean_log_parses_with_every_message() -> None:
    raw = ULOG.read_bytes()
    got = ulog_fast.parse(raw, TOPICS)
    assert got is not None and got.problem is None
    assert {d.name for d in got.data_list} <= set(TOPICS) and got.data_list


def test_an_unknown_message_type_anywhere_gives_none() -> None:
    raw = bytearray(ULOG.read_bytes())
    starts = _message_starts(bytes(raw))
    for k in (len(starts) // 3, len(starts) - 1):
        bad = bytearray(raw)
        bad[starts[k] + 2] = ord("z")
        assert ulog_fast.parse(bytes(bad), TOPICS) is None


def test_a_truncated_last_message_is_a_problem_unless_its_type_is_unknown() -> None:
    raw = ULOG.read_bytes()
    last = _message_starts(raw)[-1]
    cut = raw[: last + 4]  # the last message's header and one byte of its payload
    got = ulog_fast.parse(cut, TOPICS)
    assert got is not None and got.problem is not None and "truncated" in got.problem
    bad = bytearray(cut)
    bad[last + 2] = ord("z")
    assert ulog_fast.parse(bytes(bad), TOPICS) is None
