"""ArduPilot DataFlash (.bin) logs, decoded in bulk with numpy.

A DataFlash log is a stream of messages ``A3 95 <type> <payload>``; FMT messages (type 128)
describe every other type: its length, struct format and column names. So the whole file can be
decoded without a per-message Python loop over fields:

1. find every ``A3 95`` pair (numpy), read the FMT messages among them;
2. follow the chain of message starts (each start plus its type's length is the next start),
   which skips header bytes that merely occur inside payloads; where the chain breaks, resync
   on the next start that chains on, and report the bytes skipped (a corrupt tail is reported
   and the good part used);
3. per message type, gather the payload bytes of all its messages into one array and view it
   through a structured dtype built from the FMT format string.

There is no checksum in the format, so a corrupt payload behind an intact header decodes as
garbage; the readers downstream range-check what they use.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from thrustmap.core.errors import DataFormatError
from thrustmap.core.units import ThrottleScale
from thrustmap.flightlogs.copter_era import (
    EV_ARMED,
    EV_DISARMED,
    climb_from_altitude,
    inertial_or_baro,
    land_state_from_events,
    untimed_events,
)
from thrustmap.flightlogs.series import (
    FlightLog,
    FloatArray,
    Signal,
    nanmedian,
    sorted_signal,
)

log = logging.getLogger(__name__)

HEAD1, HEAD2, FMT_TYPE, FMT_LEN = 0xA3, 0x95, 128, 89

#: format char -> (numpy dtype, multiplier or None); see ArduPilot's AP_Logger docs
_FORMAT: dict[str, tuple[str, float | None]] = {
    "a": ("(32,)<i2", None),
    "b": ("i1", None),
    "B": ("u1", None),
    "h": ("<i2", None),
    "H": ("<u2", None),
    "i": ("<i4", None),
    "I": ("<u4", None),
    "f": ("<f4", None),
    "d": ("<f8", None),
    "g": ("<f2", None),
    "n": ("S4", None),
    "N": ("S16", None),
    "Z": ("S64", None),
    "c": ("<i2", 0.01),
    "C": ("<u2", 0.01),
    "e": ("<i4", 0.01),
    "E": ("<u4", 0.01),
    "L": ("<i4", 1e-7),
    "M": ("u1", None),
    "q": ("<i8", None),
    "Q": ("<u8", None),
}

#: messages on the boot clock used to time messages that carry no time (EV before Copter 3.4)
TIME_REFERENCE_MESSAGES = ("IMU", "ATT", "CTUN", "BARO", "RCOU", "CURR", "BAT", "RCIN", "MAG")


@dataclass(frozen=True)
class MessageFormat:
    type_id: int
    length: int  # including the 3 header bytes
    name: str
    format: str
    columns: tuple[str, ...]
    dtype: np.dtype[Any]
    multipliers: tuple[float | None, ...]


def _make_format(type_id: int, length: int, name: str, fmt: str, cols: str) -> MessageFormat:
    names = tuple(c for c in cols.split(",") if c) if cols else ()
    if len(names) != len(fmt):
        raise ValueError(f"{name}: {len(fmt)} format chars but {len(names)} columns")
    if len(set(names)) != len(names):
        raise ValueError(f"{name}: duplicate column names")
    dtype = np.dtype({"names": list(names), "formats": [_FORMAT[c][0] for c in fmt]})
    if dtype.itemsize != length - 3:
        raise ValueError(f"{name}: format {fmt} is {dtype.itemsize} bytes, FMT says {length - 3}")
    return MessageFormat(
        type_id, length, name, fmt, names, dtype, tuple(_FORMAT[c][1] for c in fmt)
    )


class _Columns(dict[str, npt.NDArray[Any]]):
    """A message's columns; a missing one is a DataFormatError naming the message and field."""

    def __init__(self, path: str, fmt: MessageFormat) -> None:
        super().__init__()
        self.path = path
        self.fmt = fmt

    def __missing__(self, key: str) -> npt.NDArray[Any]:
        raise DataFormatError(
            f"{self.fmt.name} messages have no field '{key}' (their FMT defines "
            f"{', '.join(self.fmt.columns) or 'none'}); expected ArduPilot's {self.fmt.name} layout",
            file=self.path,
        )


