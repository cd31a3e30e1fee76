"""Configurable text-line thrust stands (DIY stands on a serial port): a pure codec.

A :class:`LineStandSpec` says how to read one stand's lines and how to command it:

- ``columns``: field -> :class:`Column` (by 0-based ``index`` or by header ``name``) with
  ``si = raw * scale + offset``. Fields: ``time_s``, ``throttle`` (native units of
  ``throttle_scale``), ``thrust_n``, ``torque_nm``, ``voltage_v``, ``current_a``, ``rpm``.
  ``thrust_n`` is required.
- ``header_prefix`` (e.g. ``#COLS``): a line ``#COLS a,b,c`` names the columns; name-based
  columns resolve against the latest header. Other lines starting with ``comment_prefix``
  (``#``) are banners/comments.
- ``throttle_command``: a ``str.format`` template with ``{us}`` (int, PWM µs 1000..2000),
  ``{pct}`` (float 0..100), ``{pct_floor}`` (int, never above ``pct``), ``{fraction}`` (0..1),
  ``{native}`` and any ``command_vars``;
  e.g. ``"HOLD,{pct:.1f}\\n"``, ``"{us:d}\\n"``, ``"thr({pct:.0f})"``. ``stop_command``
  (default: the throttle command at 0 %). ``keepalive`` line sent every
  ``keepalive_interval_s`` (the stand's watchdog, ``watchdog_s``, stops the motor without it).

:class:`LineStandDecoder` is incremental (any chunking; LF, CRLF or CR line ends). Bad lines are
reported as :class:`LineError` events (a ``DataFormatError`` with the line number and reason) in
stream order by ``feed_events``; ``feed`` returns only samples. Nothing it is fed makes it raise.

Reference protocol for DIY stands (preset ``thrustmap-line``, see ``LINE_PROTOCOL.md``)::

    stand -> host   # any banner text
                    #COLS t_us,throttle_us,thrust_mN,torque_mNm,voltage_mV,current_mA,rpm
                    1234567,1500,4021,-52,16012,8340,21050        (integers, LF)
    host -> stand   THR <us>\\n   (1000..2000, clamped; 1000 = stop)   STOP\\n   PING\\n
                    any line feeds a 1 s watchdog; on expiry the stand sets 1000 µs and prints
                    "#WATCHDOG". Hosts send PING every 0.25 s.
"""

from __future__ import annotations

import math
import re
import string
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.core.units import scale as lookup_scale

#: lines a port must print before ``matches_lines`` identifies a preset from them
IDENTIFY_MIN_LINES = 3
FIELDS = ("time_s", "throttle", "thrust_n", "torque_nm", "voltage_v", "current_a", "rpm")
MAX_LINE_BYTES = 4096


@dataclass(frozen=True)
class Column:
    """Where a field is on the line and how to convert it: ``si = raw * scale + offset``."""

    index: int | None = None
    name: str | None = None
    scale: float = 1.0
    offset: float = 0.0
    #: the firmware prints the count modulo this (a 16-bit ``%d`` of a wider count): the count
    #: less its tare (``-offset / scale``) is taken in ``[-modulo/2, modulo/2)``
    modulo: int | None = None

    def to_si(self, raw: float) -> float:
        if self.modulo is None:
            return raw * self.scale + self.offset
        return _wrap(raw + self.offset / self.scale, self.modulo) * self.scale

    def from_si(self, value: float) -> float:
        raw = (value - self.offset) / self.scale
        return raw if self.modulo is None else _wrap(raw, self.modulo)


def _wrap(counts: float, modulo: int) -> float:
    half = modulo / 2
    return (counts + half) % modulo - half


