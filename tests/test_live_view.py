"""The live view of the bench: fits any width, plain lines off a terminal, clean exit on Ctrl-C.

Pseudo-terminal tests run a real-time simulated sweep under a pty of 80 and 120 columns and
replay the bytes into a terminal emulator (pyte): no printed line is wider than the terminal
(so no redraw wraps), and after Ctrl-C the screen holds the summary and no panel remnants.
"""

from __future__ import annotations

import fcntl
import io
import os
import re
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest

from thrustmap.cli.live import LiveView, Snapshot, sparkline

CSI = re.compile(rb"\x1b\[[0-9;?]*[A-Za-z]|\x1b\][^\x07]*\x07|\x1b[()][A-Z0-9]")
PANEL_MARKS = ("phase:", "margins:", "ETA")


def full_view(width: int) -> list[str]:
    from rich.cells import cell_len
    from rich.console import Console

    view = LiveView("sweep stairs-up", live=False, quiet=True, total_s=95.0)
    for k in range(200):
        view.feed(
            Snapshot(
                elapsed_s=k * 0.1, total_s=95.0, segment=4, segments=21, label="step 35 %",
                throttle_pct=35.0, throttle_native=1350.0, unit="us", thrust_n=3.1 + 0.01 * k,
                voltage_v=24.8 - 0.002 * k, current_a=12.3, rpm=15230.0, temperature_c=31.2,
            ),
            {"thrust": 0.62, "current": 0.08, "voltage": 0.2, "rpm": 0.5, "temperature": 0.7,
             "vibration": 0.9},
        )  # fmt: skip
    buf = io.StringIO()
    console = Console(file=buf, width=width, force_terminal=True, color_system=None)
    console.print(view.render(width))
    lines = buf.getvalue().splitlines()
    assert all(cell_len(ln) <= width for ln in lines), [ln for ln in lines if cell_len(ln) > width]
    return lines


@pytest.mark.parametrize("width", [40, 80, 120, 200])
def test_panel_lines_fit_the_width(width: int) -> None:
    lines = full_view(width)
    text = "\n".join(lines)
    assert "phase:" in text and "ETA" in text
    assert "thrust" in text and "voltage" in text and "current 12.3 A" in text.replace("  ", " ")
    assert "15230" in text and "31.2 °C" in text
    assert "current 8%" in text  # each interlock's margin
    assert len(lines) <= (16 if width < 60 else 11)  # a panel, not a scroll


def test_wide_terminal_uses_columns() -> None:
    assert len(full_view(120)) < len(full_view(40))


def test_sparkline_scales_to_its_range_and_width() -> None:
    assert sparkline([0.0, 1.0, 2.0, 3.0], 4) == "▁▃▆█"
    assert sparkline([5.0] * 10, 6) == "▁" * 6
    assert len(sparkline([float(x) for x in range(500)], 30)) == 30
    assert sparkline([], 10) == ""


def test_plain_lines_off_a_terminal(capsys: pytest.CaptureFixture[str]) -> None:
    with LiveView("sweep steps", live=False, plain_period_s=0.0) as view:
        view.set_phase("waiting for rest, taring")
        view.feed(Snapshot(elapsed_s=3.0, total_s=10.0, throttle_pct=20.0, thrust_n=1.5),
                  {"current": 0.4})  # fmt: skip
    err = capsys.readouterr().err
    assert "sweep steps: connecting" in err
    assert "sweep steps: waiting for rest, taring" in err
    assert "T 1.50 N" in err and "ETA 7 s" in err and "tightest margin current 40 %" in err
    assert "\x1b" not in err and "\r" not in err


def test_quiet_prints_nothing(capsys: pytest.CaptureFixture[str]) -> None:
    with LiveView("sweep steps", quiet=True, live=False, plain_period_s=0.0) as view:
        view.set_phase("running")
        view.feed(Snapshot(elapsed_s=1.0, total_s=2.0))
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""


# -- a real sweep in a pseudo-terminal ------------------------------------------------------------


