"""Issue 36 on REAL firmware: ArduCopter SITL (and PX4 SITL, SIH quadx).

Skipped unless the binaries are given (CI has none):
CI replays recordings of these runs instead (fixtures/firmware/, tests/test_firmware_recordings.py).
- ``THRUSTMAP_ARDUPILOT_SITL``: the ``arducopter`` SITL binary (``build/sitl/bin/arducopter``);
  its defaults file is ``Tools/autotest/default_params/copter.parm`` of the same tree, or
  ``THRUSTMAP_ARDUPILOT_DEFAULTS``.
- ``THRUSTMAP_PX4_SITL``: the ``px4`` SITL binary (``build/px4_sitl_default/bin/px4``), run
  from its build folder with SYS_AUTOSTART 10040 (SIH quadx).
``THRUSTMAP_SITL_RUNS`` (default 1) repeats the intruder spin.

The real CLI runs in a subprocess (``python -m thrustmap``); the vehicle's outputs are read
from the vehicle itself on another of its ports, not from thrustmap. The SITLs bind their ports
on every interface: run this in a private network namespace, e.g.
``unshare -n sh -c 'ip link set lo up; python -m pytest tests/test_link_lock_sitl.py'``.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink import encode as enc
from thrustmap.protocols.mavlink.link import mavutil_connection

PROJECT = Path(__file__).resolve().parent.parent
ARDUPILOT = os.environ.get("THRUSTMAP_ARDUPILOT_SITL", "")
PX4 = os.environ.get("THRUSTMAP_PX4_SITL", "")
RUNS = int(os.environ.get("THRUSTMAP_SITL_RUNS", "1"))
KEY = bytes(range(7, 39))
SIGNING_EPOCH_S = 1420070400


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def thrustmap(*args: str, cwd: Path, timeout_s: float = 120) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(PROJECT))
    env.pop("THRUSTMAP_MAVLINK_SIGNING_KEY", None)
    return subprocess.run(
        [sys.executable, "-m", "thrustmap", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )


class Monitor:
    """A second MAVLink connection to the vehicle (its own port): what the vehicle outputs."""

    def __init__(self, url: str) -> None:
        self.conn: Any = mavutil_connection(url, source_system=254, source_component=191)
        self.servo: list[int] = []
        self.armed = False
        self.texts: list[str] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.1)
            if msg is None:
                continue
            kind = msg.get_type()
            with self._lock:
                if kind == "SERVO_OUTPUT_RAW" and msg.port == 0:
                    self.servo = [getattr(msg, f"servo{i}_raw") for i in range(1, 9)]
                elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    self.armed = bool(msg.base_mode & 128)
                elif kind == "STATUSTEXT":
                    self.texts.append(str(msg.text))

    def wait(self, what: str, done: Any, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._lock:
                if done(self):
                    return
            time.sleep(0.05)
        raise AssertionError(f"the vehicle never showed {what}: servo {self.servo}")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.conn.close()


class Intruder:
    """A second local socket sending HEARTBEATs to thrustmap's port once ``armed()``."""

    def __init__(self, port: int, armed: Any) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        host, port_ = self.sock.getsockname()
        self.address = f"{host}:{port_}"
        self.port, self.armed = port, armed
        self.sent = self.received = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        hb = mav.MavlinkCodec(255, 190).encode(
            enc.heartbeat_message(mav.Autopilot.INVALID, armed=False, vehicle_type=6)
        )
        deadline = time.monotonic() + 120
        while not self._stop.wait(0.05) and time.monotonic() < deadline:
            try:
                while True:
                    self.received += len(self.sock.recv(65535))
            except BlockingIOError:
                pass
            if self.armed():
                self.sock.sendto(hb, ("127.0.0.1", self.port))
                self.sent += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        time.sleep(0.1)
        try:
            while True:
                self.received += len(self.sock.recv(65535))
        except BlockingIOError:
            pass
        self.sock.close()


# ------------------------------------------------------------------------------------------
# ArduCopter SITL
# ------------------------------------------------------------------------------------------
@dataclass
class ArduCopter:
    process: subprocess.Popen[bytes]
    base_port: int  # SERIAL0 tcp (the first port: unsigned accepted), SERIAL2 = base + 2
    udp_port: int  # SERIAL1 sends to 127.0.0.1:udp_port (thrustmap listens: udpin)
    folder: Path


@pytest.fixture(scope="module")
def arducopter(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ArduCopter]:
    if not ARDUPILOT or not Path(ARDUPILOT).is_file():
        pytest.skip("set THRUSTMAP_ARDUPILOT_SITL to an arducopter SITL binary")
    binary = Path(ARDUPILOT).resolve()
    defaults = os.environ.get("THRUSTMAP_ARDUPILOT_DEFAULTS") or str(
        binary.parents[3] / "Tools/autotest/default_params/copter.parm"
    )
    folder = tmp_path_factory.mktemp("arducopter")
    instance = 3
    base_port = 5760 + 10 * instance
    udp_port = free_udp_port()
    log = (folder / "sitl.log").open("wb")
    process = subprocess.Popen(
        [str(binary), "--model", "quad", "--speedup", "1", "-I", str(instance)]
        + ["--home", "-35.363261,149.165230,584,353"]
        + ["--defaults", defaults, "--serial0", "tcp:0", "--serial1"]
        + [f"udpclient:127.0.0.1:{udp_port}", "--serial2", "tcp:2"],
        cwd=folder,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        yield ArduCopter(process, base_port, udp_port, folder)
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=10)
        log.close()


