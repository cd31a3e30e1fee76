"""Issue 14's examples at library level: each test failed on the code before the fix."""

from __future__ import annotations

import contextlib
import logging
import os
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from fuzz.cli_cases import LOGS, dataflash_many_breaks, ulog_hang
from thrustmap.core.errors import ConfigError, DataFormatError, ThrustmapError

# -- 1. hangs -------------------------------------------------------------------------------------


def _skip_table_reference(i_interval: int, p_num: int, p_den: int) -> list[int]:
    def logged(idx: int) -> bool:
        return (idx % i_interval + p_num - 1) % p_den < p_num

    table = []
    for r in range(i_interval):
        k = 1
        while not logged(r + k) and k <= i_interval + p_den:
            k += 1
        table.append(k - 1)
    return table


def test_blackbox_skip_table_matches_the_reference_and_is_linear() -> None:

    import thrustmap.flightlogs.blackbox_format as blackbox_format

    for i_interval in (1, 2, 3, 7, 32, 33):
        for p_num, p_den in ((1, 1), (1, 2), (1, 16), (2, 3), (3, 7), (1, 40)):
            assert list(
                blackbox_format.p_skip_counts(i_interval, p_num, p_den)
            ) == _skip_table_reference(i_interval, p_num, p_den)
    # the largest header the decoder accepts: 2·65535 steps, not 65535² (the old loop)
    t0 = time.process_time()
    table = blackbox_format.p_skip_counts(
        blackbox_format.MAX_INTERVAL, 1, blackbox_format.MAX_INTERVAL
    )
    assert time.process_time() - t0 < 5.0
    assert table[0] == blackbox_format.MAX_INTERVAL - 1


@pytest.mark.parametrize(
    "header",
    [{"I interval": "99999999"}, {"P interval": "1/99999999"}, {"P interval": "99999999"}],
)
def test_blackbox_out_of_range_intervals_are_refused(header: dict[str, str]) -> None:
    import thrustmap.flightlogs.blackbox_format as thrustmap_flightlogs_blackbox_format
    from fuzz.cli_cases import bbl_with_header
    from thrustmap.flightlogs import blackbox_decode as bd

    data = bbl_with_header(header)
    a, b = thrustmap_flightlogs_blackbox_format.split_logs(data)[0]
    with pytest.raises(thrustmap_flightlogs_blackbox_format.CorruptFrame, match="out of range"):
        bd.decode_log(data[a:b])


def test_blackbox_thousands_of_fields_are_refused_before_parsing() -> None:
    import thrustmap.flightlogs.blackbox_format as thrustmap_flightlogs_blackbox_format
    from fuzz.cli_cases import bbl_many_fields

    data = bbl_many_fields(20000)
    with pytest.raises(thrustmap_flightlogs_blackbox_format.CorruptFrame, match="at most 256"):
        thrustmap_flightlogs_blackbox_format.parse_headers(data)


def test_blackbox_garbage_decodes_within_a_work_budget() -> None:
    """A log whose body is frame markers and noise: every byte starts a resync attempt."""
    import thrustmap.flightlogs.blackbox_format as flightlogs_blackbox_format
    from thrustmap.flightlogs import blackbox_decode as bd

    raw = (LOGS / "bb_hover_sim.bbl").read_bytes()
    a, b = flightlogs_blackbox_format.split_logs(raw)[0]
    section = raw[a:b]
    _, _, body = flightlogs_blackbox_format.parse_headers(section)
    rng = np.random.default_rng(3)
    noise = rng.choice(np.frombuffer(b"IPE\x00\x01\x80", np.uint8), size=400_000).tobytes()
    decoded = bd.decode_log(section[:body] + noise)
    assert any("too corrupt" in w or "corrupt frame" in w for w in decoded.warnings)


def test_dataflash_resync_is_linear_and_warnings_are_summarised(tmp_path: Path) -> None:
    from thrustmap.flightlogs import dataflash

    path = tmp_path / "x.bin"
    path.write_bytes(dataflash_many_breaks())
    log = dataflash.parse(path)
    skipped = [w for w in log.warnings if "corrupt" in w]
    assert len(skipped) <= dataflash.MAX_LISTED_GAPS + 2  # was one line per break (12,556)
    assert any("more corrupt stretches" in w for w in skipped)
    assert log.counts()  # the good messages between the breaks are all kept