@dataclass(frozen=True)
class LineStandSpec:
    name: str
    columns: Mapping[str, Column]
    delimiter: str | None = ","  # None: any whitespace
    comment_prefix: str = "#"
    header_prefix: str | None = "#COLS"
    header_names: tuple[str, ...] = ()  # the header a simulated stand prints
    throttle_scale: str = "pwm"
    throttle_command: str | None = None
    stop_command: str | None = None
    keepalive: str | None = None
    keepalive_interval_s: float = 0.25
    watchdog_s: float | None = None
    baudrate: int | None = None
    command_vars: Mapping[str, Any] = field(default_factory=dict)
    description: str = ""
    #: where this preset comes from: the firmware's repository, pinned commit, file and line
    source: str = ""
    #: how the preset was checked (shown by ``thrustmap probe`` and the README's stand table)
    verified: str = ""
    #: False when the firmware only echoes the throttle it is sent (it drives no ESC): the
    #: motor is then driven, and stopped, by the flight controller (``--throttle``)
    drives_esc: bool = True
    #: the firmware runs its own sweep: this line starts it (the motor spins: sent only when
    #: asked), ``sequence_end`` ends it; the run is read as a recording (throttle from its rows)
    sequence_start: str | None = None
    sequence_end: str | None = None
    #: the firmware's own sequence as its source defines it (for the simulator and the docs):
    #: the throttle levels (``throttle_scale`` units), the wait after each level is set, then
    #: ``sequence_rows`` rows ``sequence_row_period_s`` apart
    sequence_levels: tuple[float, ...] = ()
    sequence_settle_s: float = 0.0
    sequence_rows: int = 0
    sequence_row_period_s: float = 0.0
    #: what the firmware prints between cells when it is not ``delimiter`` (``", "``)
    row_separator: str | None = None
    #: the board resets when its port is opened (Arduino auto-reset by DTR) and hears
    #: nothing for this long (its bootloader): the first command waits for it
    boot_s: float = 0.0
    #: resetting the board (a DTR pulse on an Arduino's auto-reset line) stops its output; the
    #: way out for a firmware with no stop command
    reset_stops: bool = False
    #: identification by ``thrustmap probe``: every complete line the port prints unasked
    #: fullmatches one of these regular expressions (at least ``IDENTIFY_MIN_LINES`` of them)
    line_patterns: tuple[str, ...] = ()
    #: fields read as raw counts: ``thrustmap stand calibrate`` (tare + a known mass) writes the
    #: calibration that turns them into SI; until then the column's own scale is used
    raw_counts: tuple[str, ...] = ()
    #: data lines are those this regular expression matches at their start (the data is what
    #: follows the match: ``"D,"``); other lines (``SYSTEM_READY``, a menu) are text, kept as
    #: comments. None: every line that is not a comment or a header is data.
    data_match: str | None = None
    #: the number inside each cell is this expression's first group (``"Thrust: 12.3"`` with
    #: ``r":\s*(\S+)"``); None: the cell is the number
    cell_match: str | None = None
    #: a comment or text line this matches (at its start, any case) is the stand's watchdog
    #: stopping the motor; ``error_match``: the stand refusing a command
    watchdog_match: str = r"WATCHDOG\b"
    error_match: str = r"ERR\b"
    #: a firmware that takes a fixed set of throttle levels: (percent, command) pairs; a
    #: request is sent as the highest level at or below it (never more), below the lowest
    #: one as the stop command
    throttle_levels: tuple[tuple[float, str], ...] = ()
    #: a comment or text line this matches (at its start) confirms the stop (a firmware that
    #: prints no throttle column after stopping, e.g. a menu it prints again)
    stop_confirm: str | None = None
    #: how long the firmware's own stop takes (a ramp down): added to the time allowed to
    #: confirm it
    stop_time_s: float = 0.0

    def __post_init__(self) -> None:
        unknown = set(self.columns) - set(FIELDS)
        if unknown:
            raise ConfigError(
                f"line stand '{self.name}': unknown fields {sorted(unknown)}; "
                f"expected some of {', '.join(FIELDS)}"
            )
        if "thrust_n" not in self.columns:
            raise ConfigError(f"line stand '{self.name}': a thrust_n column is required")
        for key, col in self.columns.items():
            if (col.index is None) == (col.name is None):
                raise ConfigError(
                    f"line stand '{self.name}': column {key} needs exactly one of index or name"
                )
            if col.name is not None and self.header_prefix is None:
                raise ConfigError(
                    f"line stand '{self.name}': column {key} is named but there is no header"
                )
            if col.scale == 0 or not math.isfinite(col.scale):
                raise ConfigError(f"line stand '{self.name}': column {key} needs a finite scale")
            if col.modulo is not None and col.modulo < 2:
                raise ConfigError(f"line stand '{self.name}': column {key} modulo must be >= 2")
        lookup_scale(self.throttle_scale)
        for pattern in self.line_patterns:
            try:
                re.compile(pattern)
            except re.error as exc:
                raise ConfigError(
                    f"line stand '{self.name}': bad line pattern {pattern!r}: {exc}"
                ) from None
        for key in self.raw_counts:
            if key not in self.columns:
                raise ConfigError(f"line stand '{self.name}': raw_counts names no column {key}")
        self._check_firmware_fields()
        for template in (self.throttle_command, self.stop_command):
            if template is not None:
                try:
                    self._format(template, 0.0)
                except (KeyError, ValueError, IndexError) as exc:
                    raise ConfigError(
                        f"line stand '{self.name}': bad command template {template!r}: {exc}"
                    ) from None

    def _check_firmware_fields(self) -> None:
        for what, regex in (
            ("data_match", self.data_match),
            ("cell_match", self.cell_match),
            ("watchdog_match", self.watchdog_match),
            ("error_match", self.error_match),
            ("stop_confirm", self.stop_confirm),
        ):
            _check_regex(self.name, what, regex)
        if self.cell_match is not None and re.compile(self.cell_match).groups < 1:
            raise ConfigError(f"line stand '{self.name}': cell_match needs one (group)")
        if not (0.0 <= self.stop_time_s <= 60.0):
            raise ConfigError(f"line stand '{self.name}': stop_time_s must be 0..60 s")
        if self.throttle_levels and self.stop_command is None:
            raise ConfigError(f"line stand '{self.name}': throttle levels need a stop command")

    # -- commands (host -> stand) ---------------------------------------------------------
    def _format(self, template: str, pct: float) -> str:
        pct = min(max(pct, 0.0), 100.0)
        native = float(lookup_scale(self.throttle_scale).from_pct(pct))
        values = dict(self.command_vars)
        values.update(
            pct=pct,
            pct_floor=int(math.floor(pct + 1e-9)),
            us=int(round(1000 + 10 * pct)),
            fraction=pct / 100,
            native=native,
        )
        return template.format(**values)

    def command_for(self, throttle_native: float) -> bytes:
        """The throttle command for a value in ``throttle_scale`` units (clamped to 0..100 %)."""
        pct = float(lookup_scale(self.throttle_scale).to_pct(throttle_native))
        if self.throttle_levels:
            return self._level_command(pct)
        if self.throttle_command is None:
            raise ConfigError(f"line stand '{self.name}' takes no throttle command")
        return self._format(self.throttle_command, pct).encode()

    def _level_command(self, pct: float) -> bytes:
        below = [lv for lv in self.throttle_levels if lv[0] <= pct + 1e-9]
        if not below:
            return self.stop_bytes()
        return max(below)[1].encode()

    @property
    def takes_throttle(self) -> bool:
        """True when the host can set the throttle (a template or a set of levels)."""
        return self.throttle_command is not None or bool(self.throttle_levels)

    def stop_bytes(self) -> bytes:
        if self.stop_command is not None:
            return self._format(self.stop_command, 0.0).encode()
        if self.throttle_command is None:
            raise ConfigError(f"line stand '{self.name}' takes no commands")
        return self._format(self.throttle_command, 0.0).encode()

    def matches_lines(self, lines: list[str]) -> bool:
        """True when these complete lines (empty ones skipped) are what this stand prints:
        at least ``IDENTIFY_MIN_LINES``, each fullmatching one of ``line_patterns``."""
        if not self.line_patterns:
            return False
        texts = [ln.strip() for ln in lines if ln.strip()]
        if len(texts) < IDENTIFY_MIN_LINES:
            return False
        patterns = [re.compile(p) for p in self.line_patterns]
        return all(any(p.fullmatch(t) for p in patterns) for t in texts)

    def keepalive_bytes(self) -> bytes | None:
        return None if self.keepalive is None else self.keepalive.encode()

    def parse_command(self, line: str) -> float | None:
        """Stand side: the throttle percent a received command asks for (0 for stop), or None
        when the line is not a throttle/stop command (a keep-alive, or unknown)."""
        text = line.strip()
        if self.stop_command is not None and text == self.stop_command.strip():
            return 0.0
        for pct, command in self.throttle_levels:
            if text == command.strip():
                return pct
        if self.throttle_command is None:
            return None
        match = _template_regex(self.throttle_command, dict(self.command_vars)).fullmatch(text)
        if match is None:
            return None
        got = {k: float(v) for k, v in match.groupdict().items()}
        if "pct" in got or "pct_floor" in got:
            return min(max(got.get("pct", got.get("pct_floor", 0.0)), 0.0), 100.0)
        if "us" in got:
            return min(max((got["us"] - 1000.0) / 10.0, 0.0), 100.0)
        if "fraction" in got:
            return min(max(got["fraction"] * 100.0, 0.0), 100.0)
        if "native" in got:
            pct = float(lookup_scale(self.throttle_scale).to_pct(got["native"]))
            return min(max(pct, 0.0), 100.0)
        return None

    # -- lines (stand -> host), for simulators --------------------------------------------
    def header_line(self) -> str | None:
        if self.header_prefix is None or not self.header_names:
            return None
        return f"{self.header_prefix} {','.join(self.header_names)}"

    def format_sample(self, values: Mapping[str, float]) -> str:
        """A data line carrying ``values`` (SI, by field); other columns read 0."""
        positions: dict[str, int] = {}
        for key, col in self.columns.items():
            if col.index is not None:
                positions[key] = col.index
            elif col.name in self.header_names:
                positions[key] = self.header_names.index(col.name)
        width = max([len(self.header_names), *(p + 1 for p in positions.values())])
        cells = ["0"] * width
        for key, pos in positions.items():
            if key in values:
                raw = self.columns[key].from_si(values[key])
                cells[pos] = str(int(round(raw))) if abs(raw) < 1e15 else repr(raw)
        return (self.row_separator or self.delimiter or " ").join(cells)

    def with_load_cell(self, field_name: str, tare: float, si_per_count: float) -> LineStandSpec:
        """Calibrate a raw column: ``si = (raw - tare) * si_per_count``."""
        col = self.columns[field_name]
        cols = dict(self.columns)
        cols[field_name] = replace(col, scale=si_per_count, offset=-tare * si_per_count)
        return replace(self, columns=cols)


