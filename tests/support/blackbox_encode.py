"""A small blackbox *encoder* for the subset :mod:`blackbox_decode` reads, plus a simulated hover
flight — so the project can generate its own .bbl fixtures with known values (and round-trip
every encoding and predictor in tests).

Encodings: signed/unsigned variable byte, negative 14-bit, tag8_8svb, tag2_3s32, tag8_4s16
(data version 2), null. Predictors: zero, previous, straight line, average of two, minthrottle,
motor[0], increment, 1500, vbatref, minmotor. Events: sync beep, disarm, flight mode, log end.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import thrustmap.flightlogs.blackbox_format as blackbox_format
from thrustmap.flightlogs import blackbox_decode as bd


def uvb(value: int) -> bytes:
    value &= 0xFFFFFFFF
    out = bytearray()
    while value >= 0x80:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def svb(value: int) -> bytes:
    return uvb((value << 1) if value >= 0 else ((-value) << 1) - 1)


def _fits(value: int, bits: int) -> bool:
    return -(1 << (bits - 1)) <= value < (1 << (bits - 1))


def tag8_8svb(values: Sequence[int]) -> bytes:
    if len(values) == 1:
        return svb(values[0])
    header = sum(1 << i for i, v in enumerate(values) if v != 0)
    return bytes([header]) + b"".join(svb(v) for v in values if v != 0)


def tag2_3s32(values: Sequence[int]) -> bytes:
    a, b, c = values
    if all(_fits(v, 2) for v in values):
        return bytes([((a & 3) << 4) | ((b & 3) << 2) | (c & 3)])
    if all(_fits(v, 4) for v in values):
        return bytes([0x40 | (a & 0xF), ((b & 0xF) << 4) | (c & 0xF)])
    if all(_fits(v, 6) for v in values):
        return bytes([0x80 | (a & 0x3F), b & 0x3F, c & 0x3F])
    lead = 0xC0
    body = bytearray()
    for i, v in enumerate(values):
        nbytes = next(n for n in (1, 2, 3, 4) if _fits(v, 8 * n))
        lead |= (nbytes - 1) << (2 * i)
        body += (v & ((1 << (8 * nbytes)) - 1)).to_bytes(nbytes, "little")
    return bytes([lead]) + bytes(body)


def tag8_4s16(values: Sequence[int]) -> bytes:
    selector = 0
    nibbles: list[int] = []
    for i, v in enumerate(values):
        if v == 0:
            kind = 0
        elif _fits(v, 4):
            kind = 1
            nibbles.append(v & 0xF)
        elif _fits(v, 8):
            kind = 2
            nibbles += [(v >> 4) & 0xF, v & 0xF]
        elif _fits(v, 16):
            kind = 3
            nibbles += [(v >> 12) & 0xF, (v >> 8) & 0xF, (v >> 4) & 0xF, v & 0xF]
        else:
            raise ValueError(f"tag8_4s16 value {v} does not fit 16 bits")
        selector |= kind << (2 * i)
    if len(nibbles) % 2:
        nibbles.append(0)
    return bytes([selector]) + bytes(
        (nibbles[k] << 4) | nibbles[k + 1] for k in range(0, len(nibbles), 2)
    )


@dataclass
class Encoder:
    """Writes one log: header lines, then frames whose predictions mirror the decoder's."""

    headers: list[tuple[str, str]]  # plain header lines (not the field definitions)
    idef: blackbox_format.FrameDef
    p_predictor: list[int]
    p_encoding: list[int]
    sdef: blackbox_format.FrameDef | None = None
    gdef: blackbox_format.FrameDef | None = (
        None  # GPS frames (time from the last main frame, home coords)
    )
    hdef: blackbox_format.FrameDef | None = None  # GPS-home frames

    def __post_init__(self) -> None:
        hd = dict(self.headers)
        minthrottle = blackbox_format.header_int(hd, "minthrottle", 1150)
        self.constants = {
            "minthrottle": minthrottle,
            "vbatref": blackbox_format.header_int(hd, "vbatref", 4095),
            "motor_low": blackbox_format.header_int(hd, "motorOutput", minthrottle, 0),
        }
        self.i_interval = max(blackbox_format.header_int(hd, "I interval", 32), 1)
        self.skip = blackbox_format.p_skip_counts(self.i_interval, *blackbox_format.p_interval(hd))
        self.motor0 = self.idef.names.index("motor[0]") if "motor[0]" in self.idef.names else -1
        self.prev: list[int] | None = None
        self.prev2: list[int] | None = None
        self.last_time = -1  # the last main frame's time, or a logging-resume event's
        self.home = [0, 0]

    def header_bytes(self) -> bytes:
        def line(k: str, v: str) -> bytes:
            return f"H {k}:{v}\n".encode("latin-1")

        def ints(xs: Sequence[int]) -> str:
            return ",".join(str(x) for x in xs)

        out = bytearray(line("Product", "Blackbox flight data recorder by Nicholas Sherlock"))
        out += line("Data version", "2")
        out += line("Field I name", ",".join(self.idef.names))
        out += line("Field I signed", ints(self.idef.signed))
        out += line("Field I predictor", ints(self.idef.predictor))
        out += line("Field I encoding", ints(self.idef.encoding))
        out += line("Field P predictor", ints(self.p_predictor))
        out += line("Field P encoding", ints(self.p_encoding))
        for marker, fd in (("H", self.hdef), ("G", self.gdef), ("S", self.sdef)):
            if fd is not None:
                out += line(f"Field {marker} name", ",".join(fd.names))
                out += line(f"Field {marker} signed", ints(fd.signed))
                out += line(f"Field {marker} predictor", ints(fd.predictor))
                out += line(f"Field {marker} encoding", ints(fd.encoding))
        for k, v in self.headers:
            out += line(k, v)
        return bytes(out)

    def _predict(self, i: int, pred: int, cur: list[int], prev: list[int], prev2: list[int]) -> int:
        c = self.constants
        if pred == blackbox_format.PRED_ZERO:
            return 0
        if pred == blackbox_format.PRED_PREVIOUS:
            return prev[i]
        if pred == blackbox_format.PRED_STRAIGHT_LINE:
            return 2 * prev[i] - prev2[i]
        if pred == blackbox_format.PRED_AVERAGE_2:
            s = prev[i] + prev2[i]
            return (s + (s < 0)) >> 1
        if pred == blackbox_format.PRED_MINTHROTTLE:
            return c["minthrottle"]
        if pred == blackbox_format.PRED_MOTOR_0:
            return cur[self.motor0]
        if pred == blackbox_format.PRED_1500:
            return 1500
        if pred == blackbox_format.PRED_VBATREF:
            return c["vbatref"]
        if pred == blackbox_format.PRED_MINMOTOR:
            return c["motor_low"]
        if pred == blackbox_format.PRED_HOME_COORD:
            return self.home[0]
        if pred == blackbox_format.PRED_HOME_COORD_1:
            return self.home[1]
        if pred == blackbox_format.PRED_LAST_MAIN_FRAME_TIME:
            return self.last_time
        raise ValueError(f"encoder does not support predictor {pred}")

    def _frame(
        self,
        values: Sequence[int],
        fd: blackbox_format.FrameDef,
        predictor: list[int],
        encoding: list[int],
        prev: list[int],
        prev2: list[int],
        skipped: int,
    ) -> bytes:
        cur = list(values)
        n = len(fd.names)
        predictor = list(predictor)
        for i in range(1, n):  # home coordinates: (lat, lon) pairs sharing one predictor id
            if (
                predictor[i - 1] == blackbox_format.PRED_HOME_COORD
                and predictor[i] == blackbox_format.PRED_HOME_COORD
            ):
                predictor[i] = blackbox_format.PRED_HOME_COORD_1
        res: list[int] = []
        for i in range(n):
            if predictor[i] == blackbox_format.PRED_INC:
                if cur[i] != prev[i] + skipped + 1:
                    raise ValueError(f"{fd.names[i]} must be {prev[i] + skipped + 1}")
                res.append(0)
                continue
            r = cur[i] - self._predict(i, predictor[i], cur, prev, prev2)
            if fd.signed and fd.signed[i]:
                r = ((r + 0x80000000) & 0xFFFFFFFF) - 0x80000000
            res.append(r)
        out = bytearray()
        i = 0
        while i < n:
            e = encoding[i]
            if predictor[i] == blackbox_format.PRED_INC:
                i += 1
            elif e == blackbox_format.ENC_SIGNED_VB:
                out += svb(res[i])
                i += 1
            elif e == blackbox_format.ENC_UNSIGNED_VB:
                out += uvb(res[i])
                i += 1
            elif e == blackbox_format.ENC_NEG_14BIT:
                out += uvb((-res[i]) & 0x3FFF)
                i += 1
            elif e == blackbox_format.ENC_NULL:
                if res[i] != 0:
                    raise ValueError(
                        f"{fd.names[i]} has null encoding but differs from its prediction"
                    )
                i += 1
            elif e == blackbox_format.ENC_TAG8_8SVB:
                j = i + 1
                while j < min(i + 8, n) and encoding[j] == blackbox_format.ENC_TAG8_8SVB:
                    j += 1
                out += tag8_8svb(res[i:j])
                i = j
            elif e == blackbox_format.ENC_TAG2_3S32:
                out += tag2_3s32((res[i : i + 3] + [0, 0, 0])[:3])
                i += 3
            elif e == blackbox_format.ENC_TAG8_4S16:
                out += tag8_4s16((res[i : i + 4] + [0, 0, 0, 0])[:4])
                i += 4
            else:
                raise ValueError(f"encoder does not support encoding {e}")
        return bytes(out)

    def i_frame(self, values: Sequence[int]) -> bytes:
        zeros = [0] * len(self.idef.names)
        body = self._frame(
            values, self.idef, self.idef.predictor, self.idef.encoding, zeros, zeros, 0
        )
        self.prev = self.prev2 = list(values)
        self.last_time = values[1]
        return b"I" + body

    def p_frame(self, values: Sequence[int]) -> bytes:
        if self.prev is None or self.prev2 is None:
            raise ValueError("a P frame needs a preceding I frame")
        skipped = self.skip[self.prev[0] % self.i_interval]
        body = self._frame(
            values, self.idef, self.p_predictor, self.p_encoding, self.prev, self.prev2, skipped
        )
        self.prev2, self.prev = self.prev, list(values)
        self.last_time = values[1]
        return b"P" + body

    def s_frame(self, values: Sequence[int]) -> bytes:
        if self.sdef is None:
            raise ValueError("no slow-frame definition")
        zeros = [0] * len(self.sdef.names)
        return b"S" + self._frame(
            values, self.sdef, self.sdef.predictor, self.sdef.encoding, zeros, zeros, 0
        )

    def g_frame(self, values: Sequence[int]) -> bytes:
        """A GPS frame: its time relative to the last main frame, its coordinates to home."""
        if self.gdef is None:
            raise ValueError("no GPS-frame definition")
        zeros = [0] * len(self.gdef.names)
        return b"G" + self._frame(
            values, self.gdef, self.gdef.predictor, self.gdef.encoding, zeros, zeros, 0
        )

    def h_frame(self, values: Sequence[int]) -> bytes:
        """A GPS-home frame (GPS_home[0], GPS_home[1]): later GPS frames are relative to it."""
        if self.hdef is None:
            raise ValueError("no GPS-home-frame definition")
        zeros = [0] * len(self.hdef.names)
        out = b"H" + self._frame(
            values, self.hdef, self.hdef.predictor, self.hdef.encoding, zeros, zeros, 0
        )
        self.home = [int(values[0]), int(values[1])]
        return out

    def event(self, kind: int, *args: int) -> bytes:
        if kind == blackbox_format.EVENT_LOGGING_RESUME:
            self.last_time = args[1]
        if kind == blackbox_format.EVENT_LOG_END:
            return b"E\xff" + blackbox_format.END_OF_LOG_TEXT
        return b"E" + bytes([kind]) + b"".join(uvb(a) for a in args)