def sweep_cmd(tmp_path: Path, *extra: str, realtime: bool = True) -> list[str]:
    return [
        sys.executable, "-m", "thrustmap", "sweep", "stairs-up", "--stand",
        "sim://tyto-1585", "--from", "10", "--to", "20", "--step", "10", "--dwell", "1.2",
        "--realtime" if realtime else "--fast", "--yes", "-o", str(tmp_path / "run.csv"), *extra,
    ]  # fmt: skip


def run_in_pty(
    args: list[str], cols: int, rows: int = 30, interrupt_after_s: float | None = None
) -> tuple[bytes, int]:
    """Run ``args`` on a new pty of cols x rows as its controlling terminal; optionally type
    Ctrl-C (the terminal sends SIGINT) that long after the panel shows 'running'."""
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, cols, 0, 0))

    def controlling_tty() -> None:
        os.setsid()
        fcntl.ioctl(0, termios.TIOCSCTTY, 0)

    env = {**os.environ, "COLUMNS": str(cols), "LINES": str(rows), "TERM": "xterm-256color"}
    env.pop("NO_COLOR", None)
    proc = subprocess.Popen(
        args, stdin=slave, stdout=slave, stderr=slave, preexec_fn=controlling_tty, env=env,
        close_fds=True,
    )  # fmt: skip
    os.close(slave)
    data = bytearray()
    running_at: float | None = None
    sent = False
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.1)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:
                break
            if not chunk:
                break
            data += chunk
            if running_at is None and b"running" in data:
                running_at = time.monotonic()
        if (
            interrupt_after_s is not None
            and not sent
            and running_at is not None
            and time.monotonic() - running_at > interrupt_after_s
        ):
            os.write(master, b"\x03")
            sent = True
        if proc.poll() is not None and not ready:
            break
    rc = proc.wait(timeout=30)
    os.close(master)
    return bytes(data), rc


def printed_segments(data: bytes) -> list[str]:
    """What the program printed between cursor returns/newlines, escape sequences removed."""
    text = CSI.sub(b"", data).decode("utf-8", "replace")
    return [s for s in re.split(r"[\r\n]", text) if s]


def final_screen(data: bytes, cols: int, rows: int = 30) -> list[str]:
    pyte = pytest.importorskip("pyte", reason="pyte (terminal emulator) is not installed")
    screen = pyte.Screen(cols, rows)
    stream = pyte.ByteStream(screen)
    stream.feed(data)
    return [ln.rstrip() for ln in screen.display if ln.strip()]


@pytest.mark.parametrize("cols", [80, 120])
def test_sweep_panel_in_a_pty_fits_and_ends_clean(cols: int, tmp_path: Path) -> None:
    from rich.cells import cell_len

    data, rc = run_in_pty(sweep_cmd(tmp_path), cols)
    assert rc == 0, data[-2000:]
    segs = printed_segments(data)
    assert any("phase:" in s and "running" in s for s in segs)  # the panel was drawn
    assert any("waiting for rest, taring" in s for s in segs)  # the tare wait is a phase
    assert any("margins:" in s for s in segs)
    # The panel's redraws never exceed the width (the final summary is ordinary output and
    # may wrap like any printed line: a long log path).
    too_wide = [s for s in segs if cell_len(s) > cols and not s.startswith("completed:")]
    assert too_wide == []
    screen = final_screen(data, cols)
    summary = "".join(screen[-3:])
    assert "completed:" in summary and "stop verified" in summary, screen
    assert not any(m in ln for ln in screen for m in PANEL_MARKS), screen


@pytest.mark.parametrize("cols", [80, 120])
def test_ctrl_c_leaves_a_clean_screen_with_the_summary(cols: int, tmp_path: Path) -> None:
    data, rc = run_in_pty(sweep_cmd(tmp_path), cols, interrupt_after_s=1.0)
    screen = final_screen(data, cols)
    assert rc != 0
    assert not any(m in ln for ln in screen for m in PANEL_MARKS), screen
    summary = "\n".join(screen)
    assert "aborted" in summary or "interrupted" in summary, screen
    assert "stop verified" in summary, screen