def _check_regex(name: str, what: str, pattern: str | None) -> None:
    if pattern is None:
        return
    try:
        re.compile(pattern)
    except re.error as exc:
        raise ConfigError(f"line stand '{name}': bad {what} {pattern!r}: {exc}") from None


def _template_regex(template: str, fixed: dict[str, Any]) -> re.Pattern[str]:
    parts: list[str] = []
    for literal, name, spec, _conv in string.Formatter().parse(template.strip()):
        parts.append(re.escape(literal))
        if name is None:
            continue
        if name in ("pct", "pct_floor", "us", "fraction", "native"):
            parts.append(rf"(?P<{name}>[-+]?\d+(?:\.\d*)?)")
        elif name in fixed:
            parts.append(re.escape(format(fixed[name], spec or "")))
        else:
            parts.append(r".*?")
    return re.compile("".join(parts))


# --------------------------------------------------------------------------- decoding


@dataclass(frozen=True)
class LineSample:
    """One data line in SI units (None for fields the stand does not report)."""

    line_no: int
    thrust_n: float
    time_s: float | None = None
    throttle: float | None = None
    torque_nm: float | None = None
    voltage_v: float | None = None
    current_a: float | None = None
    rpm: float | None = None


@dataclass(frozen=True)
class LineComment:
    line_no: int
    text: str