# --- a simulated hover flight --------------------------------------------------------------

SIM_MAIN = blackbox_format.FrameDef(
    names=[
        "loopIteration",
        "time",
        "rcCommand[0]",
        "rcCommand[1]",
        "rcCommand[2]",
        "rcCommand[3]",
        "vbatLatest",
        "amperageLatest",
        "gyroADC[0]",
        "gyroADC[1]",
        "gyroADC[2]",
        "accSmooth[0]",
        "accSmooth[1]",
        "accSmooth[2]",
        "motor[0]",
        "motor[1]",
        "motor[2]",
        "motor[3]",
    ],  # fmt: skip
    signed=[0, 0, 1, 1, 1, 0, 0, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0],
    predictor=[0, 0, 0, 0, 0, 0, 9, 0, 0, 0, 0, 0, 0, 0, 11, 5, 5, 5],
    encoding=[1, 1, 0, 0, 0, 1, 3, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0],
)
SIM_P_PREDICTOR = [6, 2, 1, 1, 1, 1, 1, 1, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3]
SIM_P_ENCODING = [9, 0, 8, 8, 8, 8, 6, 6, 7, 7, 7, 0, 0, 0, 0, 0, 0, 0]
SIM_SLOW = blackbox_format.FrameDef(
    names=["flightModeFlags", "stateFlags", "failsafePhase", "rxSignalReceived"],
    signed=[0, 0, 0, 0],
    predictor=[0, 0, 0, 0],
    encoding=[1, 1, 7, 7],
)
#: GPS frames as Betaflight 4.2 logs them (time from the last main frame, coordinates from home)
SIM_GPS = blackbox_format.FrameDef(
    names=["time", "GPS_numSat", "GPS_coord[0]", "GPS_coord[1]", "GPS_altitude", "GPS_speed",
           "GPS_ground_course"],
    signed=[0, 0, 1, 1, 0, 0, 0],
    predictor=[10, 0, 7, 7, 0, 0, 0],
    encoding=[1, 1, 0, 0, 1, 1, 1],
)  # fmt: skip
SIM_GPS_HOME = blackbox_format.FrameDef(
    names=["GPS_home[0]", "GPS_home[1]"], signed=[1, 1], predictor=[0, 0], encoding=[0, 0]
)
SIM_HEADERS = [
    ("Firmware type", "Cleanflight"),
    ("Firmware revision", "Betaflight 4.2.8 (thrustmap-sim) SIM"),
    ("Craft name", "thrustmap-sim"),
    ("I interval", "256"),
    ("P interval", "32"),
    ("P ratio", "8"),
    ("minthrottle", "1070"),
    ("maxthrottle", "2000"),
    ("motorOutput", "158,2047"),
    ("acc_1G", "2048"),
    ("vbatcellvoltage", "330,350,430"),
    ("vbatref", "1650"),
    ("looptime", "125"),
    ("motor_pwm_protocol", "7"),
]
SIM_LOOPTIME_US = 125
SIM_P_INTERVAL = 32  # one logged frame every 32 loops: 250 Hz