def test_ulog_walk_stops_pyulog_before_its_endless_loop(tmp_path: Path) -> None:
    from thrustmap.flightlogs import ulog

    raw = ulog_hang()
    w = ulog.walk(raw)
    assert w.good_end == 16 and w.problem is not None
    path = tmp_path / "x.ulg"
    path.write_bytes(raw)
    with pytest.raises(DataFormatError):
        ulog.read(path)


def _ulog_with_formats(formats: list[str], subscribe: str) -> bytes:
    raw = (LOGS / "sim_hover.ulg").read_bytes()
    body = b""
    for f in formats:
        payload = f.encode()
        body += struct.pack("<HB", len(payload), ord("F")) + payload
    add = struct.pack("<BH", 0, 0) + subscribe.encode()
    body += struct.pack("<HB", len(add), ord("A")) + add
    return raw[:16] + body


def test_ulog_walk_refuses_cyclic_and_exploding_formats() -> None:
    from thrustmap.flightlogs import ulog

    cyclic = _ulog_with_formats(["a:b x;", "b:a y;"], "a")
    assert "cyclic" in (ulog.walk(cyclic).problem or "")
    exploding = _ulog_with_formats(
        ["a:b[255] x;", "b:c[255] y;", "c:uint64_t[255] z;"], "a"
    )  # 16.6 M fields once flattened
    assert "too large" in (ulog.walk(exploding).problem or "")
    fine = _ulog_with_formats(["a:uint64_t timestamp;float[4] q;"], "a")
    assert ulog.walk(fine).problem is None


