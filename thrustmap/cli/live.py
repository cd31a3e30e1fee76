"""The live view of the bench: a panel that fits the terminal, or plain progress lines.

``LiveView`` is fed by the runner (``sweep_monitor``, the runner's monitor callback) or by
``spin`` (``spin_report``) and shows: plan progress with phase and ETA (connecting and the
at-rest/tare wait are phases of their own), the commanded level, thrust, voltage, current, rpm
and temperature, a small plot of thrust and voltage over the last seconds, and each interlock's
margin. On a terminal it is a rich ``Live`` panel redrawn in place, every line cut to the
terminal's width (never wrapped), and erased on exit so only the summary stays; elsewhere (a
pipe, CI) it prints a plain line every few seconds to stderr; ``quiet`` prints nothing.

rich is imported when the panel starts, never when the CLI starts.
"""

from __future__ import annotations

import logging
import sys
import time
from collections import deque
from dataclasses import dataclass
from types import TracebackType
from typing import Any, TextIO

import click

log = logging.getLogger(__name__)
SPARK = "▁▂▃▄▅▆▇█"
#: units of the interlock margins the runner reports (name -> unit of its reading)
MARGIN_ORDER = ("thrust", "current", "voltage", "rpm", "temperature", "vibration")


@dataclass
class Snapshot:
    """The latest values shown (None = not measured by this rig)."""

    elapsed_s: float = 0.0
    total_s: float = 0.0
    segment: int = 0
    segments: int = 0
    label: str = ""
    throttle_pct: float | None = None
    throttle_native: float | None = None
    unit: str = ""
    thrust_n: float | None = None
    voltage_v: float | None = None
    current_a: float | None = None
    rpm: float | None = None
    temperature_c: float | None = None
    plan_note: str = ""  # an adaptive plan: worst interval, points, time left


def sparkline(values: list[float], width: int) -> str:
    """``values`` resampled to ``width`` block characters scaled to their own range."""
    if width <= 0 or not values:
        return ""
    n = len(values)
    picked = [values[min(n - 1, int(i * n / width))] for i in range(min(width, n))]
    lo, hi = min(picked), max(picked)
    span = hi - lo
    if span <= 0:
        return SPARK[0] * len(picked)
    return "".join(SPARK[min(7, int((v - lo) / span * 7.999))] for v in picked)


def _native(value: float, unit: str) -> str:
    """A native throttle with its unit: "1100 µs"; a dimensionless one (PX4's 0..1) as
    "0.100 of full scale"; one without a unit as "647.7 raw"."""
    if unit == "1":
        return f"{value:.3f} of full scale"
    if not unit:
        return f"{value:.1f} raw"
    return f"{value:.0f} {unit}"


def _fmt(x: float | None, spec: str, unit: str) -> str:
    return "–" if x is None else f"{format(x, spec)} {unit}"