def sim_frame_values(
    k: int, start_iteration: int, start_time_us: int, duration_s: float
) -> list[int]:
    """The known values of main frame ``k`` of a simulated hover (integers, firmware units)."""
    it = start_iteration + SIM_P_INTERVAL * k
    t_us = start_time_us + SIM_P_INTERVAL * SIM_LOOPTIME_US * k
    frac = (SIM_P_INTERVAL * SIM_LOOPTIME_US * k) / (duration_s * 1e6)
    vbat = 1640 - round(40 * frac)  # 16.40 V -> 16.00 V
    wobble = round(30 * math.sin(2 * math.pi * 2.0 * k / 250))
    acc_z = 2048 + wobble  # 1 g hover with a 2 Hz ripple
    motors = [880 + wobble + 7 * m for m in range(4)]
    throttle = 1500 + (k % 5) - 2
    return [
        it, t_us, (k % 7) - 3, 2 - (k % 5), 0, throttle,
        vbat, 1234 + (k % 11), wobble // 3, -wobble // 4, 5,
        12, -20, acc_z, *motors,
    ]  # fmt: skip


#: INAV 8 as it writes its headers (blackbox.c): "Firmware type" still says Cleanflight, the
#: revision says INAV; motor[] in µs-equivalent (mincommand 1000 .. maxthrottle), the idle as
#: motorOutput's low end; motor_pwm_protocol 6 (DShot); battery fields named vbat, amperage.
INAV_HEADERS = [
    ("Firmware type", "Cleanflight"),
    ("Firmware revision", "INAV 8.0.1 (thrustmap-sim) SIM"),
    ("Craft name", ""),
    ("I interval", "256"),
    ("P interval", "32"),
    ("P ratio", "8"),
    ("minthrottle", "1100"),
    ("maxthrottle", "2000"),
    ("motorOutput", "1100,2000"),
    ("acc_1G", "2048"),
    ("vbat_scale", "110"),
    ("vbatcellvoltage", "33,35,42"),
    ("vbatref", "1650"),
    ("looptime", "125"),
    ("acc_hardware", "8"),
    ("motor_pwm_protocol", "6"),
]
INAV_MAIN = blackbox_format.FrameDef(
    names=["vbat" if n == "vbatLatest" else "amperage" if n == "amperageLatest" else n
           for n in SIM_MAIN.names],
    signed=SIM_MAIN.signed,
    predictor=[4 if n == "motor[0]" else p for n, p in zip(SIM_MAIN.names, SIM_MAIN.predictor, strict=True)],
    encoding=SIM_MAIN.encoding,
)  # fmt: skip
#: INAV's hover in the simulated log: motor[] 1500 µs-equivalent = 50 % of 1000..2000
INAV_HOVER_MOTOR = 1500


