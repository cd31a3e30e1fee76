"""Byte-level simulators of three DIY stand firmwares, written from their source (the presets in
``protocols/stands/presets`` cite the lines): what each prints, at its rate, and what it does
with what it receives. ``sim://line-stand?preset=<name>`` picks one when it exists.

- :class:`EinszWhoopPeer` (einsz/whoop_thrust_stand): ``#INIT``/banner/``#COLS`` and
  ``SYSTEM_READY`` at boot, ``D,...`` rows of 23 fields at 10 Hz, a bare percent, ``DSHOT,v``,
  ``STOP``, ``TARE``, ``ID``; ``PING`` arms the 1 s watchdog (``#WD,armed``), which stops a
  turning motor and prints ``#WARN,watchdog_timeout``; unknown lines are ignored. The DShot
  value is ``map(pct, 1, 100, 1, 2000)`` and the plant sees ``dshot / 2000``. Its own ``SWEEP``
  (the idle hunt, 1 % steps up and down with 250 Hz rows, the logged ramp down, ``END_SWEEP``;
  ``STOP`` or the watchdog abort it) is simulated; its other programs answer ``#ERROR``.
- :class:`MqtbPeer` (VirtualEnder/TestStandv2): the menu, ``Input: ...``; ``s`` runs the
  stepping program (2 s, header, 250 Hz rows of a 27 s ramp 1100-2000-1100 µs); any byte
  ends it (1000 µs, menu again); ``t`` tares. Thrust in whole grams, as ``int`` prints it.
- :class:`AvenhausPeer` (avenhaus/thrust_stand): boot and help lines, a live row every 100 ms
  ending in a carriage return; ``1``..``0`` ramp to 10..100 % (cosine, 3 s per 100 %), a space
  ramps to 0; ``s`` runs its own 21-step test and prints the result block.

The plant is thrustmap's physics simulator: throttle is the fraction of full ESC command.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping

from thrustmap.protocols.stands.line import LineStandSpec
from thrustmap.rig.sim.plant import Plant


class FirmwarePeer:
    """What the three share: a boot print, rows every ``period_s`` from the plant, received
    bytes handed to :meth:`receive`, at most ``max_backlog_s`` of rows kept when the host does
    not read (a full USB buffer drops them on the real boards)."""

    def __init__(
        self,
        plant: Plant,
        spec: LineStandSpec,
        *,
        motor: int = 0,
        period_s: float = 0.1,
        max_backlog_s: float = 5.0,
    ) -> None:
        self.plant = plant
        self.spec = spec
        self.motor = motor
        self.period_s = period_s
        self.max_backlog_s = max_backlog_s
        self.throttle_frac = 0.0
        self.received: list[bytes] = []
        self._out = bytearray()
        self._start_s: float | None = None
        self._next_s = 0.0

    # -- BytePeer ---------------------------------------------------------------------------
    def write(self, data: bytes, now_s: float) -> None:
        self._advance(now_s)
        self.received.append(bytes(data))
        self.receive(bytes(data), now_s)

    def read(self, now_s: float) -> bytes:
        self._advance(now_s)
        out = bytes(self._out)
        self._out.clear()
        return out

    @property
    def throttle_pct(self) -> float:
        """What the ESC is commanded, in percent of its range."""
        return self.throttle_frac * 100.0

    # -- for subclasses ---------------------------------------------------------------------
    def say(self, text: str, end: str = "\r\n") -> None:
        self._out += (text + end).encode()

    def set_fraction(self, fraction: float, t: float) -> None:
        self.throttle_frac = min(max(fraction, 0.0), 1.0)
        self.plant.set_throttle(self.motor, self.throttle_frac, t)

    def si(self, t: float) -> dict[str, float]:
        state = self.plant.state(t)
        rpm = state.rpm[self.motor] if self.motor < len(state.rpm) else 0.0
        return {
            "thrust_n": state.thrust_n,
            "torque_nm": state.torque_nm,
            "voltage_v": state.voltage_v,
            "current_a": state.current_a,
            "rpm": rpm,
        }

    def raw(self, values: Mapping[str, float], key: str) -> float:
        """``values[key]`` in the units the firmware prints (the preset's column, inverted)."""
        return self.spec.columns[key].from_si(values[key])

    def boot(self, t: float) -> None:
        """What the firmware prints when the port opens."""

    def tick(self, t: float) -> None:
        """One row time: act on timers, print a row if the firmware would."""

    def receive(self, data: bytes, t: float) -> None:
        """Bytes from the host."""

    # -- time -------------------------------------------------------------------------------
    def _advance(self, now_s: float) -> None:
        if self._start_s is None:
            self._start_s = now_s
            self._next_s = now_s
            self.boot(now_s)
        if now_s - self._next_s > self.max_backlog_s:
            self._next_s = now_s - self.max_backlog_s
        while self._next_s <= now_s + 1e-12:
            t = self._next_s
            self.tick(t)
            self._next_s = t + self.period_s

    @property
    def start_s(self) -> float:
        return 0.0 if self._start_s is None else self._start_s


# --------------------------------------------------------------------------- einsz whoop

#: what ``setup()`` prints before the banner (firmware.ino, HX711 build)
EINSZ_INIT = ("#INIT,i2c", "#INIT,ina", "#INIT,bmp280", "#INIT,hx711", "#INIT,done")


def einsz_banner(columns: tuple[str, ...]) -> tuple[str, ...]:
    """``emitBanner()`` for an HX711 build with no BMP280, 12 poles, EDT asked, normal spin."""
    return (
        "#SCHEMA,1",
        "#FW,thrust_stand,2.0.0,Nov 28 2026",
        "#BOARD,rp2040",
        "#ESC,pin=15,proto=DSHOT600,poles=12,edt=1,dir=normal",
        "#SCALE,hx711,dt=16,sck=17,rate_sps=80",
        "#INA,name=INA226,shunt_uohm=10000,max_a=8,conv_us=1100,avg=4,shunt_fs_uv=81920",
        "#FLAGS,1=ina_shunt_sat,2=ina_i_sat,4=thrust_stale,8=rpm_stale,16=watchdog,"
        "32=esc_alert,64=edt_stale",
        "#PHASE,0=idle,1=sweep_hunt,2=sweep_up,3=transient,4=sweep_down,5=response,"
        "6=coastdown,7=hold,8=spindown",
        "#AMBIENT,banner,present=0",
        "#COLS," + ",".join(columns),
    )


def einsz_dshot(pct: int) -> int:
    """``setThrottle()``: ``map(pct, 1, 100, 1, 2000)``, 0 for 0 (integer arithmetic)."""
    pct = min(max(pct, 0), 100)
    return 0 if pct == 0 else 1 + (pct - 1) * 1999 // 99


def einsz_pct_label(dshot: int) -> int:
    """``setThrottleRaw()``: the percent label of a raw DShot value, rounded."""
    return 1 + ((dshot - 1) * 99 + 999) // 1999 if dshot else 0


#: a segment of a firmware's own program: (seconds, phase, log rows after this many seconds
#: into it, or None for a wait that logs nothing: ``sequenceDelay()``)
Segment = tuple[float, int, float | None]


class EinszWhoopPeer(FirmwarePeer):
    WATCHDOG_S = 1.0  # WATCHDOG_MS
    IDLE_S = 0.1  # PRINT_IDLE_US
    FAST_S = 0.004  # PRINT_FAST_US (HX711 build)

    def __init__(self, plant: Plant, spec: LineStandSpec, *, motor: int = 0) -> None:
        super().__init__(plant, spec, motor=motor, period_s=self.IDLE_S)
        self.pct = 0
        self.dshot = 0
        self.armed = False
        self.tripped = False
        self.watchdog_trips = 0
        self.last_host_s = 0.0
        self.tare_n = 0.0
        self.abort = ""  # why a running program is being ended early
        self._rx = bytearray()
        self._program: Iterator[Segment] | None = None
        self._segment: Segment = (0.0, 0, None)
        self._segment_t = 0.0
        self._now = 0.0

    def boot(self, t: float) -> None:
        for line in (*EINSZ_INIT, *einsz_banner(self.spec.header_names), "SYSTEM_READY"):
            self.say(line, "\n")
        self.last_host_s = t

    def _set(self, pct: int, dshot: int, t: float) -> None:
        self.pct, self.dshot = pct, dshot
        self.set_fraction(dshot / 2000.0, t)

    @property
    def in_sequence(self) -> bool:
        return self._program is not None

    def receive(self, data: bytes, t: float) -> None:
        self._rx += data
        while True:
            cut = min(
                (i for i in (self._rx.find(b"\n"), self._rx.find(b"\r")) if i >= 0), default=-1
            )
            if cut < 0:
                del self._rx[31:]  # inputBuf[32]: the rest of an overlong line is dropped
                return
            line = self._rx[:cut].decode("ascii", errors="replace")[:31]
            del self._rx[: cut + 1]
            if line:
                self.command(line, t)

    def command(self, cmd: str, t: float) -> None:
        """``handleCommand()``; of the firmware's own programs only ``SWEEP`` is simulated."""
        self.last_host_s = t
        if self.in_sequence and cmd not in ("PING", "STOP"):
            self.say("#ERROR,busy," + cmd, "\n")
        elif cmd == "PING":
            if not self.armed:
                self.armed = True
                self.say("#WD,armed", "\n")
        elif cmd == "ID":
            for line in einsz_banner(self.spec.header_names):
                self.say(line, "\n")
        elif cmd == "STOP":
            self._set(0, 0, t)  # immediate, never ramped
            self.abort = self.abort or ("stop" if self.in_sequence else "")
        elif cmd == "TARE":
            self._set(0, 0, t)
            self.tare_n = self.si(t)["thrust_n"]
            self.say("#TARE,ok", "\n")
        elif cmd == "SWEEP":
            self._start(self._sweep(), t)
        elif cmd.startswith("DSHOT,"):
            value = min(max(_atoi(cmd[6:]), 0), 2000)
            self._set(einsz_pct_label(value), value, t)
            self.tripped = False
        elif cmd[:1].isdigit():
            pct = min(max(_atoi(cmd), 0), 100)
            self._set(pct, einsz_dshot(pct), t)
            self.tripped = False
        elif cmd in ("TRANSIENT",) or cmd.startswith(("RESPONSE", "HOLD", "DHOLD", "COAST")):
            self.say("#ERROR,not_simulated," + cmd, "\n")

    # -- the firmware's own SWEEP (runSweepSequence(), endSequence(), rampThrottleDown()) ----
    def _start(self, program: Iterator[Segment], t: float) -> None:
        self.abort = ""
        self.tripped = False  # resetSequenceCounters()
        self._program = program
        self.period_s = self.FAST_S
        self._segment_t = t
        self._segment = (0.0, 0, None)
        self._now = t

    def _sweep(self) -> Iterator[Segment]:
        # ``self._now`` is the start of the segment being entered (set before each step)
        self._set(0, 0, self._now)
        yield (0.5, 0, None)
        self.say("#AMBIENT,start,present=0", "\n")
        self.say("START_SWEEP", "\n")
        idle = 0
        for pct in range(1, 16):  # phase A: the lowest throttle that keeps the rotor turning
            self._set(pct, einsz_dshot(pct), self._now)
            yield (0.45, 1, None)
            if self.abort:
                break
            if self.si(self._now)["rpm"] >= 2500:
                idle = pct
                self.say(f"MIN_RELIABLE_IDLE,{idle}", "\n")
                break
        if not idle and not self.abort:
            self.say("#ERROR,idle_hunt_failed", "\n")
        levels = [] if not idle else [*range(idle, 101), *range(99, idle - 1, -1)]
        for i, pct in enumerate(levels):  # phases B and C: 200 ms a level, 100 ms logged
            if self.abort:
                break
            self._set(pct, einsz_dshot(pct), self._now)
            yield (0.2, 2 if i <= 100 - idle else 4, 0.1)
        yield from self._end_sequence("sweep", "END_SWEEP")

    def _end_sequence(self, tag: str, sentinel: str) -> Iterator[Segment]:
        if not self.abort:
            value = self.dshot
            while value > 0:  # rampThrottleDown(): 100 DShot steps every 20 ms, logged
                value = max(0, value - 100)
                self._set(einsz_pct_label(value), value, self._now)
                yield (0.02, 8, 0.0)
            self._set(0, 0, self._now)
            yield (0.1, 8, 0.0)
        else:
            self.say(f"#WARN,sequence_aborted,{self.abort}", "\n")
        self._set(0, 0, self._now)
        self.say(f"#STATS,{tag},telem_ok=0,telem_bad=0,rows_dropped=0", "\n")
        self.say("#AMBIENT,end,present=0", "\n")
        self.say(sentinel, "\n")

    def _run_program(self, t: float) -> bool:
        """Advance the running program to ``t``; True when this tick prints a row."""
        assert self._program is not None
        if self.abort and self._segment[1] != 8:  # runWindow() returns at the next sample
            self._segment = (t - self._segment_t, *self._segment[1:])  # (the ramp is exempt)
        while t >= self._segment_t + self._segment[0]:
            self._segment_t += self._segment[0]
            self._now = self._segment_t
            step = next(self._program, None)
            if step is None:
                self._program = None
                self.period_s = self.IDLE_S
                return True
            self._segment = step
        log_after = self._segment[2]
        return log_after is not None and t - self._segment_t >= log_after

    def tick(self, t: float) -> None:
        trip_s = self.last_host_s + self.WATCHDOG_S
        if self.armed and not self.tripped and self.pct != 0 and trip_s <= t:
            self._set(0, 0, trip_s)  # serviceWatchdog()
            self.tripped = True
            self.watchdog_trips += 1
            self.abort = self.abort or ("watchdog" if self.in_sequence else "")
            self.say("#WARN,watchdog_timeout", "\n")
        phase = 0
        if self._program is not None:
            if not self._run_program(t):
                return
            phase = self._segment[1] if self._program is not None else 0
        self._row(t, phase)

    def _row(self, t: float, phase: int) -> None:
        v = self.si(t)
        v["thrust_n"] -= self.tare_n
        t_us = int((t - self.start_s) * 1e6) & 0xFFFFFFFF
        rpm = int(v["rpm"])
        erpm = rpm * 6
        flags = 16 if self.tripped else 0
        cells = (
            t_us, phase, self.pct, self.dshot, rpm, erpm, 4095 if erpm == 0 else 0, 0,
            int(round(self.raw(v, "thrust_n"))), 0, 0,
            int(round(self.raw(v, "voltage_v"))), int(round(self.raw(v, "current_a"))),
            0, 0, 0, 0, 0, 0, 0, 0, 0, flags,
        )  # fmt: skip
        self.say("D," + ",".join(str(c) for c in cells), "\n")


def _atoi(text: str) -> int:
    digits = ""
    for ch in text.strip():
        if not ch.isdigit() and not (ch in "+-" and not digits):
            break
        digits += ch
    try:
        return int(digits)
    except ValueError:
        return 0


# --------------------------------------------------------------------------- MQTB


def mqtb_stepping_us(elapsed_s: float) -> int:
    """``steppingTest()``'s program: the ESC µs at ``elapsed_s`` into it, -1 when it is over
    (1100 µs 2 s, up to 2000 over 12 s, 2000 0.5 s, down to 1100 over 12 s, 1100 0.5 s)."""
    segments: tuple[tuple[float, int, int], ...] = (
        (2.0, 1100, 1100),
        (12.0, 1100, 2000),
        (0.5, 2000, 2000),
        (12.0, 2000, 1100),
        (0.5, 1100, 1100),
    )
    t = elapsed_s
    for length, a, b in segments:
        if t < length:
            return int(a + (b - a) * t / length)
        t -= length
    return -1


class MqtbPeer(FirmwarePeer):
    ROW_S = 0.004  # LOOPDELAY
    POLES = 14

    def __init__(self, plant: Plant, spec: LineStandSpec, *, motor: int = 0) -> None:
        super().__init__(plant, spec, motor=motor, period_s=self.ROW_S)
        self.us = 1000
        self.test_start_s: float | None = None  # rows from here
        self.program: Callable[[float], int] | None = None
        self.tare_g = 0.0
        self.steps = 0.0
        self.programs_run = 0
        self._header_due = ""

    def boot(self, t: float) -> None:
        self._menu()

    def _menu(self) -> None:
        from thrustmap.protocols.stands.presets.mqtb_teststand import MENU

        for line in MENU:
            self.say(line)

    def _set_us(self, us: int, t: float) -> None:
        self.us = us
        self.set_fraction((us - 1000) / 1000.0, t)

    def receive(self, data: bytes, t: float) -> None:
        text = data.decode("ascii", errors="replace")
        if self.program is not None:  # any byte ends a program
            self.program = None
            self.test_start_s = None
            self._set_us(1000, t)  # loop(): updatePWM(MINCOMMAND)
            self._menu()
            return
        self.say("Input: " + text)
        if "t" in text:
            self.say("Taring")
            self.tare_g = self._grams(t, tared=False)
        elif "s" in text and not any(c in text for c in "cibmrvwk"):
            from thrustmap.protocols.stands.presets.mqtb_teststand import HEADER, START_LINE

            self.say(START_LINE)
            self.program = mqtb_stepping_us
            self.test_start_s = t + 2.0  # delay(2000), then the header
            self._header_due = HEADER
            self.programs_run += 1
            return
        self._menu()

    def _grams(self, t: float, *, tared: bool = True) -> float:
        grams = self.si(t)["thrust_n"] / (self.spec.columns["thrust_n"].scale)
        return grams - (self.tare_g if tared else 0.0)

    def tick(self, t: float) -> None:
        if self.program is None or self.test_start_s is None or t < self.test_start_s:
            return
        if self._header_due:
            self.say(self._header_due)
            self._header_due = ""
        elapsed = t - self.test_start_s
        us = self.program(elapsed)
        if us < 0:  # the program is over: back to loop()
            self.program = None
            self._set_us(1000, t)
            self._menu()
            return
        if us != self.us:
            self._set_us(us, t)
        v = self.si(t)
        self.steps += v["rpm"] / 60.0 * self.POLES / 2 * self.ROW_S
        grams = float(int(self._grams(t)))  # ``int thrust = scale.get_units()``
        row = (
            f"{int(elapsed * 1e6)},{us},{grams:.2f},{int(self.steps)},{int(v['rpm'])},"
            f"{v['voltage_v']:.2f},{v['current_a']:.2f}"
        )
        self.say(row)


# --------------------------------------------------------------------------- avenhaus

AVENHAUS_BOOT = (
    "",
    "",
    "# Thrust Stand 0.2 | Nov 28 2026 | 17:00:00",
    "# Motor ESC ...",
)
AVENHAUS_HELP = (
    "",
    "*** Command List ***",
    " t - Tare sensors",
    " c - Calibrate motor ESC",
    " s - Start/Stop test",
    " p - Print CSV results",
    " k - Measure motor KV (RPM/V) - remove propellers before use",
    " 0-9 - Set throttle to 10%%-100%%",
    " a - Enable analog throttle control",
    " w - Clear stored Wi-Fi credentials",
    " SPACE - Stop motor",
    " h - Print this help message",
    "Press 's' to start the test, or 'h' to see this help message.",
    "Wi-Fi: OFF  0.0.0.0",
)


class AvenhausPeer(FirmwarePeer):
    ROW_S = 0.1  # ``millis() > t + 100``

    def __init__(self, plant: Plant, spec: LineStandSpec, *, motor: int = 0) -> None:
        super().__init__(plant, spec, motor=motor, period_s=self.ROW_S)
        self.pct = 0.0
        self._ramp: tuple[float, float, float, float] | None = None  # t0, from, to, length
        self.step = -1
        self._test_t = 0.0
        self.stats: list[tuple[float, dict[str, float]]] = []

    def boot(self, t: float) -> None:
        for line in AVENHAUS_BOOT:
            self.say(line, "\n")
        for line in ("Arming ESC...", "ESC armed", "# Motor ESC initialized."):
            self.say(line)
        for line in AVENHAUS_HELP:
            self.say(line)

    def ramp_to(self, pct: float, length_s: float, t: float) -> None:
        """``MotorESC::setThrottle(pct, true, ms)``: a cosine ease from the present value."""
        if pct == self.pct:
            self._ramp = None
            return
        self._ramp = (t, self.pct, pct, max(length_s, 1e-6))

    def _ramp_now(self, t: float) -> None:
        if self._ramp is None:
            return
        t0, a, b, length = self._ramp
        progress = (t - t0) / length
        if progress >= 1.0:
            self.pct = b
            self._ramp = None
        else:
            self.pct = a + (b - a) * (1.0 - math.cos(progress * math.pi)) * 0.5
        # the pulse is whole µs: ``map(pw, 1000, 2000, 0, 10000) / 100``
        self.pct = round(self.pct * 10.0) / 10.0
        self.set_fraction(self.pct / 100.0, t)

    def receive(self, data: bytes, t: float) -> None:
        for byte in data.decode("ascii", errors="replace"):
            self.command(byte, t)

    def command(self, byte: str, t: float) -> None:
        """``check_serial()``: one byte."""
        if byte in "0123456789":
            if self.step >= 0:
                self._abort(t)
                return
            pct = 100.0 if byte == "0" else 10.0 * int(byte)
            self.ramp_to(pct, 3.0 * abs(self.pct - pct) / 100.0, t)
        elif byte == " ":
            if self.step >= 0:
                self._abort(t)
            else:
                self.ramp_to(0.0, 3.0 * self.pct / 100.0, t)
        elif byte == "s":
            if self.step >= 0:
                self._abort(t)
            else:
                self.step = 0
                self.stats = []
                self._test_t = t + 2.0  # step 0: 2 s at rest
                self.say("", "\n")
                self.say("# Test started. Step 0 = idle baseline.", "\n")
        elif byte == "t":
            self.say("# Tare thrust sensor complete", "\n")
        elif byte == "h":
            for line in AVENHAUS_HELP:
                self.say(line)

    def _abort(self, t: float) -> None:
        self.say("", "\n")
        self.say("# Test aborted!", "\n")
        self.say(f"# Starting smooth deceleration from {self.pct:.2f}%", "\n")
        self.ramp_to(0.0, 3.0, t)
        self.csv_block()
        self.step = -1

    def _test(self, t: float) -> None:
        if self.step < 0 or t < self._test_t or self._ramp is not None:
            return
        self.stats.append((self.pct, self.si(t)))
        self.step += 1
        if self.step > 20:
            self.say("", "\n")
            self.say("# Test completed.", "\n")
            self.csv_block()
            self.ramp_to(0.0, 3.0, t)
            self.step = -1
            return
        pct = 5.0 + (self.step - 1) / 19.0 * 95.0
        self.ramp_to(pct, 1.0, t)
        self._test_t = t + 1.0 + 0.1 + 2.0

    def csv_block(self) -> None:
        """``print_csv_results()``: a row per step with data."""
        self.say("\r\n\r\n*** TEST RESULTS CSV DATA ***\r\n")
        self.say(
            "Step,Throttle(%),Thrust(g),Torque(g·cm),Voltage(V),Current(A),Power(W),RPM,"
            "Thermal_Max(C),Efficiency(g/W),LC_Samples,Sensor_Samples"
        )
        for i, (pct, v) in enumerate(self.stats):
            grams = self.raw(v, "thrust_n")
            power = v["voltage_v"] * v["current_a"]
            eff = grams / (power / 1000.0) if power > 0 else 0.0
            self.say(
                f"{i},{pct:.2f},{grams:.2f},{self.raw(v, 'torque_nm'):.2f},{v['voltage_v']:.2f},"
                f"{v['current_a']:.3f},{power:.2f},{v['rpm']:.0f},0.00,{eff:.2f},20,20"
            )
        self.say("\r\n\r\n*** END OF TEST RESULTS ***")

    def tick(self, t: float) -> None:
        self._ramp_now(t)
        self._test(t)
        v = self.si(t)
        state = "ACCEL" if self._ramp is not None else ("RUNNING" if self.pct > 0 else "IDLE")
        power = v["voltage_v"] * v["current_a"]
        self.say(
            f"{self.step} | Throttle: {self.pct:.1f}% | State: {state} | "
            f"Thrust: {self.raw(v, 'thrust_n'):.2f} | Torque: {self.raw(v, 'torque_nm'):.2f} | "
            f"Voltage: {v['voltage_v']:.2f} | Current: {v['current_a']:.3f} | "
            f"Power: {power:.2f} | RPM: {v['rpm']:.2f} | Thermal: 0.0C | Pot: 0.00",
            "   \r",
        )


#: preset name -> its firmware's simulator
FIRMWARE_PEERS: dict[str, Callable[[Plant, LineStandSpec], FirmwarePeer]] = {
    "einsz-whoop": EinszWhoopPeer,
    "mqtb-teststand": MqtbPeer,
    "avenhaus-thrust-stand": AvenhausPeer,
}