@dataclass(frozen=True)
class LineHeader:
    line_no: int
    names: tuple[str, ...]


class LineError(DataFormatError):
    """A line that could not be read; ``line`` is its 1-based number, ``text`` the line."""

    def __init__(self, message: str, *, line: int, text: str, column: str | None = None):
        super().__init__(message, line=line, column=column)
        self.text = text


LineEvent = LineSample | LineComment | LineHeader | LineError


class LineStandDecoder:
    def __init__(self, spec: LineStandSpec, max_kept_errors: int = 64) -> None:
        self.spec = spec
        self._buf = bytearray()
        self._skip_lf = False
        self._overflow = False
        self.line_no = 0
        self.header: tuple[str, ...] | None = None
        self._indices: dict[str, int] | None = self._resolve(None)
        self.errors: deque[LineError] = deque(maxlen=max_kept_errors)
        self.error_count = 0
        self._data_re = None if spec.data_match is None else re.compile(spec.data_match)
        self._cell_re = None if spec.cell_match is None else re.compile(spec.cell_match)

    def feed(self, data: bytes | bytearray | memoryview) -> list[LineSample]:
        samples: list[LineSample] = []
        for event in self.feed_events(data):
            if isinstance(event, LineSample):
                samples.append(event)
            elif isinstance(event, LineError):
                self.errors.append(event)
        return samples

    def feed_events(self, data: bytes | bytearray | memoryview) -> list[LineEvent]:
        events: list[LineEvent] = []
        buf = self._buf
        for byte in bytes(data):
            if byte in (0x0A, 0x0D):
                if byte == 0x0A and self._skip_lf:
                    self._skip_lf = False
                    continue
                self._skip_lf = byte == 0x0D
                self._end_line(events)
                continue
            self._skip_lf = False
            if len(buf) < MAX_LINE_BYTES:
                buf.append(byte)
            else:
                self._overflow = True
        return events

    def _end_line(self, events: list[LineEvent]) -> None:
        self.line_no += 1
        raw = bytes(self._buf)
        self._buf.clear()
        if self._overflow:
            self._overflow = False
            self._error(events, f"line longer than {MAX_LINE_BYTES} bytes", raw[:80])
            return
        text = raw.decode("utf-8", errors="replace").strip()
        if not text:
            return
        spec = self.spec
        if spec.header_prefix is not None and text.startswith(spec.header_prefix):
            body = text[len(spec.header_prefix) :]
            names = tuple(n.strip() for n in re.split(r"[,\s;]+", body.strip()) if n.strip())
            self.header = names
            events.append(LineHeader(self.line_no, names))
            self._indices = self._resolve(names)
            if self._indices is None:
                missing = [
                    c.name
                    for c in spec.columns.values()
                    if c.name is not None and c.name.lower() not in {n.lower() for n in names}
                ]
                self._error(events, f"header lacks columns {missing}", raw)
            return
        if text.startswith(spec.comment_prefix):
            events.append(LineComment(self.line_no, text[len(spec.comment_prefix) :].strip()))
            return
        if self._data_re is not None:
            match = self._data_re.match(text)
            if match is None:
                events.append(LineComment(self.line_no, text))
                return
            text = text[match.end() :]
        self._data_line(text, events)

    def _resolve(self, names: tuple[str, ...] | None) -> dict[str, int] | None:
        lower = [n.lower() for n in names] if names is not None else []
        out: dict[str, int] = {}
        for key, col in self.spec.columns.items():
            if col.index is not None:
                out[key] = col.index
            elif col.name is not None and col.name.lower() in lower:
                out[key] = lower.index(col.name.lower())
            else:
                return None
        return out

    def _data_line(self, text: str, events: list[LineEvent]) -> None:
        if self._indices is None:
            self._error(events, f"data before a usable {self.spec.header_prefix} header", text)
            return
        if self.spec.sequence_end is not None and text == self.spec.sequence_end:
            events.append(LineComment(self.line_no, text))
            return
        parts = text.split(self.spec.delimiter) if self.spec.delimiter else text.split()
        values: dict[str, float] = {}
        for key, index in self._indices.items():
            col = self.spec.columns[key]
            label = col.name or f"#{index}"
            if index >= len(parts):
                self._error(
                    events,
                    f"expected at least {index + 1} columns, got {len(parts)}",
                    text,
                    label,
                )
                return
            cell = parts[index].strip()
            if self._cell_re is not None:
                found = self._cell_re.search(cell)
                cell = found.group(1) if found is not None else cell
            try:
                raw = float(cell)
            except ValueError:
                raw = math.nan
            if not math.isfinite(raw):
                self._error(events, f"{cell!r} is not a finite number", text, label)
                return
            values[key] = col.to_si(raw)
        events.append(LineSample(self.line_no, **values))

    def _error(
        self, events: list[LineEvent], reason: str, text: str | bytes, column: str | None = None
    ) -> None:
        if isinstance(text, bytes):
            text = text.decode("utf-8", errors="replace")
        self.error_count += 1
        events.append(
            LineError(f"{self.spec.name}: {reason}", line=self.line_no, text=text, column=column)
        )