def test_pyulog_prints_nothing_on_stdout(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    from fuzz.cli_cases import ulog_flipped
    from thrustmap.flightlogs import ulog

    for seed in range(4):
        path = tmp_path / f"x{seed}.ulg"
        path.write_bytes(ulog_flipped(seed))
        with contextlib.suppress(ThrustmapError):
            ulog.read(path)
    assert capfd.readouterr().out == ""


# -- 2. time jumps --------------------------------------------------------------------------------


def _acc(times: list[float]) -> object:
    from thrustmap.flightlogs.series import Signal

    t = np.asarray(times, float)
    return Signal(t, np.full(len(t), 9.8), "m/s^2", "test")


def test_one_mistyped_time_is_dropped_with_a_warning() -> None:
    from thrustmap.fitting.df.resample import plausible_timeline

    times = [*np.arange(0, 300, 0.01).tolist(), 3005000.0]
    acc, warnings = plausible_timeline(_acc(times), 10.0, "x.csv")  # type: ignore[arg-type]
    assert float(acc.time_s[-1]) < 300.0
    assert len(acc) == len(times) - 1
    assert any("3.005e+06" in w and "time jump" in w for w in warnings)


def test_a_span_the_samples_cannot_fill_is_refused() -> None:
    from thrustmap.fitting.df.resample import plausible_timeline

    # two equal halves a year apart: not an isolated sample, but no flight either
    times = [*np.arange(0, 10, 0.01).tolist(), *np.arange(3.2e7, 3.2e7 + 10, 0.01).tolist()]
    with pytest.raises(DataFormatError, match="span"):
        plausible_timeline(_acc(times), 10.0, "x.csv")  # type: ignore[arg-type]


def test_two_flights_an_hour_apart_are_kept() -> None:
    from thrustmap.fitting.df.resample import plausible_timeline

    times = [*np.arange(0, 120, 0.005).tolist(), *np.arange(3720, 3840, 0.005).tolist()]
    acc, warnings = plausible_timeline(_acc(times), 10.0, "x.csv")  # type: ignore[arg-type]
    assert len(acc) == len(times) and not warnings


# -- 3. outputs never over inputs -----------------------------------------------------------------


def test_write_df_refuses_a_sidecar_that_is_the_table(tmp_path: Path) -> None:
    import pandas as pd

    from thrustmap.fitting.df.dffile import write_df
    from thrustmap.fitting.df.table import Df

    df = Df(pd.DataFrame({"voltage_v": [16.0], "force_n": [10.0]}), {"format": "x"}, [])
    with pytest.raises(ConfigError, match="sidecar"):
        write_df(df, tmp_path / "df.json")
    side = write_df(df, tmp_path / "df.csv")
    assert side == tmp_path / "df.json"
    assert (tmp_path / "df.csv").read_text().startswith("voltage_v,force_n")
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporaries left


# -- 4. transcripts -------------------------------------------------------------------------------


def test_transcript_reader_opens_only_regular_files(tmp_path: Path) -> None:
    from thrustmap.protocols.transcript import TranscriptFormatError, read_transcript

    with pytest.raises(TranscriptFormatError, match="not a device"):
        read_transcript("/dev/zero")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(TranscriptFormatError, match="not a device"):
        read_transcript(fifo)


def test_transcript_line_length_is_bounded(tmp_path: Path) -> None:
    from thrustmap.protocols import transcript as tr

    path = tmp_path / "t.jsonl"
    header = '{"format": "thrustmap.transcript", "version": 1, "inner": ""}\n'
    path.write_text(header + '{"t": 0, "note": "' + "x" * (tr.MAX_LINE_CHARS + 10) + '"}\n')
    with pytest.raises(tr.TranscriptFormatError, match="longer than"):
        tr.read_transcript(path)


def test_transcript_header_url_is_never_opened(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import thrustmap.rig.devices.detect as detect
    from thrustmap.protocols import transcript as tr

    opened: list[str] = []
    real = tr.read_transcript

    def spy(path: str | os.PathLike[str], **kw: bool) -> tr.Transcript:
        opened.append(str(path))
        return real(path, **kw)

    monkeypatch.setattr(tr, "read_transcript", spy)
    path = tmp_path / "t.jsonl"
    path.write_text(
        '{"format": "thrustmap.transcript", "version": 1, "inner": "replay:///etc/shadow"}\n'
    )
    assert detect.detect_from_url(f"replay://{path}") is None
    assert opened == [str(path)]


def test_unknown_replay_option_is_a_typed_error(tmp_path: Path) -> None:
    from thrustmap.protocols.transcript import TransportError
    from thrustmap.protocols.transport import open_transport

    path = tmp_path / "t.jsonl"
    path.write_text('{"format": "thrustmap.transcript", "version": 1, "inner": ""}\n')
    with pytest.raises(TransportError, match="bogus"):
        open_transport(f"replay://{path}?bogus=1")


# -- 9/10. one line, the file named, warnings through logging -------------------------------------


def test_paper_csv_line_numbers_count_blank_lines(tmp_path: Path) -> None:
    from thrustmap.flightlogs.detect import read_log

    lines = (LOGS / "sim_hover_paper.csv").read_text().splitlines()
    lines[1:1] = ["", ""]  # two blank lines after the header
    cells = lines[10].split(",")
    cells[1] = "oops"
    lines[10] = ",".join(cells)
    path = tmp_path / "x.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError) as info:
        read_log(path, format="paper-csv")
    assert info.value.line == 11


def test_reader_errors_name_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from thrustmap.flightlogs import blackbox
    from thrustmap.flightlogs.detect import read_log

    def no_file(*args: object, **kwargs: object) -> object:
        raise DataFormatError("acc_1G unknown", column="accSmooth[2]")

    monkeypatch.setattr(blackbox, "read", no_file)
    path = tmp_path / "x.bbl"
    path.write_bytes((LOGS / "bb_hover_sim.bbl").read_bytes())
    with pytest.raises(DataFormatError) as info:
        read_log(path, format="blackbox")
    assert str(info.value).startswith(str(path))


def test_cli_error_is_one_line_and_warnings_are_counted(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import click

    from thrustmap import cli

    @click.command("boom")
    def boom() -> None:
        logging.getLogger("thrustmap.test").warning("first\nsecond")
        np.log(np.zeros(1))  # a numpy RuntimeWarning
        raise DataFormatError("bad\nthing", file="x.csv", line=3)

    monkeypatch.setitem(cli.COMMANDS, "boom", "x:y")
    monkeypatch.setattr(cli.LazyGroup, "get_command", lambda self, ctx, name: boom)
    with pytest.raises(SystemExit) as info:
        cli.main(["boom"])
    assert info.value.code == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.splitlines() == ["error: x.csv:3: bad thing (1 warning before it; -v shows them)"]


def test_cli_success_shows_held_warnings_on_one_line_each(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import click

    from thrustmap import cli

    @click.command("fine")
    def fine() -> None:
        logging.getLogger("thrustmap.test").warning("first\nsecond")
        np.log(np.zeros(1))
        click.echo("result")

    monkeypatch.setattr(cli.LazyGroup, "get_command", lambda self, ctx, name: fine)
    cli.main(["fine"])
    out, err = capsys.readouterr()
    assert out == "result\n"
    assert err.splitlines() == ["warning: first second"]