def test_not_a_terminal_prints_plain_lines_and_quiet_only_the_summary(tmp_path: Path) -> None:
    proc = subprocess.run(
        sweep_cmd(tmp_path, realtime=False), capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert "\x1b" not in proc.stdout + proc.stderr and "\r" not in proc.stderr
    assert "sweep stairs-up: running" in proc.stderr
    assert proc.stdout.strip().startswith("completed:")
    quiet = subprocess.run(
        sweep_cmd(tmp_path, "--quiet", realtime=False) + ["-o", str(tmp_path / "q.csv")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert quiet.returncode == 0, quiet.stderr
    assert quiet.stderr == ""
    assert quiet.stdout.strip().startswith("completed:") and len(quiet.stdout.splitlines()) == 1


def test_spin_panel_in_a_pty(tmp_path: Path) -> None:
    from rich.cells import cell_len

    args = [
        sys.executable, "-m", "thrustmap", "spin", "sim://betaflight", "--motor", "1",
        "--throttle", "10", "--seconds", "2", "--yes", "--clock", "real",
        "--stand", "sim://tyto-1585",
    ]  # fmt: skip
    data, rc = run_in_pty(args, 80)
    assert rc == 0, data[-2000:]
    segs = printed_segments(data)
    assert any("phase:" in s and "spinning" in s for s in segs)
    assert any(s.startswith("thrust ") for s in segs)  # the live plot of thrust
    assert [s for s in segs if cell_len(s) > 80] == []
    screen = final_screen(data, 80)
    assert screen[-1].startswith("motor 1 stopped (verified)"), screen
    assert not any(m in ln for ln in screen for m in PANEL_MARKS), screen


def test_a_failing_panel_falls_back_to_lines(capsys: pytest.CaptureFixture[str]) -> None:
    """A display fault never ends a run: the view drops the panel and prints lines."""
    view = LiveView(
        "sweep steps", live=True, stream=io.StringIO(), plain_period_s=0.0, refresh_s=0.0
    )

    def broken(width: int) -> None:
        raise ValueError("render bug")

    with view:
        view.render = broken  # type: ignore[method-assign]
        view.feed(Snapshot(elapsed_s=1.0, total_s=4.0, thrust_n=2.0))  # panel fails here
        view.feed(Snapshot(elapsed_s=2.0, total_s=4.0, thrust_n=2.5))
    assert view.live is False
    assert "T 2.50 N" in capsys.readouterr().err


def test_spin_closes_the_output_when_the_view_cannot_start(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The output is opened before the view: a view that fails to start still stops it."""
    from click.testing import CliRunner

    import thrustmap.rig.devices.opening as opening
    from thrustmap.cli import cli
    from thrustmap.cli import live as live_mod
    from thrustmap.core.units import SCALES

    class Output:
        throttle_scale = SCALES["pwm"]
        entered = exited = stops = closed = 0

        def __enter__(self) -> Output:
            Output.entered += 1
            return self

        def __exit__(self, *exc: object) -> None:
            Output.exited += 1

        def identify(self) -> None:
            pass

        def stop_and_verify(self) -> bool:
            Output.stops += 1
            return True

        def close(self) -> None:
            Output.closed += 1

    def no_view(self: LiveView) -> LiveView:
        raise RuntimeError("no terminal")

    monkeypatch.setattr(opening, "open_throttle_output", lambda *a, **k: Output())
    monkeypatch.setattr(live_mod.LiveView, "__enter__", no_view)
    result = CliRunner().invoke(
        cli, ["spin", "sim://betaflight", "--motor", "1", "--throttle", "10", "--yes"]
    )
    assert isinstance(result.exception, RuntimeError)
    # the session's one closing place stopped, verified and closed the output
    assert Output.stops == 1 and Output.closed == 1