def simulate_hover_log(
    duration_s: float,
    *,
    start_iteration: int = 4096,
    start_time_us: int = 5_000_000,
    acc_scale: float = 1.0,
    inav: bool = False,
    headers: Sequence[tuple[str, str]] = (),
) -> bytes:
    """One armed hover log at 250 Hz ending with a disarm and the log-end event.

    ``acc_scale`` multiplies the accelerometer (0: an accelerometer that reads zero, -1: a
    downward axis); ``inav`` writes the log as INAV 8 does (its headers, field names and motor
    units); ``headers`` are added to (or replace) the header lines."""
    base = INAV_HEADERS if inav else SIM_HEADERS
    extra = dict(headers)
    hdrs = [(k, extra.pop(k, v)) for k, v in base] + list(extra.items())
    enc = Encoder(hdrs, INAV_MAIN if inav else SIM_MAIN, SIM_P_PREDICTOR, SIM_P_ENCODING,
                  SIM_SLOW)  # fmt: skip
    out = bytearray(enc.header_bytes())
    out += enc.event(blackbox_format.EVENT_SYNC_BEEP, start_time_us - 1000)
    out += enc.s_frame([1, 0, 0, 1])  # ARM box active
    n = round(duration_s * 1e6 / (SIM_P_INTERVAL * SIM_LOOPTIME_US))
    frames_per_i = 256 // SIM_P_INTERVAL
    for k in range(n):
        values = sim_frame_values(k, start_iteration, start_time_us, duration_s)
        values[11:14] = [round(v * acc_scale) for v in values[11:14]]
        if inav:  # the mixer's µs-equivalent output, not DShot values
            values[14:18] = [v - 880 + INAV_HOVER_MOTOR for v in values[14:18]]
        out += enc.i_frame(values) if k % frames_per_i == 0 else enc.p_frame(values)
    out += enc.event(blackbox_format.EVENT_DISARM, 4)
    out += enc.s_frame([0, 0, 0, 1])
    out += enc.event(blackbox_format.EVENT_LOG_END)
    return bytes(out)