def wait_ready(monitor: Monitor) -> None:
    """Ask for SERVO_OUTPUT_RAW (ArduPilot streams nothing unasked) until it comes; then give
    the board time to finish initialising (it refuses motor tests until then)."""
    deadline = time.monotonic() + 180
    while not monitor.servo and time.monotonic() < deadline:
        monitor.conn.mav.command_long_send(1, 1, 511, 0, 36, 100_000, 0, 0, 0, 0, 0)
        time.sleep(1.0)
    monitor.wait("SERVO_OUTPUT_RAW", lambda m: bool(m.servo), 1)
    time.sleep(10)


def connect_monitor(url: str, timeout_s: float = 60) -> Monitor:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return Monitor(url)
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


@pytest.mark.parametrize("run", range(RUNS))
def test_ardupilot_spin_udpin_aborts_on_an_intruder(
    arducopter: ArduCopter, tmp_path: Path, run: int
) -> None:
    monitor = connect_monitor(f"tcp:127.0.0.1:{arducopter.base_port}")
    try:
        wait_ready(monitor)
        idle = max(monitor.servo[:4])
        intruder = Intruder(arducopter.udp_port, lambda: max(monitor.servo[:4]) > idle + 20)
        try:
            done = thrustmap(
                "spin",
                f"udpin:127.0.0.1:{arducopter.udp_port}",
                "--motor",
                "1",
                "--throttle",
                "10",
                "--seconds",
                "6",
                "--ramp",
                "0",
                "--yes",
                cwd=tmp_path,
            )
        finally:
            intruder.close()
        text = done.stdout + done.stderr
        print(f"run {run}: exit {done.returncode}, intruder sent {intruder.sent}, received "
              f"{intruder.received}\n{text}")  # fmt: skip
        assert intruder.sent > 0, text
        assert done.returncode == 1, text
        assert f"{intruder.address} sent to the vehicle link" in text
        assert intruder.received == 0, text
        monitor.wait("outputs at idle", lambda m: max(m.servo[:4]) <= idle and not m.armed, 5)
        print(f"run {run}: outputs after the spin {monitor.servo[:4]} (idle {idle})")
    finally:
        monitor.close()


def test_ardupilot_signing_on_its_second_port(arducopter: ArduCopter, tmp_path: Path) -> None:
    """A key set through SETUP_SIGNING on the first port; on another port probe and spin work
    with the key; without it one line and exit 2; the key is in no file thrustmap wrote."""
    monitor = connect_monitor(f"tcp:127.0.0.1:{arducopter.base_port}")
    try:
        wait_ready(monitor)
        stamp = int((time.time() - SIGNING_EPOCH_S) * 100_000)
        monitor.conn.mav.setup_signing_send(1, 1, list(KEY), stamp)
        time.sleep(1.0)
        keyfile = tmp_path / "secret" / "vehicle.key"
        keyfile.parent.mkdir()
        keyfile.write_text(KEY.hex())
        work = tmp_path / "work"
        work.mkdir()
        second = f"tcp:127.0.0.1:{arducopter.base_port + 2}"
        refused = thrustmap("probe", second, cwd=work)
        print(f"without the key: exit {refused.returncode}: {refused.stderr.strip()}")
        assert refused.returncode == 2, refused.stdout + refused.stderr
        lines = refused.stderr.strip().splitlines()
        assert (
            len(lines) == 1
            and "the vehicle requires signed MAVLink: pass --signing-key" in (lines[0])
        )
        probed = thrustmap(
            "probe", f"record://{second}?file={work / 'probe.jsonl'}", "--signing-key",
            str(keyfile), cwd=work,
        )  # fmt: skip
        assert probed.returncode == 0, probed.stdout + probed.stderr
        assert "ardupilot" in probed.stdout
        spun = thrustmap(
            "spin", f"record://{second}?file={work / 'spin.jsonl'}", "--motor", "1",
            "--throttle", "10", "--seconds", "2", "--yes", "--signing-key", KEY.hex(), cwd=work,
        )  # fmt: skip
        print(f"with the key: probe exit {probed.returncode}, spin exit {spun.returncode}")
        print(spun.stdout)
        assert spun.returncode == 0, spun.stdout + spun.stderr
        assert "stopped (verified)" in spun.stdout
        for path in [p for p in work.rglob("*") if p.is_file()]:
            data = path.read_bytes()
            assert KEY not in data and KEY.hex().encode() not in data, path
        for text in (refused, probed, spun):
            assert KEY.hex() not in text.stdout + text.stderr
    finally:
        # the key lives in this SITL's eeprom (a temporary folder); signing off all the same
        monitor.conn.setup_signing(KEY, sign_outgoing=True)
        monitor.conn.mav.setup_signing_send(1, 1, [0] * 32, 0)
        monitor.close()