class LiveView:
    """Live panel (terminal), plain lines (not a terminal) or nothing (quiet).

    Use as a context manager around the run: the panel is erased on every way out (Ctrl-C
    included) so the summary printed afterwards stands alone on a clean screen."""

    def __init__(
        self,
        title: str,
        *,
        quiet: bool = False,
        live: bool | None = None,
        total_s: float = 0.0,
        phase: str = "connecting",
        window_s: float = 20.0,
        plain_period_s: float = 5.0,
        refresh_s: float = 0.2,
        stream: TextIO | None = None,
    ) -> None:
        self.title = title
        self.quiet = quiet
        self.stream = stream
        out = stream if stream is not None else sys.stdout
        self.live = (not quiet) and (out.isatty() if live is None else live)
        self.window_s = window_s
        self.plain_period_s = plain_period_s
        self.refresh_s = refresh_s
        self.phase = phase
        self.snap = Snapshot(total_s=total_s)
        self.margins: dict[str, float] = {}
        self.history: deque[tuple[float, float | None, float | None]] = deque()
        self._live: Any = None
        self._console: Any = None
        self._last_draw = 0.0
        self._last_plain = -1e9
        self._log_streams: list[tuple[logging.Handler, Any]] = []

    # -- lifecycle ------------------------------------------------------------------------------
    def __enter__(self) -> LiveView:
        if self.live:
            from rich.console import Console
            from rich.live import Live

            self._console = Console(file=self.stream, highlight=False)
            self._live = Live(
                console=self._console,
                auto_refresh=False,  # redrawn from the feeding thread: no extra thread to stop
                transient=True,  # erased on exit: the summary stands alone
                redirect_stdout=False,
                redirect_stderr=False,
                vertical_overflow="crop",
            )
            self._live.start()
            self._route_logging()
            self._draw(force=True)
        elif not self.quiet:
            self._plain(f"{self.title}: {self.phase}")
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._live is not None:
            self._live.stop()
            self._live = None
        for handler, stream in self._log_streams:
            handler.stream = stream  # type: ignore[attr-defined]
        self._log_streams.clear()

    def _route_logging(self) -> None:
        """Log lines written to the terminal while the panel is up go above it (through the
        panel's console), or they would land inside the panel and break its redraw."""
        console = self._console
        terminal = {id(sys.stdout), id(sys.stderr), id(sys.__stdout__), id(sys.__stderr__)}

        class Above:
            def write(self, text: str) -> int:
                if text.strip():
                    console.print(text.rstrip("\n"), markup=False, highlight=False, soft_wrap=True)
                return len(text)

            def flush(self) -> None:
                pass

        loggers = [logging.getLogger(), logging.getLogger("thrustmap")]
        for handler in [h for lg in loggers for h in lg.handlers]:
            stream = getattr(handler, "stream", None)  # StreamHandler or the CLI's own handler
            if stream is not None and id(stream) in terminal:
                self._log_streams.append((handler, stream))
                handler.stream = Above()  # type: ignore[attr-defined]

    # -- feeding --------------------------------------------------------------------------------
    def note(self, text: str) -> None:
        """A one-off line for the operator: above the panel on a terminal, a plain line elsewhere."""
        if self._console is not None and self._live is not None:
            self._console.print(text, markup=False, highlight=False, soft_wrap=True)
        elif not self.quiet:
            self._plain(text)

    def set_phase(self, phase: str) -> None:
        if phase != self.phase:
            self.phase = phase
            if not self.live and not self.quiet:
                self._plain(f"{self.title}: {phase}")
            self._draw(force=True)

    def feed(self, snap: Snapshot, margins: dict[str, float] | None = None) -> None:
        """New values; redraws at most every ``refresh_s`` (wall clock)."""
        self.snap = snap
        if margins is not None:
            self.margins = margins
        self.history.append((snap.elapsed_s, snap.thrust_n, snap.voltage_v))
        while self.history and self.history[0][0] < snap.elapsed_s - self.window_s:
            self.history.popleft()
        if self.live:
            self._draw()
        elif not self.quiet:
            now = time.monotonic()
            if now - self._last_plain >= self.plain_period_s:
                self._plain(self.plain_line())

    def sweep_monitor(self, st: Any) -> None:
        """The runner's monitor callback (``thrustmap.rig.runner.Status``)."""
        r = st.reading
        # the runner's phases: at rest and tare before the plan (their own phase, not progress)
        phase = getattr(st, "phase", "plan")
        self.set_phase("running" if phase == "plan" else "waiting for rest, taring")
        self.feed(
            Snapshot(
                elapsed_s=st.elapsed_s,
                total_s=st.plan_duration_s,
                segment=st.segment,
                segments=st.segments,
                label=st.label,
                throttle_pct=st.throttle_pct,
                throttle_native=st.throttle_native,
                thrust_n=r.thrust_n,
                voltage_v=r.voltage_v,
                current_a=r.current_a,
                rpm=r.rpm,
                temperature_c=r.temperature_c,
                plan_note=getattr(st, "plan_note", ""),
            ),
            dict(st.margins),
        )

    def spin_report(self, report: Any, motor: int, unit: str, total_s: float) -> None:
        """``spin``'s once-a-second report (``thrustmap.rig.spin.SpinReport``)."""
        tel, stand = report.telemetry, report.stand
        rpm = None
        if tel is not None and tel.rpm is not None and len(tel.rpm) > 0:
            rpm = float(tel.rpm[motor - 1] if motor - 1 < len(tel.rpm) else tel.rpm[0])
        self.set_phase("spinning")
        self.feed(
            Snapshot(
                elapsed_s=report.elapsed_s,
                total_s=total_s,
                label=f"motor {motor}",
                throttle_pct=report.throttle_pct,
                throttle_native=report.throttle_native,
                unit=unit,
                thrust_n=None if stand is None else stand.thrust_n,
                voltage_v=(tel.voltage_v if tel is not None else None)
                or (getattr(stand, "voltage_v", None) if stand is not None else None),
                current_a=(tel.current_a if tel is not None else None)
                or (getattr(stand, "current_a", None) if stand is not None else None),
                rpm=rpm,
            )
        )

    # -- plain ----------------------------------------------------------------------------------
    def plain_line(self) -> str:
        s = self.snap
        eta = max(s.total_s - s.elapsed_s, 0.0)
        # before the plan (connecting, at rest, taring) there is no progress or ETA to show
        clock = f"{s.elapsed_s:5.0f}/{s.total_s:.0f} s ETA {eta:.0f} s" if s.total_s > 0 else ""
        seg = f" seg {s.segment + 1}/{s.segments}" if s.segments else ""
        margin = ""
        if self.margins:
            name, m = min(self.margins.items(), key=lambda kv: kv[1])
            margin = f"  tightest margin {name} {m * 100:.0f} %"
        native = "" if s.throttle_native is None else f" ({_native(s.throttle_native, s.unit)})"
        return (
            f"{clock}{seg} {s.label}  ".lstrip()
            + f"thr {_fmt(s.throttle_pct, '.1f', '%')}{native}  T {_fmt(s.thrust_n, '.2f', 'N')}  "
            f"{_fmt(s.voltage_v, '.2f', 'V')}  {_fmt(s.current_a, '.1f', 'A')}  "
            f"{_fmt(s.rpm, '.0f', 'rpm')}{margin}" + (f"  {s.plan_note}" if s.plan_note else "")
        )

    def _plain(self, line: str) -> None:
        self._last_plain = time.monotonic()
        click.echo(line, err=True)

    # -- panel ----------------------------------------------------------------------------------
    def _draw(self, force: bool = False) -> None:
        if self._live is None:
            return
        now = time.monotonic()
        if not force and now - self._last_draw < self.refresh_s:
            return
        self._last_draw = now
        try:
            self._live.update(self.render(self._console.size.width), refresh=True)
        except Exception as exc:  # a display fault must never end a run: fall back to lines
            log.warning("live panel failed (%s); printing progress lines instead", exc)
            self._live.stop()
            self._live = None
            self.live = False

    def render(self, width: int) -> Any:
        """The panel as a rich renderable whose every line fits in ``width`` columns."""
        from rich.console import Group
        from rich.text import Text

        w = max(width, 20)
        s = self.snap
        lines: list[Text] = []

        def line(*parts: tuple[str, str]) -> None:
            t = Text(no_wrap=True, overflow="ellipsis")
            for text, style in parts:
                t.append(text, style=style)
            t.truncate(w, overflow="ellipsis")
            lines.append(t)

        phase_style = "bold green" if self.phase in ("running", "spinning") else "bold yellow"
        seg = f"  segment {s.segment + 1}/{s.segments}" if s.segments else ""
        line(
            (self.title, "bold"),
            ("  phase: ", ""),
            (self.phase, phase_style),
            (f"{seg}  {s.label}", "cyan"),
        )
        frac = min(max(s.elapsed_s / s.total_s, 0.0), 1.0) if s.total_s > 0 else 0.0
        eta = max(s.total_s - s.elapsed_s, 0.0)
        if s.total_s > 0:
            tail = f" {frac * 100:3.0f} %  {s.elapsed_s:.0f}/{s.total_s:.0f} s  ETA {eta:.0f} s"
            bar_w = max(w - len(tail) - 2, 4)
            filled = int(round(frac * bar_w))
            line(("█" * filled, "green"), ("░" * (bar_w - filled), "grey50"), (tail, ""))
        else:  # connecting, waiting for rest, taring: no plan progress yet, so no bar or ETA
            line((f"{self.phase}: the plan has not started", "grey50"))
        if s.plan_note:
            line(("adaptive: ", "grey50"), (s.plan_note, "bold cyan"))
        native = "" if s.throttle_native is None else f" ({_native(s.throttle_native, s.unit)})"
        cells = [
            ("throttle", _fmt(s.throttle_pct, ".1f", "%") + native),
            ("thrust", _fmt(s.thrust_n, ".3f", "N")),
            ("voltage", _fmt(s.voltage_v, ".2f", "V")),
            ("current", _fmt(s.current_a, ".1f", "A")),
            ("rpm", _fmt(s.rpm, ".0f", "")),
            ("temp", _fmt(s.temperature_c, ".1f", "°C")),
        ]
        self._cells(cells, w, line)
        span = self.history[-1][0] - self.history[0][0] if len(self.history) > 1 else 0.0
        for name, idx, unit, style in (("thrust", 1, "N", "magenta"), ("voltage", 2, "V", "blue")):
            vals = [float(h[idx]) for h in self.history if h[idx] is not None]  # type: ignore[arg-type]
            rng = f" {min(vals):.2f}..{max(vals):.2f} {unit}" if vals else " –"
            label = f"{name:<8}"
            spark_w = max(w - len(label) - len(rng) - 1, 0)
            line((label, ""), (sparkline(vals, spark_w), style), (rng, "grey50"))
        line((f"(last {span:.0f} s)", "grey50"))
        if self.margins:
            items = []
            for name in sorted(self.margins, key=lambda n: (MARGIN_ORDER + (n,)).index(n)):
                m = self.margins[name]
                style = "green" if m > 0.3 else "yellow" if m > 0.1 else "bold red"
                items.append((f"{name} {m * 100:.0f}%", style))
            row: list[tuple[str, str]] = [("margins: ", "")]
            used = len("margins: ")
            for text, style in items:
                piece = text + "  "
                if used + len(piece) > w and len(row) > 1:
                    line(*row)
                    row, used = [("         ", "")], 9
                row.append((piece, style))
                used += len(piece)
            line(*row)
        # A short last line: the terminal's "^C" echo lands here without wrapping the panel.
        line(("Ctrl-C stops the motor and keeps the log", "grey50"))
        return Group(*lines)

    @staticmethod
    def _cells(cells: list[tuple[str, str]], width: int, line: Any) -> None:
        """name value pairs laid out in as many columns as the width allows."""
        cell_w = max(len(n) + len(v) + 3 for n, v in cells)
        per_row = max(1, width // cell_w)
        for i in range(0, len(cells), per_row):
            parts = []
            for n, v in cells[i : i + per_row]:
                parts.append((f"{n} ", "grey50"))
                parts.append((v.ljust(cell_w - len(n) - 1), "bold"))
            line(*parts)
