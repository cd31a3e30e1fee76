"""Record the real firmware's side of thrustmap's link claims once (for fixtures/firmware/).

    python -m support.record_firmware ardupilot|px4 BINARY OUT_DIR

Runs, in a network namespace of its own (``unshare -n``, loopback only), the SITL binary
(ArduCopter ``--model quad``; PX4 SIH quadx) and the real CLI (``python -m thrustmap``) against
it through ``record://``, one recording per way out of a motor test:

- ``spin``: the end of the spin; ``spin_sigint`` / ``spin_sigterm``: the signal once the motor
  turns; ``spin_sigkill``: thrustmap killed, the firmware ends its test itself;
  ``spin_lostlink``: the link cut (both ways) once the motor turns;
- ``spin_intruder``: a second local sender on thrustmap's ``udpin`` port once the motor turns
  (the locked link; the driver's exception way out);
- ``probe``, and on ArduPilot ``probe_signed`` / ``probe_unsigned`` after SETUP_SIGNING.

thrustmap's link goes through a relay of this script (vehicle -> relay -> ``udpin`` port), the
only way to cut it; it passes on the vehicle's datagrams only (see ``Relay``), and an intruder
run fails when thrustmap does not name the second sender. Beside each ``<name>.jsonl``
(thrustmap's own transcript) a ``<name>.monitor.tlog`` records what the vehicle reported on
ANOTHER of its ports meanwhile (heartbeat, outputs, status text): the stop as the firmware did
it, whatever thrustmap said. ``<name>.json`` holds the exit code, the output and, for the
intruder, what it sent and got, the relay's addresses and strangers, and the UDP sockets.
Every process it starts is ended on every way out.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
HOME = "-35.363261,149.165230,584,353"  # ArduPilot's test field (CMAC)
PX4_INSTANCE = 6
RELAY_PORT = 14550  # where the vehicle sends (PX4's GCS link always sends here)
UDPIN_PORT = 14600  # where thrustmap listens
KEY = bytes(range(7, 39))  # the signing key of the ArduPilot recordings (a test key)
SPIN = ["--motor", "1", "--throttle", "10", "--ramp", "0", "--yes"]
MONITOR_TYPES = ("HEARTBEAT", "SERVO_OUTPUT_RAW", "STATUSTEXT", "COMMAND_ACK")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + str(ROOT / "tests")
    env.pop("THRUSTMAP_MAVLINK_SIGNING_KEY", None)
    return env


class Relay:
    """vehicle -> RELAY_PORT -> thrustmap's udpin port and back; ``cut()`` drops both ways.

    Up it forwards only what the vehicle sends (the first address that speaks to its port),
    down only what thrustmap's udpin port sends. Anything else is dropped and counted by address
    (``strangers``): forwarded, a second sender would reach thrustmap with the relay's address,
    the locked peer's, and pass for the vehicle's own traffic (the 2026-11-28 PX4 run that
    missed it: the second sender's heartbeats arrived that way, never from its own address).
    """

    def __init__(self) -> None:
        self.vehicle_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.vehicle_side.bind(("127.0.0.1", RELAY_PORT))
        self.host_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.host_side.bind(("127.0.0.1", 0))
        self.thrustmap = ("127.0.0.1", UDPIN_PORT)
        self.vehicle: Any = None
        self.strangers: dict[str, int] = {}
        self.cut_at: float | None = None
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._pump, args=(True,), daemon=True),
            threading.Thread(target=self._pump, args=(False,), daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _pump(self, up: bool) -> None:
        src = self.vehicle_side if up else self.host_side
        src.settimeout(0.1)
        while not self._stop.is_set():
            try:
                data, addr = src.recvfrom(65535)
            except TimeoutError:
                continue
            except OSError:
                return
            if up and self.vehicle is None:
                self.vehicle = addr
            if addr != (self.vehicle if up else self.thrustmap):
                key = "{}:{}".format(*addr)
                self.strangers[key] = self.strangers.get(key, 0) + 1
                continue
            if self.cut_at is not None:
                continue
            if up:
                self.host_side.sendto(data, self.thrustmap)
            elif self.vehicle is not None:
                self.vehicle_side.sendto(data, self.vehicle)

    def addresses(self) -> dict[str, str]:
        """Its two sockets as ``host:port`` (thrustmap locks to ``host_side``)."""
        return {
            "vehicle_side": "{}:{}".format(*self.vehicle_side.getsockname()),
            "host_side": "{}:{}".format(*self.host_side.getsockname()),
        }

    def cut(self) -> None:
        self.cut_at = time.time()

    def restore(self) -> None:
        self.cut_at = None

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2)
        self.vehicle_side.close()
        self.host_side.close()


class Monitor:
    """The vehicle on another of its ports: outputs, armed state and text, logged to a .tlog."""

    def __init__(self, url: str, px4: bool) -> None:
        from pymavlink import mavutil

        self.conn: Any = mavutil.mavlink_connection(url, source_system=254, source_component=191)
        self.px4 = px4
        self.servo: list[int] = []
        self.armed = False
        self._log: Any = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def start_log(self, path: Path) -> None:
        with self._lock:
            self._log = path.open("wb")

    def stop_log(self) -> None:
        with self._lock:
            if self._log is not None:
                self._log.close()
            self._log = None

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.1)
            if msg is None or msg.get_type() not in MONITOR_TYPES:
                continue
            with self._lock:
                if self._log is not None:
                    stamp = int(time.time() * 1e6).to_bytes(8, "big")
                    self._log.write(stamp + bytes(msg.get_msgbuf()))
                if msg.get_type() == "SERVO_OUTPUT_RAW" and msg.port == 0:
                    self.servo = [getattr(msg, f"servo{i}_raw") for i in range(1, 9)]
                elif msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    self.armed = bool(msg.base_mode & 128)

    def ask_outputs(self) -> None:
        """SERVO_OUTPUT_RAW at 10 Hz (and a heartbeat: PX4 wants a partner on its link)."""
        if self.px4:
            self.conn.mav.heartbeat_send(6, 8, 0, 0, 0)
        self.conn.mav.command_long_send(1, 1, 511, 0, 36, 100_000, 0, 0, 0, 0, 0)

    def wait(self, what: str, done: Any, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if done(self):
                return
            time.sleep(0.05)
        raise RuntimeError(f"the vehicle never showed {what}: servo {self.servo}")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.stop_log()
        self.conn.close()


def start_sitl(autopilot: str, binary: Path, work: Path) -> subprocess.Popen[bytes]:
    out = open(work / "sitl.out", "wb")  # noqa: SIM115 - the process owns it
    if autopilot == "ardupilot":
        tree = binary.resolve().parents[3]  # <tree>/build/sitl/bin/arducopter
        defaults = tree / "Tools" / "autotest" / "default_params" / "copter.parm"
        args = [
            str(binary), "--model", "quad", "--speedup", "1", "-I0", "--home", HOME,
            "--defaults", str(defaults), "--serial0", "tcp:0",
            "--serial1", f"udpclient:127.0.0.1:{RELAY_PORT}",
        ]  # fmt: skip
        return subprocess.Popen(args, cwd=work, stdout=out, stderr=subprocess.STDOUT)
    build = binary.resolve().parents[1]  # <build>/bin/px4
    env = dict(
        os.environ, PX4_SYS_AUTOSTART="10040", PX4_SIMULATOR="sihsim", PX4_SIM_MODEL="sihsim_quadx"
    )
    return subprocess.Popen(
        [str(binary), "-i", str(PX4_INSTANCE), "-d", str(build / "etc")],
        cwd=work, env=env, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
    )  # fmt: skip


def connect_monitor(autopilot: str) -> Monitor:
    url = (
        "tcp:127.0.0.1:5760"
        if autopilot == "ardupilot"
        else f"udpout:127.0.0.1:{14580 + PX4_INSTANCE}"
    )
    deadline = time.monotonic() + 120
    while True:
        try:
            monitor = Monitor(url, autopilot == "px4")
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)
    while not monitor.servo and time.monotonic() < deadline + 120:
        monitor.ask_outputs()
        time.sleep(1.0)
    monitor.wait("SERVO_OUTPUT_RAW", lambda m: bool(m.servo), 1)
    time.sleep(15)  # past boot: ArduPilot refuses motor tests while initialising
    return monitor


def thrustmap_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "thrustmap", *args]


def udpin_record(out: Path, name: str) -> str:
    return f"record://udpin:127.0.0.1:{UDPIN_PORT}?file={out / (name + '.jsonl')}"


def run_spin(name: str, out: Path, monitor: Monitor, relay: Relay, way: str) -> dict[str, Any]:
    """One spin of motor 1 at 10 % (6 s), ended by ``way``: end, sigint, sigterm, sigkill,
    lostlink or intruder."""
    idle = max(monitor.servo[:4])
    monitor.start_log(out / f"{name}.monitor.tlog")
    result: dict[str, Any] = {"way": way, "idle_us": idle}
    intruder = Intruder() if way == "intruder" else None
    if intruder is not None:
        result["relay"] = relay.addresses()
        if intruder.address in result["relay"].values():  # it would pass for the locked peer
            raise RuntimeError(f"the second sender shares the relay's address {intruder.address}")
    proc = subprocess.Popen(
        thrustmap_cmd("spin", udpin_record(out, name), *SPIN, "--seconds", "6"),
        env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        if way != "end":
            monitor.wait("the motor turning", lambda m: max(m.servo[:4]) > idle + 20, 60)
            time.sleep(1.0)
            result["motor_turning_us"] = max(monitor.servo[:4])
            result["acted_unix_s"] = time.time()  # the monitor .tlog's clock
            if way in ("sigint", "sigterm", "sigkill"):
                sig = {
                    "sigint": signal.SIGINT,
                    "sigterm": signal.SIGTERM,
                    "sigkill": signal.SIGKILL,
                }
                proc.send_signal(sig[way])
            elif way == "lostlink":
                relay.cut()
            elif intruder is not None:
                relay.strangers.clear()
                intruder.start()
                result["udp_sockets"] = udp_sockets((UDPIN_PORT, RELAY_PORT))
        stdout, stderr = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if intruder is not None:
            result.update(intruder.close(), relay_strangers=dict(relay.strangers))
    monitor.wait("outputs at idle", lambda m: max(m.servo[:4]) <= idle and not m.armed, 30)
    time.sleep(2.0)  # what follows the stop
    monitor.stop_log()
    relay.restore()
    result.update(exit=proc.returncode, stdout=stdout, stderr=stderr)
    (out / f"{name}.json").write_text(json.dumps(result, indent=1) + "\n")
    if intruder is not None and f"{intruder.address} sent to the vehicle link" not in stderr:
        raise RuntimeError(
            f"{name}: the second sender ({intruder.address}) sent {intruder.sent} datagram(s) "
            f"but thrustmap never named it (exit {proc.returncode}); see {name}.json"
        )
    return result


def udp_sockets(ports: tuple[int, ...]) -> list[dict[str, Any]]:
    """The UDP sockets of this namespace bound to ``ports`` (/proc/net/udp): address, the
    datagrams queued and those the kernel dropped (a full receive buffer), to tell afterwards
    whether a second sender's datagrams could have reached thrustmap's socket."""
    found = []
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        fields = line.split()
        host_hex, port_hex = fields[1].split(":")
        if int(port_hex, 16) in ports:
            host = socket.inet_ntoa(bytes.fromhex(host_hex)[::-1])
            queued = int(fields[4].split(":")[1], 16)
            found.append(
                {"local": f"{host}:{int(port_hex, 16)}", "rx_queue_bytes": queued,
                 "drops": int(fields[-1]), "inode": int(fields[9])}
            )  # fmt: skip
    return found


class Intruder:
    """A second local socket sending HEARTBEATs to thrustmap's udpin port once started."""

    def __init__(self) -> None:
        from thrustmap.protocols.mavlink import codec as mav
        from thrustmap.protocols.mavlink import encode as enc

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.address = "{}:{}".format(*self.sock.getsockname())
        self.hb = mav.MavlinkCodec(255, 190).encode(
            enc.heartbeat_message(mav.Autopilot.INVALID, armed=False, vehicle_type=6)
        )
        self.sent = self.received = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.sock.sendto(self.hb, ("127.0.0.1", UDPIN_PORT))
            self.sent += 1
            with contextlib.suppress(TimeoutError):
                self.received += len(self.sock.recv(65535))

    def close(self) -> dict[str, Any]:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        time.sleep(0.2)
        self.sock.settimeout(0)
        try:
            while True:
                self.received += len(self.sock.recv(65535))
        except OSError:
            pass
        self.sock.close()
        return {
            "intruder": self.address,
            "intruder_sent": self.sent,
            "intruder_received": self.received,
        }


def run_probe(name: str, out: Path, *extra: str) -> dict[str, Any]:
    done = subprocess.run(
        thrustmap_cmd("probe", udpin_record(out, name), *extra),
        env=_env(), capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    result = {"exit": done.returncode, "stdout": done.stdout, "stderr": done.stderr}
    (out / f"{name}.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


def run_signing(out: Path, monitor: Monitor) -> None:
    """ArduPilot: the key set through SETUP_SIGNING on its first port; thrustmap's port (the
    second) then takes only signed messages. Signing is turned off again afterwards."""
    stamp = int((time.time() - 1420070400) * 100_000)
    monitor.conn.mav.setup_signing_send(1, 1, list(KEY), stamp)
    time.sleep(2.0)
    keyfile = out / "signing.key"
    keyfile.write_text(KEY.hex())
    try:
        run_probe("probe_unsigned", out)
        run_probe("probe_signed", out, "--signing-key", str(keyfile))
    finally:
        keyfile.unlink()
        monitor.conn.setup_signing(KEY, sign_outgoing=True)
        monitor.conn.mav.setup_signing_send(1, 1, [0] * 32, 0)


WAYS = ("end", "intruder", "sigint", "sigterm", "sigkill", "lostlink")


def record(autopilot: str, binary: Path, out: Path, ways: tuple[str, ...]) -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    work = out / "work"
    work.mkdir(exist_ok=True)
    sitl = start_sitl(autopilot, binary, work)
    relay = Relay()
    monitor: Monitor | None = None
    summary: dict[str, Any] = {}
    try:
        monitor = connect_monitor(autopilot)
        summary["probe"] = run_probe("probe", out)["exit"]
        for way in ways:
            name = "spin" if way == "end" else f"spin_{way}"
            summary[name] = run_spin(name, out, monitor, relay, way)["exit"]
            time.sleep(3)
        if autopilot == "ardupilot":
            run_signing(out, monitor)
    finally:
        if monitor is not None:
            monitor.close()
        relay.close()
        sitl.terminate()
        try:
            sitl.wait(timeout=10)
        except subprocess.TimeoutExpired:
            sitl.kill()
            sitl.wait()
        Path(f"/tmp/px4-sock-{PX4_INSTANCE}").unlink(missing_ok=True)
    return summary


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("autopilot", choices=["ardupilot", "px4"])
    ap.add_argument("binary", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument(
        "--ways", default=",".join(WAYS), help="comma-separated subset of " + ",".join(WAYS)
    )
    ap.add_argument("--in-netns", action="store_true", help="(internal) already in a namespace")
    args = ap.parse_args(argv)
    if not args.in_netns and shutil.which("unshare") and os.geteuid() == 0:
        inner = [
            sys.executable,
            "-m",
            "support.record_firmware",
            *(argv or sys.argv[1:]),
            "--in-netns",
        ]
        script = "ip link set lo up 2>/dev/null || true; exec " + " ".join(f"'{a}'" for a in inner)
        sys.exit(subprocess.call(["unshare", "-n", "sh", "-c", script], env=_env()))
    ways = tuple(w for w in args.ways.split(",") if w)
    print(json.dumps(record(args.autopilot, args.binary.resolve(), args.out.resolve(), ways)))


if __name__ == "__main__":
    main()