# ------------------------------------------------------------------------------------------
# PX4 SITL (SIH quadx): the GCS link sends from 18570 + i to 127.0.0.1:14550
# ------------------------------------------------------------------------------------------
PX4_INSTANCE = 5
PX4_GCS_PORT = 14550  # where the GCS link sends (every instance)


@pytest.fixture(scope="module")
def px4(tmp_path_factory: pytest.TempPathFactory) -> Iterator[subprocess.Popen[bytes]]:
    if not PX4 or not Path(PX4).is_file():
        pytest.skip("set THRUSTMAP_PX4_SITL to a px4 SITL binary (build/px4_sitl_default/bin/px4)")
    binary = Path(PX4).resolve()
    folder = tmp_path_factory.mktemp("px4")
    env = dict(
        os.environ,
        PX4_SYS_AUTOSTART="10040",
        PX4_SIMULATOR="sihsim",
        PX4_SIM_MODEL="sihsim_quadx",
    )
    log = (folder / "px4.log").open("wb")
    process = subprocess.Popen(
        [str(binary), "-i", str(PX4_INSTANCE), "-d", str(binary.parents[1] / "etc")],
        cwd=folder,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        yield process
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=10)
        log.close()
        Path(f"/tmp/px4-sock-{PX4_INSTANCE}").unlink(missing_ok=True)  # PX4 leaves it


@pytest.fixture(scope="module")
def px4_monitor(px4: subprocess.Popen[bytes]) -> Iterator[Monitor]:
    """PX4's offboard link (14580 + i) as the second port. PX4 keeps talking to the first
    address that spoke to it: one monitor for every run."""
    monitor = Monitor(f"udpout:127.0.0.1:{14580 + PX4_INSTANCE}")
    conn = monitor.conn
    deadline = time.monotonic() + 120  # PX4 takes a while to boot on a busy machine
    while not monitor.servo and time.monotonic() < deadline:
        conn.mav.heartbeat_send(6, 8, 0, 0, 0)  # a partner for PX4's link
        conn.mav.command_long_send(1, 1, 511, 0, 36, 100_000, 0, 0, 0, 0, 0)  # SERVO_OUTPUT_RAW
        time.sleep(0.5)
    try:
        monitor.wait("SERVO_OUTPUT_RAW", lambda m: bool(m.servo), 1)
        yield monitor
    finally:
        monitor.close()


@pytest.mark.parametrize("run", range(RUNS))
def test_px4_spin_udpin_aborts_on_an_intruder(
    px4_monitor: Monitor, tmp_path: Path, run: int
) -> None:
    monitor = px4_monitor
    time.sleep(5 if run == 0 else 1)  # past boot: preflight checks settle
    idle = max(monitor.servo[:4])
    intruder = Intruder(PX4_GCS_PORT, lambda: max(monitor.servo[:4]) > idle + 20)
    try:
        done = thrustmap(
            "spin", f"udpin:127.0.0.1:{PX4_GCS_PORT}", "--motor", "1", "--throttle", "10",
            "--seconds", "6", "--ramp", "0", "--yes", cwd=tmp_path,
        )  # fmt: skip
    finally:
        intruder.close()
    text = done.stdout + done.stderr
    print(f"run {run}: exit {done.returncode}, intruder sent {intruder.sent}, received "
          f"{intruder.received}\n{text}")  # fmt: skip
    assert intruder.sent > 0, text
    assert done.returncode == 1, text
    assert f"{intruder.address} sent to the vehicle link" in text
    assert intruder.received == 0, text
    monitor.wait("outputs at idle", lambda m: max(m.servo[:4]) <= idle and not m.armed, 5)
    print(f"run {run}: outputs after the spin {monitor.servo[:4]} (idle {idle})")


def test_px4_probe_with_and_without_a_key(px4_monitor: Monitor, tmp_path: Path) -> None:
    """PX4 here has no signing key: a probe without one works; with one, every unsigned
    message is refused and it says so in one line (exit 2), never the key."""
    url = f"udpin:127.0.0.1:{PX4_GCS_PORT}"
    plain = thrustmap("probe", url, cwd=tmp_path)
    assert plain.returncode == 0, plain.stdout + plain.stderr
    assert "px4" in plain.stdout
    signed = thrustmap("probe", url, "--signing-key", KEY.hex(), cwd=tmp_path)
    print(signed.stderr)
    assert signed.returncode == 2, signed.stdout + signed.stderr
    lines = signed.stderr.strip().splitlines()
    assert len(lines) == 1 and "unsigned MAVLink message(s)" in lines[0]
    assert KEY.hex() not in signed.stdout + signed.stderr