def simulate_hover_file(
    durations_s: Sequence[float] = (4.0, 3.0), acc_scales: Sequence[float] = ()
) -> bytes:
    """A file with one log per duration (each an armed hover; several flights in one file);
    ``acc_scales`` (one per log, default 1) as ``simulate_hover_log`` takes it. A duration of
    0 is an empty log (headers, then the log end at once), as flash chips hold them."""
    scales = list(acc_scales) + [1.0] * (len(durations_s) - len(acc_scales))
    return b"".join(
        simulate_hover_log(
            d, start_iteration=4096 * (i + 1), start_time_us=5_000_000 * (i + 1), acc_scale=a
        )
        for i, (d, a) in enumerate(zip(durations_s, scales, strict=True))
    )


# --- blackbox_decode-style CSV ----------------------------------------------------------------

_MODE_NAMES = [
    "ANGLE_MODE", "HORIZON_MODE", "MAG", "BARO", "GPS_HOME", "GPS_HOLD", "HEADFREE", "UNUSED",
    "PASSTHRU", "RANGEFINDER_MODE", "FAILSAFE_MODE",
]  # fmt: skip


def decode_csv_text(decoded: blackbox_format.DecodedLog) -> str:
    """What the official blackbox_decode (default units, firmware < 4.3) writes for a log."""
    names = decoded.main_fields
    unit = {"time": "us", "vbatLatest": "V", "amperageLatest": "A"}
    slow_unit = {"flightModeFlags": "flags", "stateFlags": "flags", "failsafePhase": "flags"}
    cols = [f"{n} ({unit[n]})" if n in unit else n for n in names]
    cols += [f"{n} ({slow_unit[n]})" if n in slow_unit else n for n in decoded.slow_fields]
    lines = [", ".join(cols)]
    slow = [0] * len(decoded.slow_fields)
    next_slow = 0
    for k, row in enumerate(decoded.main.tolist()):
        while next_slow < len(decoded.slow) and decoded.slow_frame_index[next_slow] <= k:
            slow = decoded.slow[next_slow].tolist()
            next_slow += 1
        cells = []
        for n, v in zip(names, row, strict=True):
            if n == "vbatLatest":
                cells.append(f"{v / 10:.1f}")
            elif n == "amperageLatest":
                cells.append(f"{v / 100:.2f}")
            else:
                cells.append(f"{v:3d}")
        for n, v in zip(decoded.slow_fields, slow, strict=True):
            if n == "flightModeFlags":
                flags = [name for i, name in enumerate(_MODE_NAMES) if v & (1 << i)]
                cells.append("|".join(flags) or "0")
            elif n == "failsafePhase":
                cells.append(["IDLE", "RX_LOSS_DETECTED", "LANDING", "LANDED"][v])
            else:
                cells.append(str(v))
        lines.append(", ".join(cells))
    return "\n".join(lines) + "\n"


def headers_csv_text(decoded: blackbox_format.DecodedLog) -> str:
    """blackbox_decode --save-headers output for a log."""
    rows = ["fieldname, fieldvalue"] + [f'{k},"{v}"' for k, v in decoded.headers.items()]
    return "\n".join(rows) + "\n"


FIXTURE_FILES = (
    "bb_hover_sim.bbl",
    "bb_hover_sim.01.csv",
    "bb_hover_sim.01.headers.csv",
    "bb_hover_sim_bare.csv",
)


def write_fixtures(directory: str) -> list[str]:
    """(Re)generate the project's blackbox fixtures: a two-flight .bbl and CSVs of it."""
    from pathlib import Path

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    data = simulate_hover_file()
    logs = bd.decode_file(data)
    texts: dict[str, bytes] = {
        FIXTURE_FILES[0]: data,
        FIXTURE_FILES[1]: decode_csv_text(logs[0]).encode(),
        FIXTURE_FILES[2]: headers_csv_text(logs[0]).encode(),
        FIXTURE_FILES[3]: decode_csv_text(logs[1]).encode(),
    }
    for name, content in texts.items():
        (out / name).write_bytes(content)
    return [str(out / n) for n in texts]
