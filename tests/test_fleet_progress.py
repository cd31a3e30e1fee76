"""`fleet extract` progress (issue 35): one redrawn bar line on a terminal, cleared before any
other line; plain lines elsewhere; never both on one line; within the terminal's width."""

from __future__ import annotations

import io
import logging
import shutil
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
from support.fleet_gen import Fleet, make_fleet
from test_fleet_dask import args

from thrustmap.cli import main
from thrustmap.cli.fleet import _Bar

pytest.importorskip("pyarrow")


class FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True

    def fileno(self) -> int:
        raise io.UnsupportedOperation("no file descriptor")


def screen(raw: str) -> list[str]:
    """The lines a terminal shows: ``\\r`` returns to the line's start, ``ESC[K`` clears the
    rest of it, ``\\n`` ends it."""
    lines: list[str] = []
    line: list[str] = []
    col = 0
    i = 0
    while i < len(raw):
        if raw.startswith("\x1b[K", i):
            del line[col:]
            i += 3
            continue
        ch = raw[i]
        if ch == "\r":
            col = 0
        elif ch == "\n":
            lines.append("".join(line))
            line, col = [], 0
        else:
            if col < len(line):
                line[col] = ch
            else:
                line.append(ch)
            col += 1
        i += 1
    if line:
        lines.append("".join(line))
    return lines


def is_bar(line: str) -> bool:
    return line.startswith("[") and " logs (" in line


def test_the_bar_is_cleared_before_a_note_or_a_log_record_and_fits_80_columns(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    term = FakeTerminal()
    bar = _Bar(stream=term, columns=80)
    handler = logging.StreamHandler(term)
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        bar.attach()
        ok, refused = SimpleNamespace(status="ok"), SimpleNamespace(status="refused")
        total = 123_456
        for done in range(1, 40):
            bar.shown = float("-inf")  # every update draws
            bar(done, total, refused if done % 3 else ok)
            if done == 10:
                bar.note("local workers: 2 processes forked from this command")
            if done == 20:
                logging.getLogger("thrustmap.fleet.local").warning("fleet worker 123 stopped")
        bar(total, total, ok)
        bar.end()
    finally:
        root.removeHandler(handler)
    raw = term.getvalue()
    shown = screen(raw)
    assert "local workers: 2 processes forked from this command" in shown
    assert "fleet worker 123 stopped" in shown
    assert all(len(s) < 80 for s in raw.replace("\x1b[K", "").replace("\r", "\n").split("\n"))
    for line in shown:
        assert is_bar(line) or "logs (" not in line, line  # a bar, or another line: not both
        assert line.count(" logs (") <= 1 and "progress:" not in line
    assert is_bar(shown[-1]) and shown[-1].startswith("[" + "#" * 10)  # the last one stays
    assert handler.filters == []  # detached at the end


def test_a_narrow_terminal_gets_the_count_without_the_bar() -> None:
    term = FakeTerminal()
    bar = _Bar(stream=term, columns=40)
    bar(5, 1_000_000, SimpleNamespace(status="ok"))
    (line,) = screen(term.getvalue())
    assert line.startswith("5/1000000 logs (") and len(line) < 40


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Fleet:
    return make_fleet(tmp_path_factory.mktemp("fleet"), 2, corrupt=False, no_mass=0)


def test_on_a_terminal_the_workers_line_never_shares_the_bars_line(
    fleet: Fleet, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A re-run: the reused logs' progress is drawn, then the workers are announced (the line
    that used to land on the bar's line), then the new log's progress."""
    out = tmp_path / "out"
    main(args(fleet, out, "--workers", "0", "--quiet"))
    first = sorted(fleet.good)[0]
    shutil.copy(first, first.with_name("copy-" + first.name))
    term = FakeTerminal()
    monkeypatch.setattr(sys, "stderr", term)
    main(args(fleet, out, "--workers", "1"))
    shown = screen(term.getvalue())
    workers = [s for s in shown if "one log at a time each" in s]
    assert len(workers) == 1 and not is_bar(workers[0]) and "logs (" not in workers[0]
    assert any(is_bar(s) for s in shown)
    # on a terminal the bar only, never "progress:" lines (which used to follow the bar on its
    # line when an update came within 0.1 s of the last drawing)
    assert not any("progress:" in s for s in shown)
    assert all(s.count(" logs (") <= 1 for s in shown)


def test_elsewhere_progress_is_plain_lines(
    fleet: Fleet, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    main(args(fleet, tmp_path / "out", "--workers", "1"))
    err = capsys.readouterr().err
    assert "\r" not in err and "\x1b" not in err
    progress = [s for s in err.splitlines() if "logs (" in s]
    assert progress and all(s.startswith("progress: ") for s in progress)