@dataclass
class DataFlashLog:
    """A decoded DataFlash file: formats, message start offsets per type, warnings."""

    path: str
    buf: npt.NDArray[np.uint8]
    formats: dict[int, MessageFormat]
    starts: dict[int, npt.NDArray[np.int64]]
    warnings: list[str] = field(default_factory=list)
    bytes_decoded: int = 0

    @property
    def by_name(self) -> dict[str, MessageFormat]:
        return {f.name: f for f in self.formats.values()}

    def counts(self) -> dict[str, int]:
        return {
            self.formats[t].name: len(s)
            for t, s in sorted(self.starts.items())
            if t in self.formats and len(s)
        }

    def has(self, name: str) -> bool:
        f = self.by_name.get(name)
        return f is not None and len(self.starts.get(f.type_id, ())) > 0

    def records(self, name: str) -> npt.NDArray[Any]:
        """All ``name`` messages as one structured array (raw field values)."""
        f = self.by_name.get(name)
        if f is None:
            return np.zeros(0, dtype=np.dtype([]))
        s = self.starts.get(f.type_id, np.zeros(0, np.int64))
        width = f.length - 3
        if not len(s):
            return np.zeros(0, dtype=f.dtype)
        index = (s + 3)[:, None] + np.arange(width)[None, :]
        raw = np.ascontiguousarray(self.buf[index])
        return raw.view(f.dtype).reshape(len(s))

    def columns(self, name: str) -> dict[str, npt.NDArray[Any]]:
        """``name`` messages as column arrays with FMT multipliers applied (c, C, e, E, L)."""
        f = self.by_name.get(name)
        if f is None:
            return {}
        rec = self.records(name)
        out: dict[str, npt.NDArray[Any]] = _Columns(self.path, f)
        for col, mult in zip(f.columns, f.multipliers, strict=True):
            values = rec[col]
            out[col] = values * mult if mult is not None else values
        return out

    def time_s(self, name: str) -> FloatArray:
        cols = self.columns(name)
        if "TimeUS" in cols:
            return np.asarray(cols["TimeUS"], float) * 1e-6
        if "TimeMS" in cols:
            return np.asarray(cols["TimeMS"], float) * 1e-3
        return self._time_from_neighbours(name)

    def _time_from_neighbours(self, name: str) -> FloatArray:
        """Times of a message without a time column (EV in Copter <= 3.3): each takes the time of
        the nearest timestamped message written before it (after it, when none precedes)."""
        f = self.by_name.get(name)
        own = self.starts.get(f.type_id, np.zeros(0, np.int64)) if f else np.zeros(0, np.int64)
        ref_pos: list[npt.NDArray[np.int64]] = []
        ref_t: list[FloatArray] = []
        for ref in TIME_REFERENCE_MESSAGES:  # boot-clock messages (GPS TimeMS is GPS time)
            rf = self.by_name.get(ref)
            if rf is None or not self.has(ref):
                continue
            col = next((c for c in ("TimeUS", "TimeMS") if c in rf.columns), None)
            if col is None:
                continue
            ref_pos.append(self.starts[rf.type_id])
            ref_t.append(
                np.asarray(self.records(ref)[col], float) * (1e-6 if col == "TimeUS" else 1e-3)
            )
        if not len(own):
            return np.zeros(0)
        if not ref_pos:
            raise DataFormatError(
                f"message {name} has no TimeUS/TimeMS column and no timestamped message "
                "(IMU, ATT, CTUN, ...) to time it by",
                file=self.path,
            )
        pos = np.concatenate(ref_pos)
        order = np.argsort(pos, kind="stable")
        pos, t = pos[order], np.concatenate(ref_t)[order]
        k = np.searchsorted(pos, own) - 1  # the timestamped message written just before
        return np.asarray(t[np.clip(k, 0, len(t) - 1)], float)

    def params(self) -> dict[str, float]:
        cols = self.columns("PARM")
        if not cols:
            return {}
        names = [bytes(n).split(b"\0")[0].decode("ascii", "replace") for n in cols["Name"]]
        return {n: float(v) for n, v in zip(names, cols["Value"], strict=True)}

    def text_messages(self) -> list[str]:
        cols = self.columns("MSG")
        return [
            bytes(m).split(b"\0")[0].decode("ascii", "replace") for m in cols.get("Message", [])
        ]


