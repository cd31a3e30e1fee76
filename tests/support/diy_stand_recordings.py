"""Recordings of two DIY stand firmwares composed from their print statements ("documentation/
source only": neither firmware was compiled or run; see each README in fixtures/stands/).

Every line below is what one ``Serial.print*`` call sequence prints, cited by file and line at
the pinned commit; the values come from a small known table (:func:`truth`) so a test can check
what the preset decodes against what was printed.

- ``mqtb-teststand/program_s.jsonl``: VirtualEnder/TestStandv2 @ 8521231b3d2d: the menu, the
  host's ``s``, the stepping program's header and 3 s of its 250 Hz rows, the host's ``e``
  (any byte ends a program) and the menu again.
- ``avenhaus-thrust-stand/session.jsonl``: avenhaus/thrust_stand @ a1eb40a2b013: boot and help,
  live rows at 10 Hz, ``3`` (a cosine ramp to 30 %), a space (the ramp back to 0), ``s`` (its
  own test) aborted by a space after its first two summaries, with the result block.

Regenerate: ``cd tests && python -m support.regenerate``.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from thrustmap.protocols.transcript import TranscriptWriter

MQTB = ("VirtualEnder/TestStandv2", "8521231b3d2d412c324d8562d2009fe1a6f4f835")
AVENHAUS = ("avenhaus/thrust_stand", "a1eb40a2b01369353d996fd5389337baf81a9d95")


def truth(frac: float) -> dict[str, float]:
    """The table the recordings print at throttle fraction ``frac`` (0..1 of the ESC range)."""
    return {
        "thrust_g": 1500.0 * frac * frac,
        "torque_g_cm": 300.0 * frac * frac,
        "voltage_v": 16.40 - 1.5 * frac,
        "current_a": 60.0 * frac**3,
        "rpm": 30000.0 * frac,
    }


class _Tape:
    """Events in time order for a TranscriptWriter."""

    def __init__(self, path: Path, repo: str, commit: str) -> None:
        self.writer = TranscriptWriter(
            path,
            inner="/dev/ttyUSB0",
            origin_s=0.0,
            extra={
                "generator": "support.diy_stand_recordings",
                "firmware": f"{repo}@{commit}",
                "how": "composed from the firmware's print statements (not a run of it)",
            },
        )

    def out(self, t: float, text: str) -> None:
        self.writer.event("r", text.encode("utf-8"), t)

    def host(self, t: float, text: str) -> None:
        self.writer.event("w", text.encode("ascii"), t)

    def close(self) -> None:
        self.writer.close()
        # composed, not recorded: the moment of composing means nothing and would change the
        # file (and its sha256 in the README) at every regeneration
        path = Path(self.writer.path)
        text = path.read_text(encoding="utf-8")
        head, _, rest = text.partition("\n")
        head = re.sub(r'"created_utc":"[^"]*"', '"created_utc":"2026-11-28T00:00:00+00:00"', head)
        path.write_text(head + "\n" + rest, encoding="utf-8")


# --------------------------------------------------------------------------- MQTB

MQTB_MENU = (  # MQTB_Thrust_Stand.ino lines 100-101 (Serial.println: CR LF)
    "Type: t(Tare), v(Battery Voltage), w(Load Cell), c(Calibrate), s(Stepping Test)\r\n"
    "      b(Brake Test), r(Rate Test), k(KV Test), m(Main Test), or i(Idle)\r\n"
)


def mqtb_us(elapsed_us: int) -> int:
    """``ramp_get_pwm()`` (ramp.cpp lines 37-62) over steppingTest's program (testRoutines.ino
    lines 453-457): integer arithmetic, a segment ends inclusive."""
    segments = ((1100, 1100, 2000), (1100, 2000, 12000), (2000, 2000, 500))
    segments += ((2000, 1100, 12000), (1100, 1100, 500))
    start = 0
    for a, b, ms in segments:
        length = ms * 1000
        if elapsed_us <= start + length:
            return a if a == b else a + int((elapsed_us - start) * (b - a) / length)
        start += length
    return -1


def mqtb_row(elapsed_us: int, us: int, steps: int) -> str:
    """testRoutines.ino lines 492-509: time, pwm, getThrust(thrust) (an int of grams printed with
    two decimals), stepCount1, theseRpms (an int), volts and amps (two decimals)."""
    v = truth((us - 1000) / 1000.0)
    grams = float(int(v["thrust_g"]))
    return (
        f"{elapsed_us},{us},{grams:.2f},{steps},{int(v['rpm'])},"
        f"{v['voltage_v']:.2f},{v['current_a']:.2f}\r\n"
    )


def write_mqtb(path: Path, stop_after_s: float = 3.0) -> Path:
    tape = _Tape(path, *MQTB)
    tape.out(0.0, MQTB_MENU)
    tape.host(0.5, "s")
    tape.out(0.502, "Input: s\r\n")  # MQTB_Thrust_Stand.ino lines 110-111
    tape.out(0.52, "Begining automated test, press any key to exit\r\n")  # testRoutines 421
    start = 2.52  # delay(2000) (line 422), then the header (lines 424-440)
    tape.out(start, "Time(uS),Throttle(uS),Thrust(g),eSteps,eRPMs,Volts,Amps\r\n")
    steps = 0.0
    chunk = ""
    k = 0
    while k * 4000 <= stop_after_s * 1e6:  # LOOPDELAY 4000 µs (config.h line 8)
        elapsed = k * 4000
        us = mqtb_us(elapsed)
        steps += truth((us - 1000) / 1000.0)["rpm"] / 60.0 * 7 * 0.004  # POLES 14
        chunk += mqtb_row(elapsed, us, int(steps))
        k += 1
        if k % 25 == 0:  # the host reads every 100 ms
            tape.out(start + elapsed / 1e6, chunk)
            chunk = ""
    end = start + stop_after_s
    tape.out(end, chunk)
    tape.host(end + 0.001, "e")  # any byte: while(!Serial.available()) ends (line 461)
    # drain (lines 544-547), return, delay(100) (ino line 151), updatePWM(1000), menu again
    tape.out(end + 0.105, MQTB_MENU)
    tape.close()
    return path


# --------------------------------------------------------------------------- avenhaus

AVENHAUS_BOOT = (
    "\n\n# Thrust Stand 0.2 | Nov 28 2026 | 17:00:00\n"  # main.cpp line 201 (printf)
    "# Motor ESC ...\r\n"  # line 203
    "Arming ESC...\r\n"  # motor.cpp arm()
    "ESC armed\r\n"
    "# Motor ESC initialized.\r\n"  # main.cpp line 206
    "# INA226 Current Sensor initialized.\r\n"  # sensors.cpp line 154
    "# Initialize RPM Sensor ...\r\n"  # sensors.cpp line 159
)
AVENHAUS_HELP = (  # print_help(), main.cpp lines 523-546
    "\r\n*** Command List ***\r\n"
    " t - Tare sensors\r\n"
    " c - Calibrate motor ESC\r\n"
    " s - Start/Stop test\r\n"
    " p - Print CSV results\r\n"
    " k - Measure motor KV (RPM/V) - remove propellers before use\r\n"
    " 0-9 - Set throttle to 10%%-100%%\r\n"
    " a - Enable analog throttle control\r\n"
    " w - Clear stored Wi-Fi credentials\r\n"
    " SPACE - Stop motor\r\n"
    " h - Print this help message\r\n"
    "Press 's' to start the test, or 'h' to see this help message.\r\n"
    "Wi-Fi: OFF  0.0.0.0\r\n"
)


def avenhaus_row(step: int, pct: float, state: str) -> str:
    """main.cpp lines 235-264: Serial.print(float) prints two decimals unless told."""
    v = truth(pct / 100.0)
    power = v["voltage_v"] * v["current_a"]
    return (
        f"{step} | Throttle: {pct:.1f}% | State: {state} | Thrust: {v['thrust_g']:.2f} | "
        f"Torque: {v['torque_g_cm']:.2f} | Voltage: {v['voltage_v']:.2f} | "
        f"Current: {v['current_a']:.3f} | Power: {power:.2f} | RPM: {v['rpm']:.2f} | "
        f"Thermal: 0.0C | Pot: 0.00   \r"
    )


def avenhaus_stats(step: int, pct: float) -> str:
    """print_stats(), main.cpp lines 368-385 ("Power" printed twice, as the firmware does)."""
    v = truth(pct / 100.0)
    power = v["voltage_v"] * v["current_a"]
    return (
        f"{step} | Throttle: {pct:.2f}% | Thrust: {v['thrust_g']:.2f} | "
        f"Torque: {v['torque_g_cm']:.2f} | Voltage: {v['voltage_v']:.2f} | "
        f"Current: {v['current_a']:.3f} | Power: {power:.2f} | Power: {power:.2f} | "
        f"RPM: {int(v['rpm'])} | Thermal: 0.00 | Valid: 0 |  20 |20\n"
    )


def avenhaus_csv(rows: list[tuple[int, float]]) -> str:
    """print_csv_results(), main.cpp lines 387-435."""
    out = "\n\n*** TEST RESULTS CSV DATA ***\n\r\n"
    out += (
        "Step,Throttle(%),Thrust(g),Torque(g·cm),Voltage(V),Current(A),Power(W),RPM,"
        "Thermal_Max(C),Efficiency(g/W),LC_Samples,Sensor_Samples\r\n"
    )
    for step, pct in rows:
        v = truth(pct / 100.0)
        power = v["voltage_v"] * v["current_a"]
        eff = v["thrust_g"] / (power / 1000.0) if power > 0 else 0.0
        out += (
            f"{step},{pct:.2f},{v['thrust_g']:.2f},{v['torque_g_cm']:.2f},"
            f"{v['voltage_v']:.2f},{v['current_a']:.3f},{power:.2f},{v['rpm']:.0f},0.00,"
            f"{eff:.2f},20,20\r\n"
        )
    return out + "\n\n*** END OF TEST RESULTS ***\r\n"


def cosine(a: float, b: float, progress: float) -> float:
    """MotorESC::run() (motor.cpp lines 97-110), to the whole µs the pulse has."""
    value = a + (b - a) * (1.0 - math.cos(min(progress, 1.0) * math.pi)) * 0.5
    return round(value * 10.0) / 10.0


def write_avenhaus(path: Path) -> Path:
    tape = _Tape(path, *AVENHAUS)
    tape.out(0.0, AVENHAUS_BOOT + AVENHAUS_HELP)
    # (host time, byte): '3' -> 30 %, ' ' -> 0, 's' -> own test, ' ' -> abort in step 1
    events = [(1.0, "3"), (4.0, " "), (5.5, "s"), (10.7, " ")]
    pct, ramp, step = 0.0, None, -1
    stats: list[tuple[int, float]] = []
    next_step_s = 0.0
    t = 0.1
    while t < 14.0:
        while events and events[0][0] <= t:
            at, byte = events.pop(0)
            tape.host(at, byte)
            if byte == "3":  # check_serial line 320; setThrottle line 293: 3 s per 100 %
                ramp = (at, pct, 30.0, 3.0 * abs(pct - 30.0) / 100.0)
            elif byte == " " and step < 0:  # line 316: setThrottle(0.0)
                ramp = (at, pct, 0.0, 3.0 * pct / 100.0)
            elif byte == "s":  # start_test(), lines 349-366
                step, next_step_s = 0, at + 2.0
                tape.out(at + 0.001, "\n# Test started. Step 0 = idle baseline.\n")
            elif byte == " ":  # abort_test(), lines 497-520: decel_time_ms 3000
                tape.out(at + 0.001, "\n# Test aborted!\n")
                tape.out(at + 0.002, f"# Starting smooth deceleration from {pct:.2f}%\n")
                tape.out(at + 0.003, avenhaus_csv(stats))
                ramp, step = (at, pct, 0.0, 3.0), -1
        if ramp is not None:
            at, a, b, length = ramp
            pct = cosine(a, b, (t - at) / length)
            if t - at >= length:
                ramp = None
        if step >= 0 and ramp is None and t >= next_step_s:  # run_test(), lines 437-495
            stats.append((step, pct))
            tape.out(t, avenhaus_stats(step, pct))
            step += 1
            target = 5.0 + (step - 1) / 19.0 * 95.0
            ramp, next_step_s = (t, pct, target, 1.0), t + 1.0 + 0.1 + 2.0
        state = "ACCEL" if ramp is not None else ("RUNNING" if pct > 0 else "IDLE")
        tape.out(t, avenhaus_row(step, pct, state))
        t = round(t + 0.1, 6)
    tape.close()
    return path


def write_fixtures(folder: Path) -> list[Path]:
    (folder / "mqtb-teststand").mkdir(parents=True, exist_ok=True)
    (folder / "avenhaus-thrust-stand").mkdir(parents=True, exist_ok=True)
    return [
        write_mqtb(folder / "mqtb-teststand" / "program_s.jsonl"),
        write_avenhaus(folder / "avenhaus-thrust-stand" / "session.jsonl"),
    ]
