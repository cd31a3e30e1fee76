"""Transcript format: writer/reader round trip, flushing, and errors that name file:line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from thrustmap.core.errors import DataFormatError
from thrustmap.protocols.transcript import (
    FORMAT_NAME,
    TranscriptFormatError,
    TranscriptWriter,
    read_transcript,
)


def _write(path: Path, lines: list[str], *, newline_at_end: bool = True) -> Path:
    path.write_text("\n".join(lines) + ("\n" if newline_at_end else ""), encoding="utf-8")
    return path


HEADER = json.dumps({"format": FORMAT_NAME, "version": 1, "inner": "loop://", "created_utc": "x"})


def test_round_trip_with_relative_times_notes_and_extra_header(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    with TranscriptWriter(path, inner="sim://px4", origin_s=100.0, extra={"baudrate": 57600}) as w:
        w.event("w", b"\x24\x4d\x3c", 100.25)
        w.event("r", b"", 100.3)  # empty reads are not recorded
        w.note("step 1", 100.5)
        w.event("r", b"\x00\xff", 101.0)
    t = read_transcript(path)
    assert t.header.inner == "sim://px4"
    assert t.header.extra["baudrate"] == 57600
    assert [(e.time_s, e.direction, e.data, e.note) for e in t.events] == [
        (0.25, "w", b"\x24\x4d\x3c", None),
        (0.5, None, b"", "step 1"),
        (1.0, "r", b"\x00\xff", None),
    ]
    assert [e.line for e in t.events] == [2, 3, 4]
    assert t.written() == b"$M<" and t.read() == b"\x00\xff"
    assert t.notes() == [(0.5, "step 1")]


def test_writer_flushes_every_line_before_close(tmp_path: Path) -> None:
    path = tmp_path / "live.jsonl"
    w = TranscriptWriter(path, inner="loop://", origin_s=0.0)
    w.event("w", b"abc", 0.1)
    lines = path.read_text(encoding="utf-8").splitlines()  # read while still open
    assert json.loads(lines[1]) == {"t": 0.1, "dir": "w", "hex": "616263"}
    w.close()


def test_writer_never_writes_time_backwards(tmp_path: Path) -> None:
    path = tmp_path / "mono.jsonl"
    with TranscriptWriter(path, inner="loop://", origin_s=10.0) as w:
        w.event("w", b"a", 12.0)
        w.event("r", b"b", 11.0)  # a misbehaving clock
    times = [e.time_s for e in read_transcript(path).events]
    assert times == [2.0, 2.0]


@pytest.mark.parametrize(
    ("lines", "line", "needle"),
    [
        (["not json"], 1, "JSON header"),
        ([json.dumps({"format": "other", "version": 1})], 1, "format"),
        ([json.dumps({"format": FORMAT_NAME, "version": 2})], 1, "version 2 is not supported"),
        ([HEADER, '{"t": 0.1, "dir": "w", "hex": "61'], 2, "invalid JSON"),
        ([HEADER, '{"t": 0.1, "dir": "x", "hex": "61"}'], 2, '"dir"'),
        ([HEADER, '{"t": 0.1, "dir": "w", "hex": "6"}'], 2, "hex"),
        ([HEADER, '{"t": 0.1, "dir": "w", "hex": ""}'], 2, "empty"),
        ([HEADER, '{"dir": "w", "hex": "61"}'], 2, '"t"'),
        (
            [HEADER, '{"t": 0.5, "dir": "w", "hex": "61"}', '{"t": 0.4, "dir": "r", "hex": "61"}'],
            3,
            "backwards",
        ),
    ],
)
def test_corrupt_transcripts_name_file_and_line(
    tmp_path: Path, lines: list[str], line: int, needle: str
) -> None:
    path = _write(tmp_path / "bad.jsonl", lines)
    with pytest.raises(TranscriptFormatError) as info:
        read_transcript(path)
    assert isinstance(info.value, DataFormatError)
    assert info.value.file == str(path) and info.value.line == line
    assert f"{path}:{line}: " in str(info.value)
    assert needle in str(info.value)


def test_empty_and_missing_files(tmp_path: Path) -> None:
    empty = _write(tmp_path / "empty.jsonl", [], newline_at_end=False)
    with pytest.raises(TranscriptFormatError, match="empty transcript"):
        read_transcript(empty)
    with pytest.raises(TranscriptFormatError, match="not found"):
        read_transcript(tmp_path / "nope.jsonl")


def test_truncated_tail_raises_by_default_and_can_be_dropped(tmp_path: Path) -> None:
    lines = [HEADER, '{"t": 0.1, "dir": "w", "hex": "61"}', '{"t": 0.2, "dir": "r", "he']
    path = _write(tmp_path / "cut.jsonl", lines, newline_at_end=False)
    with pytest.raises(TranscriptFormatError) as info:
        read_transcript(path)
    assert info.value.line == 3
    t = read_transcript(path, drop_truncated_tail=True)
    assert [e.data for e in t.events] == [b"a"]
    # A bad line in the middle is never dropped.
    mid = _write(tmp_path / "mid.jsonl", [HEADER, "{bad", '{"t": 0.2, "dir": "r", "hex": "61"}'])
    with pytest.raises(TranscriptFormatError):
        read_transcript(mid, drop_truncated_tail=True)