def _read_formats(
    buf: npt.NDArray[np.uint8], heads: npt.NDArray[np.int64]
) -> tuple[dict[int, MessageFormat], list[str]]:
    warnings: list[str] = []
    formats: dict[int, MessageFormat] = {}
    n = len(buf)
    fmt_pos = heads[(buf[heads + 2] == FMT_TYPE) & (heads + FMT_LEN <= n)]
    for p in fmt_pos.tolist():
        body = buf[p + 3 : p + FMT_LEN].tobytes()
        type_id, length = body[0], body[1]
        try:
            name = body[2:6].split(b"\0")[0].decode("ascii")
            fmt = body[6:22].split(b"\0")[0].decode("ascii")
            cols = body[22:86].split(b"\0")[0].decode("ascii")
            if not name.isprintable() or not name or length < 3:
                continue
            mf = _make_format(type_id, length, name, fmt, cols)
        except (UnicodeDecodeError, KeyError, ValueError, TypeError):
            continue  # header bytes inside a payload, or a format we cannot decode
        old = formats.get(type_id)
        if old is None:
            formats[type_id] = mf
        elif (old.length, old.format, old.columns) != (mf.length, mf.format, mf.columns):
            warnings.append(f"type {type_id} redefined ({old.name} -> {mf.name}); kept the first")
    return formats, warnings


#: chain breaks listed one by one; beyond this they are summarised in one line
MAX_LISTED_GAPS = 5


def _gap_warnings(gaps: list[tuple[int, int]]) -> list[str]:
    """One line per corrupt stretch, at most MAX_LISTED_GAPS, then one summary line."""
    out = [f"skipped {size} corrupt bytes at byte {at}" for at, size in gaps[:MAX_LISTED_GAPS]]
    rest = gaps[MAX_LISTED_GAPS:]
    if rest:
        out.append(
            f"... and {len(rest)} more corrupt stretches ({sum(s for _, s in rest)} bytes, "
            f"from byte {rest[0][0]} to {rest[-1][0]}) skipped"
        )
    return out