# --------------------------------------------------------------------------- presets

#: The reference DIY protocol (LINE_PROTOCOL.md): integer milli-units, named columns.
REFERENCE = LineStandSpec(
    name="thrustmap-line",
    columns={
        "time_s": Column(name="t_us", scale=1e-6),
        "throttle": Column(name="throttle_us"),
        "thrust_n": Column(name="thrust_mN", scale=1e-3),
        "torque_nm": Column(name="torque_mNm", scale=1e-3),
        "voltage_v": Column(name="voltage_mV", scale=1e-3),
        "current_a": Column(name="current_mA", scale=1e-3),
        "rpm": Column(name="rpm"),
    },
    header_names=(
        "t_us",
        "throttle_us",
        "thrust_mN",
        "torque_mNm",
        "voltage_mV",
        "current_mA",
        "rpm",
    ),
    throttle_scale="pwm",
    throttle_command="THR {us:d}\n",
    stop_command="STOP\n",
    keepalive="PING\n",
    keepalive_interval_s=0.25,
    watchdog_s=1.0,
    baudrate=115200,
    description="thrustmap reference line protocol v1 (see protocols/LINE_PROTOCOL.md)",
)

#: A GENERIC hold-command CSV stand (not any published firmware): ``#COLS`` with 8 named
#: columns, ``HOLD,<pct>,<log_ms>,<settle_ms>``, ``STOP``, ``PING`` every 0.25 s against a 1 s
#: watchdog. It was once called ``rp2040-whoop`` from notes; that name now means the real
#: RP2040 whoop firmware (einsz/whoop_thrust_stand, ``presets/einsz_whoop.py``), which this
#: does not match. thrust_raw is uncalibrated: ``with_load_cell("thrust_n", tare, n_per_count)``.
GENERIC_HOLD = LineStandSpec(
    name="generic-hold-csv",
    columns={
        "time_s": Column(name="t_us", scale=1e-6),
        "throttle": Column(name="throttle_pct"),
        "rpm": Column(name="rpm"),
        "thrust_n": Column(name="thrust_raw"),
        "voltage_v": Column(name="bus_mv", scale=1e-3),
        "current_a": Column(name="bus_ua", scale=1e-6),
    },
    header_names=(
        "t_us",
        "phase",
        "throttle_pct",
        "dshot",
        "rpm",
        "thrust_raw",
        "bus_mv",
        "bus_ua",
    ),
    throttle_scale="percent",
    throttle_command="HOLD,{pct:.1f},{log_ms:d},{settle_ms:d}\n",
    stop_command="STOP\n",
    keepalive="PING\n",
    keepalive_interval_s=0.25,
    watchdog_s=1.0,
    command_vars={"log_ms": 0, "settle_ms": 0},
    description="generic hold-command CSV stand (no published firmware; formerly "
    "'rp2040-whoop'); set log_ms/settle_ms in command_vars for your firmware",
    verified="documentation only (a generic protocol; no firmware to check against)",
)

#: the old name of ``GENERIC_HOLD`` (the preset ``rp2040-whoop`` now means einsz's firmware)
RP2040_WHOOP = GENERIC_HOLD

#: the presets defined here; every preset (one module per DIY firmware in
#: ``protocols.stands.presets``, aliases) is in ``protocols.stands.line_presets``
PRESETS: dict[str, LineStandSpec] = {s.name: s for s in (REFERENCE, GENERIC_HOLD)}
