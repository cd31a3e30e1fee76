"""Run stand firmware compiled against the Arduino shim, fed by thrustmap's physics simulator.

    python -m tests.support.arduino_shim.harness build --stand tiny-thrust-stand \\
        --firmware ~/src/tiny-thrust-stand -o /tmp/tiny
    python -m tests.support.arduino_shim.harness run --stand tiny-thrust-stand --binary /tmp/tiny

``build`` compiles YOUR checkout of the firmware (never fetched here) with ``shim.cpp``;
victorhook/thruststand also needs a checkout of olkal/HX711_ADC (``--lib``). ``run`` starts the
binary, prints the stand's serial port (a pseudo-terminal) and, for a stand that drives no
motor (victorhook), a second pseudo-terminal where a simulated Betaflight FC (thrustmap's
``MspPeer``) drives the same motor; then it feeds the firmware's HX711 and ADC pins from the
plant and applies the firmware's ``analogWrite`` to the motor, until stdin closes.
``--rfc2217 PORT`` also serves the stand's port as ``rfc2217://127.0.0.1:PORT``: a client's DTR
reaches the board's reset line there (a pseudo-terminal has no DTR). Lines on stdin: ``mass <grams>`` hangs a known mass on the load cell (for
``thrustmap stand calibrate``), ``mass 0`` takes it off; ``unplug``/``plug`` disconnect the
motor from the firmware's PWM output; ``events`` prints the firmware's last control events.

The sensor mappings (``STANDS``) are the inverses of each firmware's own reading: they are how
a real stand's cell and ADC would present the plant's thrust, voltage and current.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from thrustmap.core.physical import G0
from thrustmap.rig.sim.msp_peer import MspPeer
from thrustmap.rig.sim.physics import make_plant

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class StandWiring:
    plant: str  # thrustmap.rig.sim preset of the motor and propeller on the stand
    hx711_sck_pin: int
    hx711_tare_counts: int  # the HX711's signed 24-bit reading with nothing on the cell
    counts_per_gram: float  # 24-bit counts per gram of pull (negative: pull lowers it)
    drives_motor: bool  # the firmware's analogWrite drives the motor (else an FC does)
    pwm_pin: int = -1
    pwm_full: int = 255
    voltage_pin: int = -1
    current_pin: int = -1
    volts_per_count: float = 0.0
    amps_per_count: float = 0.0
    sources: tuple[str, ...] = ()  # firmware files, relative to its checkout
    avr_int16: bool = False
    boot_s: float = 0.0  # after a reset the bootloader hears nothing for this long


STANDS = {
    # Pro Mini: DT 3, SCK 4, PWM 10, A1 battery, A0 INA139 (Tiny-Thrust-Stand.ino lines 4-9);
    # the cell reads -422 counts/g after ">> 4" (plot_thrust.py line 17): -422*16 in 24 bits
    "tiny-thrust-stand": StandWiring(
        plant="crazyflie-2.1",
        hx711_sck_pin=4,
        hx711_tare_counts=-83_000,
        counts_per_gram=-422.0 * 16,
        drives_motor=True,
        pwm_pin=10,
        voltage_pin=15,  # A1
        current_pin=14,  # A0
        volts_per_count=5.0 / 1024,
        amps_per_count=0.06 * 22 * 5.0 / 1024,
        sources=("Arduino/Tiny-Thrust-Stand/Tiny-Thrust-Stand.ino",),
        avr_int16=True,
        boot_s=1.0,  # Optiboot's wait after a reset
    ),
    # Blue Pill: DOUT PB9, SCK PB8 (main.cpp lines 4-5). A cell a little different from the
    # authors' (220000 counts per 490 g): calibration has something to find.
    "victorhook-thruststand": StandWiring(
        plant="xnova-2207-6s",
        hx711_sck_pin=40,  # PB8 in Arduino.h
        hx711_tare_counts=152_000,
        counts_per_gram=-400.0,
        drives_motor=False,
        sources=("src/main.cpp",),
    ),
}


def build(stand: str, firmware: Path, lib: Path | None, out: Path) -> None:
    wiring = STANDS[stand]
    shim_o = out.with_suffix(".shim.o")
    cc = ["nice", "g++", "-std=c++17", "-O1", f"-I{HERE}"]
    subprocess.run([*cc, "-c", str(HERE / "shim.cpp"), "-o", str(shim_o)], check=True)
    cmd = list(cc)
    if wiring.avr_int16:
        cmd.append("-DSHIM_AVR_INT16")
    if lib is not None:
        cmd += [f"-I{lib / 'src'}", str(lib / "src" / "HX711_ADC.cpp")]
    cmd += ["-x", "c++", *(str(firmware / s) for s in wiring.sources), "-x", "none"]
    subprocess.run([*cmd, str(shim_o), "-lpthread", "-o", str(out)], check=True)
    print(json.dumps(fingerprint(firmware, wiring), indent=2))


def fingerprint(firmware: Path, wiring: StandWiring) -> dict[str, object]:
    """What a recording names: the firmware's commit and the shim's files' sha256."""
    commit = subprocess.run(
        ["git", "-C", str(firmware), "rev-parse", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    shim = {
        name: hashlib.sha256((HERE / name).read_bytes()).hexdigest()
        for name in ("Arduino.h", "shim_avr.h", "shim.cpp", "harness.py")
    }
    return {"firmware_commit": commit or None, "shim_sha256": shim}


class Harness:
    def __init__(self, stand: str, binary: Path, *, seed: int = 1, noise: bool = True) -> None:
        self.wiring = STANDS[stand]
        self.plant = make_plant(self.wiring.plant, rotors_on_esc=1, seed=seed, noise=noise)
        self.lock = threading.Lock()
        self.t0 = time.monotonic()
        self.mass_g = 0.0
        self.motor_plugged = True
        env = dict(os.environ, SHIM_HX711_SCK=str(self.wiring.hx711_sck_pin))
        env["SHIM_BOOT_S"] = str(self.wiring.boot_s)
        self.proc = subprocess.Popen(
            [str(binary)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env
        )
        assert self.proc.stdout is not None
        first = self.proc.stdout.readline().split()
        self.stand_port = first[1]
        self.fc_port: str | None = None
        self.events: list[str] = []
        self._feed()  # the cell's value before setup() reads it
        threading.Thread(target=self._control, daemon=True).start()
        threading.Thread(target=self._sensors, daemon=True).start()
        if not self.wiring.drives_motor:
            self._start_fc()

    def now(self) -> float:
        return time.monotonic() - self.t0

    def _feed(self) -> None:
        w = self.wiring
        with self.lock:
            state = self.plant.state(self.now())
        grams = state.thrust_n / G0 * 1000.0 + self.mass_g
        lines = [f"HX {int(round(w.hx711_tare_counts + grams * w.counts_per_gram))}"]
        if w.voltage_pin >= 0:
            lines.append(
                f"ADC {w.voltage_pin} {min(1023, round(state.voltage_v / w.volts_per_count))}"
            )
        if w.current_pin >= 0:
            lines.append(
                f"ADC {w.current_pin} {min(1023, round(state.current_a / w.amps_per_count))}"
            )
        assert self.proc.stdin is not None
        self.proc.stdin.write("\n".join(lines) + "\n")
        self.proc.stdin.flush()

    def _sensors(self) -> None:
        while self.proc.poll() is None:
            try:
                self._feed()
            except (BrokenPipeError, ValueError):
                return
            time.sleep(0.005)

    def _control(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            parts = line.split()
            if parts[:1] == ["PWM"] and int(parts[1]) == self.wiring.pwm_pin:
                fraction = min(max(int(parts[2]) / self.wiring.pwm_full, 0.0), 1.0)
                fraction = fraction if self.motor_plugged else 0.0
                with self.lock:
                    self.plant.set_throttle(0, fraction, self.now())
            self.events.append(f"{self.now():.3f} {line.strip()}")

    def _start_fc(self) -> None:
        """A Betaflight-like FC (thrustmap's MspPeer) on its own pseudo-terminal, driving the
        same plant: the stand's flight controller."""
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self.fc_port = os.ttyname(slave)
        peer = MspPeer(self.plant, "betaflight-4")

        def serve() -> None:
            while self.proc.poll() is None:
                try:
                    data = os.read(master, 4096)
                except BlockingIOError:
                    data = b""
                with self.lock:
                    if data:
                        peer.write(data, self.now())
                    out = peer.read(self.now())
                if out:
                    os.write(master, out)
                time.sleep(0.002)

        threading.Thread(target=serve, daemon=True).start()

    def reset(self) -> None:
        """The board's reset line pulled low (DTR asserted through the auto-reset capacitor):
        the MCU restarts; its pins float meanwhile, and the motor MOSFET's gate pull-down keeps
        the motor off (tiny-thrust-stand's schematic) until the firmware drives it again."""
        with self.lock:
            self.plant.set_throttle(0, 0.0, self.now())
        assert self.proc.stdin is not None
        self.proc.stdin.write("RESET\n")
        self.proc.stdin.flush()
        self.events.append(f"{self.now():.3f} DTR reset")

    def serve_rfc2217(self, tcp_port: int) -> None:
        """The stand's port over RFC 2217 on 127.0.0.1 (``rfc2217://127.0.0.1:<port>``): a
        client's DTR reaches the board's reset line, as on a USB-serial adapter."""
        import select
        import socket

        from serial.rfc2217 import PortManager

        server = socket.create_server(("127.0.0.1", tcp_port))

        def bridge() -> None:
            while self.proc.poll() is None:
                conn, _ = server.accept()
                fd = os.open(self.stand_port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
                manager = PortManager(_ResetLine(self.reset), _Connection(conn))
                try:
                    while True:
                        ready, _, _ = select.select([conn, fd], [], [], 0.5)
                        if conn in ready:
                            data = conn.recv(4096)
                            if not data:
                                break
                            os.write(fd, b"".join(manager.filter(data)))
                        if fd in ready:
                            conn.sendall(b"".join(manager.escape(os.read(fd, 4096))))
                except OSError:
                    pass
                finally:
                    os.close(fd)
                    conn.close()

        threading.Thread(target=bridge, daemon=True).start()

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(5)


class _Connection:
    """A socket as ``PortManager`` writes to it."""

    def __init__(self, sock: Any) -> None:
        self.sock = sock

    def write(self, data: bytes) -> None:
        self.sock.sendall(data)


class _ResetLine:
    """What the RFC 2217 server sees as its serial port: settings it may set, and DTR, whose
    assertion resets the board (an Arduino's auto-reset)."""

    def __init__(self, on_reset: Callable[[], None]) -> None:
        self.on_reset = on_reset
        self._dtr = False
        self.baudrate, self.bytesize, self.parity, self.stopbits = 115200, 8, "N", 1
        self.rts = self.break_condition = False
        self.cts = self.dsr = self.ri = self.cd = False  # modem lines a USB adapter reports

    @property
    def dtr(self) -> bool:
        return self._dtr

    @dtr.setter
    def dtr(self, value: bool) -> None:
        if value and not self._dtr:
            self.on_reset()
        self._dtr = bool(value)

    def reset_input_buffer(self) -> None:
        pass

    def reset_output_buffer(self) -> None:
        pass


def run(stand: str, binary: Path, seed: int, noise: bool, rfc2217: int | None = None) -> None:
    h = Harness(stand, binary, seed=seed, noise=noise)
    if rfc2217 is not None:
        h.serve_rfc2217(rfc2217)
        print(f"rfc2217 rfc2217://127.0.0.1:{rfc2217}", flush=True)
    print(f"stand {h.stand_port}" + (f"\nfc {h.fc_port}" if h.fc_port else ""), flush=True)
    try:
        for line in sys.stdin:
            parts = line.split()
            if parts[:1] == ["mass"] and len(parts) == 2:
                h.mass_g = float(parts[1])
                print(f"mass {h.mass_g:g} g", flush=True)
            elif parts in (["unplug"], ["plug"]):
                h.motor_plugged = parts == ["plug"]
                print(f"motor {'plugged' if h.motor_plugged else 'unplugged'}", flush=True)
            elif parts == ["events"]:
                print("\n".join(h.events[-50:]), flush=True)
    finally:
        h.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("build")
    b.add_argument("--stand", choices=sorted(STANDS), required=True)
    b.add_argument("--firmware", type=Path, required=True, help="your checkout of it")
    b.add_argument("--lib", type=Path, help="your checkout of olkal/HX711_ADC (victorhook)")
    b.add_argument("-o", "--out", type=Path, required=True)
    r = sub.add_parser("run")
    r.add_argument("--stand", choices=sorted(STANDS), required=True)
    r.add_argument("--binary", type=Path, required=True)
    r.add_argument("--seed", type=int, default=1)
    r.add_argument("--no-noise", action="store_true")
    r.add_argument("--rfc2217", type=int, help="also serve the stand on this TCP port (DTR)")
    args = ap.parse_args()
    if args.cmd == "build":
        build(args.stand, args.firmware, args.lib, args.out)
    else:
        run(args.stand, args.binary, args.seed, not args.no_noise, args.rfc2217)


if __name__ == "__main__":
    main()