def parse(path: str | Path) -> DataFlashLog:
    """Decode the message layout of a DataFlash file (messages are decoded on demand)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise DataFormatError(f"cannot read DataFlash log: {exc.strerror}", file=str(p)) from None
    if not raw:
        raise DataFormatError("DataFlash log is empty (0 bytes)", file=str(p))
    buf = np.frombuffer(raw, dtype=np.uint8)
    n = len(buf)
    heads = np.flatnonzero((buf[:-2] == HEAD1) & (buf[1:-1] == HEAD2)).astype(np.int64)
    if not len(heads) or buf[2] != FMT_TYPE or heads[0] != 0:
        raise DataFormatError(
            "not a DataFlash log: expected it to start with an FMT message (A3 95 80), "
            f"found {raw[:3].hex(' ')}",
            file=str(p),
        )
    formats, warnings = _read_formats(buf, heads)
    if FMT_TYPE not in formats:
        raise DataFormatError("DataFlash log has no readable FMT message", file=str(p))
    lengths = np.zeros(256, dtype=np.int64)
    for t, f in formats.items():
        lengths[t] = f.length
    cand = heads[lengths[buf[heads + 2]] > 0]
    nxt = cand + lengths[buf[cand + 2]]
    j = np.searchsorted(cand, nxt)
    jc = np.minimum(j, len(cand) - 1)
    chained = (j < len(cand)) & (cand[jc] == nxt)
    # -1: chain breaks; -2: this message ends exactly at end of file; -3: it runs past the end
    next_idx = np.where(chained, j, np.where(nxt == n, -2, np.where(nxt > n, -3, -1)))
    good_start = next_idx != -1
    good_idx = np.flatnonzero(good_start)
    nxt_list = next_idx.tolist()
    on_chain = np.zeros(len(cand), dtype=bool)
    i, skipped = 0, 0
    end_pos = 0
    gaps: list[tuple[int, int]] = []  # (byte, bytes skipped) per chain break
    while True:
        k = nxt_list[i]
        if k >= 0:
            on_chain[i] = True
            i = k
            continue
        pos = int(cand[i])
        if k == -2:
            on_chain[i] = True
            end_pos = n
            break
        if k == -3:
            end_pos = pos
            warnings.append(
                f"corrupt tail: last message at byte {pos} truncated "
                f"({n - pos} of {int(lengths[buf[pos + 2]])} bytes); ignored"
            )
            break
        # The chain breaks after this message: keep it, resync on the next start that chains
        # (binary search over the chaining starts: linear overall however often it breaks).
        on_chain[i] = True
        after = pos + int(lengths[buf[pos + 2]])
        first = max(i + 1, int(np.searchsorted(cand, after)))
        g = int(np.searchsorted(good_idx, first))
        if g >= len(good_idx):
            end_pos = after
            warnings.append(
                f"corrupt tail: {n - after} bytes from byte {after} are not decodable; ignored"
            )
            break
        i = int(good_idx[g])
        skipped += int(cand[i]) - after
        gaps.append((after, int(cand[i]) - after))
    warnings[len(warnings) : len(warnings)] = _gap_warnings(gaps)
    starts_all = cand[on_chain]
    types = buf[starts_all + 2]
    order = np.argsort(types, kind="stable")
    sorted_types = types[order]
    bounds = np.flatnonzero(np.diff(sorted_types.astype(np.int16))) + 1
    starts: dict[int, npt.NDArray[np.int64]] = {}
    for chunk in np.split(order, bounds):
        if len(chunk):
            starts[int(types[chunk[0]])] = starts_all[chunk]
    for w in warnings:  # returned with the log and shown once by whoever reports it
        log.debug("%s: %s", p, w)
    return DataFlashLog(str(p), buf, formats, starts, warnings, bytes_decoded=end_pos - skipped)


def sniff(path: Path, head: bytes) -> bool:
    return len(head) >= 3 and head[0] == HEAD1 and head[1] == HEAD2 and head[2] == FMT_TYPE


# -- the flight-log view -------------------------------------------------------------------------


def _instance0(cols: dict[str, npt.NDArray[Any]]) -> npt.NDArray[np.bool_]:
    for key in ("I", "Instance", "Inst", "IMU"):
        if key in cols and len(cols[key]) and cols[key].dtype.kind in "iu":
            return np.asarray(cols[key] == 0)
    return np.ones(len(next(iter(cols.values()))), dtype=bool) if cols else np.zeros(0, bool)


def _events(
    df: DataFlashLog, notes: list[str] | None = None
) -> tuple[Signal | None, Signal | None]:
    """Armed and landed step signals from ARM / EV messages (what a rule did: ``notes``)."""
    if notes is None:
        notes = []
    armed: Signal | None = None
    landed: Signal | None = None
    if df.has("ARM"):
        c = df.columns("ARM")
        armed = sorted_signal(
            df.time_s("ARM"), c["ArmState"] != 0, "bool", "ARM.ArmState", state=True
        )
    if df.has("EV"):
        t, ids = df.time_s("EV"), np.asarray(df.columns("EV")["Id"], int)
        if armed is None:
            m = np.isin(ids, (EV_ARMED, EV_DISARMED))
            if m.any():
                armed = sorted_signal(
                    np.concatenate([[t[m][0] - 1e-3], t[m]]),
                    np.concatenate([[0.0], ids[m] == EV_ARMED]),
                    "bool",
                    "EV.Id 10 ARMED / 11 DISARMED",
                    state=True,
                )
        landed = land_state_from_events(t, ids, notes)  # rule ev-burst (copter_era)
    return armed, landed


#: ArduCopter FRAME_CLASS -> motor count (AP_Motors; single/coax/heli/scripting are not here)
FRAME_CLASS_MOTORS = {1: 4, 2: 6, 3: 8, 4: 8, 5: 6, 7: 3, 12: 12, 13: 4, 14: 10}
#: the frame name ArduCopter prints at boot ("Frame: QUAD", "Frame: HEXA/X") -> motor count
FRAME_NAME_MOTORS = {
    "QUAD": 4, "HEXA": 6, "OCTA": 8, "OCTAQUAD": 8, "OCTA_QUAD": 8, "Y6": 6, "TRI": 3,
    "DODECAHEXA": 12, "DODECA_HEXA": 12, "DECA": 10, "HELI_QUAD": 4,
}  # fmt: skip


def _motor_function(value: float) -> int | None:
    """Motor number (1-based) of an output function (SERVOn_FUNCTION / RCn_FUNCTION)."""
    f = int(value)
    if 33 <= f <= 40:
        return f - 32  # k_motor1..k_motor8
    if 82 <= f <= 85:
        return f - 73  # k_motor9..k_motor12
    return None


def _rcou_column(rcou: dict[str, npt.NDArray[Any]], channel: int) -> str | None:
    return next((c for c in (f"C{channel}", f"Ch{channel}") if c in rcou), None)


def motor_layout(params: dict[str, float], messages: list[str]) -> tuple[list[int], str] | None:
    """Output channels (1-based, in motor order) that drive motors, from the log's own
    parameters: SERVOn_FUNCTION 33..40/82..85, else the frame (FRAME_CLASS, or the 'Frame:' line
    Copter 3.4+ prints at boot) on outputs 1..N unless an RCn_FUNCTION gives the output to
    something else. None when the log does not say (Copter <= 3.3)."""
    funcs = {int(k[5:-9]): v for k, v in params.items() if re.fullmatch(r"SERVO\d+_FUNCTION", k)}
    motors = {m: ch for ch, v in funcs.items() if (m := _motor_function(v)) is not None}
    if motors:
        return [motors[m] for m in sorted(motors)], "SERVOn_FUNCTION 33..40 (motor1..motor8)"
    count: int | None = None
    how = ""
    fc = params.get("FRAME_CLASS")
    if fc is not None and int(fc) in FRAME_CLASS_MOTORS:
        count, how = FRAME_CLASS_MOTORS[int(fc)], f"FRAME_CLASS {int(fc)}"
    else:
        for text in messages:
            hit = re.match(r"Frame: ?([A-Z0-9_]+)", text)
            if hit and hit.group(1) in FRAME_NAME_MOTORS:
                count, how = FRAME_NAME_MOTORS[hit.group(1)], f"'{text.strip()}' (boot message)"
                break
    if count is None:
        return None
    old = {int(k[2:-9]): v for k, v in params.items() if re.fullmatch(r"RC\d+_FUNCTION", k)}
    chans = [ch for ch in range(1, 17) if not old.get(ch) or _motor_function(old[ch])][:count]
    return chans, f"{how}: {count} motors on outputs {','.join(map(str, chans))}"


def _motor_channels(rcou: dict[str, npt.NDArray[Any]], active: npt.NDArray[np.bool_]) -> list[str]:
    """Fallback when the log names no frame: consecutive outputs from 1, PWM-like and moving."""
    names = [c for c in rcou if c.startswith(("C", "Ch")) and c.lstrip("Ch").isdigit()]
    names.sort(key=lambda c: int(c.lstrip("Ch")))
    chosen: list[str] = []
    for c in names:
        v = np.asarray(rcou[c], float)[active] if active.any() else np.asarray(rcou[c], float)
        if len(v) and 800 <= float(nanmedian(v)) <= 2200 and float(np.std(v)) > 0.5:
            chosen.append(c)
        else:
            break
    return chosen


def pwm_scale(params: dict[str, float]) -> tuple[ThrottleScale, str]:
    """The ESC range ArduCopter outputs: MOT_PWM_MIN/MAX, or the throttle channel's RC3_MIN/MAX
    when those are 0 (as the firmware does); 1000..2000 only when the log has neither."""
    lo, hi = params.get("MOT_PWM_MIN", 0.0), params.get("MOT_PWM_MAX", 0.0)
    if lo > 0 and hi > lo:
        src = f"MOT_PWM_MIN/MAX {lo:g}..{hi:g} us"
    else:
        lo, hi = params.get("RC3_MIN", 0.0), params.get("RC3_MAX", 0.0)
        src = f"RC3_MIN/MAX {lo:g}..{hi:g} us (MOT_PWM_MIN/MAX unset)"
        if not (lo > 0 and hi > lo):
            lo, hi, src = (
                1000.0,
                2000.0,
                "assumed 1000..2000 us (no MOT_PWM_MIN/MAX or RC3_MIN/MAX)",
            )
    spin = params.get("MOT_SPIN_MIN")
    if spin is not None:
        src += f"; MOT_SPIN_MIN {spin:g} (idle in flight = {lo + spin * (hi - lo):.0f} us)"
    return ThrottleScale("pwm", float(lo), float(hi), "us"), src


def read(path: Path, *, motor_channels: list[str] | None = None, **_: Any) -> list[FlightLog]:
    df = parse(path)
    flight = FlightLog(path=str(path), format="dataflash", warnings=list(df.warnings))
    params = df.params()
    msgs = df.text_messages()
    flight.metadata.update(
        {
            "firmware": next((m for m in msgs if m.startswith(("APM:", "Ardu"))), None),
            "message_counts": df.counts(),
            "bytes_decoded": df.bytes_decoded,
        }
    )
    _voltage(df, flight)
    _accel_up(df, flight)
    pilot_in = _ctun(df, flight)
    _range_finder(df, flight)
    _attitude(df, flight)
    flight.armed, flight.landed = _events(df, flight.warnings)
    _motor_outputs(df, flight, params, msgs, motor_channels)
    _finish(df, flight, params, pilot_in)
    return [flight]


def _voltage(df: DataFlashLog, flight: FlightLog) -> None:
    """The battery voltage: BAT.Volt (V), old firmware CURR.Volt (centivolts, int16)."""
    if df.has("BAT"):
        c = df.columns("BAT")
        keep = _instance0(c)
        flight.voltage_v = sorted_signal(df.time_s("BAT")[keep], c["Volt"][keep], "V", "BAT.Volt")
    elif df.has("CURR"):
        c = df.columns("CURR")
        volt = np.asarray(c["Volt"], float)
        fmt = df.by_name["CURR"].format[df.by_name["CURR"].columns.index("Volt")]
        if fmt in "hHiI":  # integer centivolts; 'c'/'f' forms are already volts
            volt = volt / 100.0
        sensed = volt > 0.5  # 0 V: no voltage sensor connected (or not yet read)
        if sensed.any():
            flight.voltage_v = sorted_signal(
                df.time_s("CURR")[sensed], volt[sensed], "V", "CURR.Volt"
            )
        else:
            flight.warnings.append("CURR.Volt reads 0 V throughout: no battery voltage sensed")
    else:
        flight.warnings.append("no BAT or CURR messages: no battery voltage")


def _accel_up(df: DataFlashLog, flight: FlightLog) -> None:
    """The upward specific force: -IMU.AccZ (FRD body frame), first IMU only."""
    if df.has("IMU"):
        c = df.columns("IMU")
        keep = _instance0(c)
        flight.accel_up_mps2 = sorted_signal(
            df.time_s("IMU")[keep], -np.asarray(c["AccZ"], float)[keep], "m/s^2", "-IMU.AccZ"
        )


def _ctun(df: DataFlashLog, flight: FlightLog) -> Signal | None:
    """CTUN: the collective throttle 0..1 (ThO; older ThrOut 0..1000), the hover throttle, the
    height above home and climb rate (in-air evidence); returns the pilot's throttle (ThrIn,
    Copter <= 3.3) when logged."""
    # collective throttle 0..1: CTUN.ThO (older ThrOut 0..1000)
    if not df.has("CTUN"):
        return None
    pilot_in: Signal | None = None
    c = df.columns("CTUN")
    t = df.time_s("CTUN")
    if "ThO" in c:
        flight.thrust_cmd_norm = sorted_signal(t, c["ThO"], "1", "CTUN.ThO")
    elif "ThrOut" in c:
        flight.thrust_cmd_norm = sorted_signal(
            t, np.asarray(c["ThrOut"], float) / 1000.0, "1", "CTUN.ThrOut/1000"
        )
    if "ThrIn" in c:  # the pilot's throttle (rc_3.control_in, 0..1000), Copter <= 3.3
        pilot_in = sorted_signal(t, c["ThrIn"], "1", "CTUN.ThrIn")
    if "ThH" in c:
        flight.extras["hover_throttle"] = sorted_signal(t, c["ThH"], "1", "CTUN.ThH")
    # in-air evidence: altitude above home (set at arming, m) and climb rate (cm/s)
    if "Alt" in c:
        flight.extras["height_m"] = sorted_signal(t, c["Alt"], "m", "CTUN.Alt (above home)")
    if "CRt" in c:
        crt = np.asarray(c["CRt"], float)
        flight.extras["climb_mps"] = sorted_signal(t, crt / 100.0, "m/s", "CTUN.CRt/100")
        if "Alt" in c:
            climb_from_altitude(flight, t, crt / 100.0, np.asarray(c["Alt"], float))
    baro_col = next((k for k in ("BarAlt", "BAlt") if k in c), None)
    if "Alt" in c and baro_col is not None:
        inertial_or_baro(flight, t, np.asarray(c["Alt"], float),
                          np.asarray(c[baro_col], float), f"CTUN.{baro_col}")  # fmt: skip
    return pilot_in


def _range_finder(df: DataFlashLog, flight: FlightLog) -> None:
    """The range finder: Dist (m, Stat 4 = good) or older Dist1 (cm)."""
    if df.has("RFND"):  # range finder: Dist (m, Stat 4 = good) or older Dist1 (cm)
        c = df.columns("RFND")
        keep = _instance0(c)
        t = df.time_s("RFND")[keep]
        if "Dist" in c:
            dist = np.asarray(c["Dist"], float)[keep]
            good = np.asarray(c["Stat"])[keep] == 4 if "Stat" in c else dist > 0
            origin = "RFND.Dist (Stat 4 good only)" if "Stat" in c else "RFND.Dist"
        elif "Dist1" in c:
            dist = np.asarray(c["Dist1"], float)[keep] / 100.0
            good, origin = dist > 0, "RFND.Dist1/100"
        else:
            dist = np.zeros(0)
            good, origin = np.zeros(0, bool), ""
        if good.any():
            flight.extras["range_m"] = sorted_signal(t, np.where(good, dist, np.nan), "m", origin)


def _attitude(df: DataFlashLog, flight: FlightLog) -> None:
    """The tilt from ATT.Roll/Pitch, and MOTB.BatVolt (the motors' voltage compensation)."""
    if df.has("ATT"):
        c = df.columns("ATT")
        r, p = np.radians(np.asarray(c["Roll"], float)), np.radians(np.asarray(c["Pitch"], float))
        tilt = np.degrees(np.arccos(np.clip(np.cos(r) * np.cos(p), -1.0, 1.0)))
        flight.extras["tilt_deg"] = sorted_signal(df.time_s("ATT"), tilt, "deg", "ATT.Roll/Pitch")
    if df.has("MOTB"):
        c = df.columns("MOTB")
        flight.extras["motb_batvolt"] = sorted_signal(
            df.time_s("MOTB"), c["BatVolt"], "1", "MOTB.BatVolt"
        )


def _motor_outputs(
    df: DataFlashLog,
    flight: FlightLog,
    params: dict[str, float],
    msgs: list[str],
    motor_channels: list[str] | None,
) -> None:
    """The motor outputs from RCOU: the channels given, else the frame's, else the leading
    outputs that move while armed; their PWM scale."""
    if df.has("RCOU"):
        c = df.columns("RCOU")
        t = df.time_s("RCOU")
        active = flight.armed.hold(t) > 0.5 if flight.armed is not None else np.ones(len(t), bool)
        layout = None if motor_channels else motor_layout(params, msgs)
        how = "given"
        if motor_channels:
            chans = list(motor_channels)
        elif layout is not None:
            chans = [col for ch in layout[0] if (col := _rcou_column(c, ch)) is not None]
            how = layout[1]
            if len(chans) < len(layout[0]):
                flight.warnings.append(f"{how}, but RCOU lacks some of those outputs")
        else:
            chans = _motor_channels(c, active)
            how = "no frame class in the log: leading outputs that move while armed"
            flight.warnings.append(
                "the log names no frame (FRAME_CLASS, SERVOn_FUNCTION, 'Frame:' message): motors "
                f"taken as the leading moving outputs ({', '.join(chans)}); check --rotors"
            )
        if chans:
            outs = np.stack([np.asarray(c[ch], float) for ch in chans], axis=1)
            flight.motor_outputs = sorted_signal(t, outs, "us", "RCOU." + ",".join(chans))
            flight.motor_output_scale, scale_src = pwm_scale(params)
            flight.metadata["motor_channels"] = how
            flight.metadata["motor_output_scale_source"] = scale_src
            allc = sorted(
                (k for k in c if re.fullmatch(r"Ch?\d+", k)), key=lambda k: int(k.lstrip("Ch"))
            )
            flight.extras["outputs_all"] = sorted_signal(
                t, np.stack([np.asarray(c[k], float) for k in allc], axis=1), "us",
                "RCOU." + ",".join(allc),
            )  # fmt: skip
        else:
            flight.warnings.append("no RCOU channel looks like a motor output")


def _finish(
    df: DataFlashLog, flight: FlightLog, params: dict[str, float], pilot_in: Signal | None
) -> None:
    """Untimed events, the parameters kept, and what is missing."""
    ev = df.by_name.get("EV")
    ev_untimed = ev is not None and df.has("EV") and not {"TimeUS", "TimeMS"} & set(ev.columns)
    cmd = flight.thrust_cmd_norm
    untimed_events(
        flight, params, ev_untimed=ev_untimed,
        throttle=cmd if cmd is not None and cmd.origin.startswith("CTUN.ThrOut") else None,
        pilot_throttle=pilot_in,
    )  # fmt: skip
    flight.metadata["params"] = {
        k: v for k, v in params.items() if k.startswith(("MOT_", "RC3_", "FRAME", "BATT_"))
    }
    if flight.accel_up_mps2 is None or flight.voltage_v is None:
        missing = [
            n
            for n, s in (
                ("IMU", flight.accel_up_mps2),
                ("battery voltage (BAT/CURR)", flight.voltage_v),
            )
            if s is None
        ]
        flight.warnings.append(f"missing {', '.join(missing)} messages")
