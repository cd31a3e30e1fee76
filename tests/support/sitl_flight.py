"""Fly a real SITL vehicle while `thrustmap gamma live` listens (for tests/test_gamma_live_sitl.py).

    python -m support.sitl_flight ardupilot|px4 BINARY OUT_DIR [--hover-s 30]

Runs, in a network namespace of its own when it can (``unshare -n``, loopback only), the SITL
binary (ArduCopter: its built-in quad, ``--model quad``; PX4: SIH quadx), `thrustmap gamma live`
on the ground-station port (ArduPilot SERIAL1 -> udp 127.0.0.1:14550, PX4's GCS link -> 14550)
with ``--record``, and a scripted flight on another port (ArduPilot SERIAL0 tcp 5760, PX4's
offboard link 14540): takeoff, hover and slow manoeuvres, landing. thrustmap only listens.
It prints one JSON line: the exit code of `gamma live`, its files and the SITL's own log.
Every process it starts is ended on every way out.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
HOME = "-35.363261,149.165230,584,353"  # ArduPilot's test field (CMAC)
#: PX4 instance: its lock and socket live in /tmp, shared by every network namespace; PX4 then
#: streams its ground-station link to 14550 and its offboard link to 14540 + instance
PX4_INSTANCE = 7


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + str(ROOT / "tests")
    return env


def start_ardupilot(binary: Path, work: Path) -> subprocess.Popen[bytes]:
    tree = binary.resolve().parents[3]  # <tree>/build/sitl/bin/arducopter
    defaults = tree / "Tools" / "autotest" / "default_params" / "copter.parm"
    extra = work / "battery.parm"
    # a battery that drains over the flight, so γ is seen at more than one voltage
    extra.write_text("SIM_BATT_CAP_AH 1.5\nBATT_CAPACITY 1500\n")
    args = [
        str(binary), "--model", "quad", "--speedup", "1", "-I0", "--home", HOME,
        "--defaults", f"{defaults},{extra}",
        "--serial0", "tcp:0", "--serial1", "udpclient:127.0.0.1:14550",
    ]  # fmt: skip
    return subprocess.Popen(
        args, cwd=work, stdout=open(work / "sitl.out", "wb"), stderr=subprocess.STDOUT
    )


def start_px4(binary: Path, work: Path) -> subprocess.Popen[bytes]:
    build = binary.resolve().parents[1]  # <build>/bin/px4
    env = dict(os.environ, PX4_SIM_MODEL="sihsim_quadx", PX4_SIMULATOR="sihsim")
    return subprocess.Popen(
        [str(binary), "-i", str(PX4_INSTANCE), "-d", str(build / "etc")],
        cwd=work,
        env=env,
        stdout=open(work / "sitl.out", "wb"),
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
    )


def fly_ardupilot(hover_s: float) -> None:
    from pymavlink import mavutil

    m = mavutil.mavlink_connection("tcp:127.0.0.1:5760", source_system=250, source_component=190)
    m.wait_heartbeat(timeout=60)
    m.mav.request_data_stream_send(m.target_system, m.target_component, 0, 4, 1)

    def heartbeat(timeout: float = 3.0) -> Any:
        return m.recv_match(type="HEARTBEAT", blocking=True, timeout=timeout)

    deadline = time.time() + 240
    while True:
        m.set_mode("GUIDED")
        m.mav.command_long_send(m.target_system, m.target_component, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        hb = heartbeat()
        hb = heartbeat() if hb is not None and not hb.base_mode & 128 else hb
        if hb is not None and hb.base_mode & 128:
            break
        if time.time() > deadline:
            raise RuntimeError("ArduCopter SITL did not arm in 240 s")
        time.sleep(2)
    m.mav.command_long_send(m.target_system, m.target_component, 22, 0, 0, 0, 0, 0, 0, 0, 10)
    end = time.time() + 60
    while time.time() < end:
        p = m.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=2)
        if p is not None and p.relative_alt > 9500:
            break

    def velocity(vn: float, ve: float, secs: float) -> None:
        end = time.time() + secs
        while time.time() < end:
            m.mav.set_position_target_local_ned_send(
                0, m.target_system, m.target_component, 1, 0b0000111111000111,
                0, 0, 0, vn, ve, 0, 0, 0, 0, 0, 0,
            )  # fmt: skip
            m.recv_match(blocking=True, timeout=0.2)

    velocity(0, 0, hover_s / 2)
    for vn, ve in ((0.5, 0), (0, 0.5), (-0.5, 0), (0, -0.5)):
        velocity(vn, ve, 8)
    velocity(0, 0, hover_s / 2)
    m.set_mode("LAND")
    end = time.time() + 120
    while time.time() < end:
        hb = heartbeat()
        if hb is not None and not hb.base_mode & 128:
            break
    m.close()


def fly_px4(hover_s: float) -> None:
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(
        f"udpin:127.0.0.1:{14540 + PX4_INSTANCE}", source_system=250, source_component=190
    )
    m.wait_heartbeat(timeout=60)
    stop = threading.Event()

    def beat() -> None:
        while not stop.is_set():
            m.mav.heartbeat_send(6, 8, 0, 0, 4)
            time.sleep(1)

    threading.Thread(target=beat, daemon=True).start()

    def cmd(c: int, *p: float) -> None:
        q = [*p] + [0.0] * (7 - len(p))
        m.mav.command_long_send(m.target_system, m.target_component, c, 0, *q)

    def armed() -> bool | None:
        hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=3)
        return None if hb is None else bool(hb.base_mode & 128)

    nan = float("nan")
    try:
        deadline = time.time() + 240
        while True:
            cmd(400, 1)
            time.sleep(1)
            if armed():
                break
            if time.time() > deadline:
                raise RuntimeError("PX4 SITL did not arm in 240 s")
            time.sleep(2)
        cmd(22, 0, 0, 0, nan, nan, nan, nan)
        end = time.time() + 60
        while time.time() < end:
            p = m.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=3)
            if p is not None and p.relative_alt > 2300:
                break
        time.sleep(max(hover_s / 2, 5))
        p0 = m.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=3)
        lat0, lon0 = p0.lat / 1e7, p0.lon / 1e7
        for dn, de in ((4, 0), (4, 4), (0, 4), (0, 0)):
            lat = lat0 + dn / 111111.0
            lon = lon0 + de / (111111.0 * math.cos(math.radians(lat0)))
            m.mav.command_int_send(
                m.target_system, m.target_component, 0, 192, 0, 0, 1.0, 1, 0, nan,
                int(lat * 1e7), int(lon * 1e7), nan,
            )  # fmt: skip
            time.sleep(8)
        time.sleep(hover_s / 2)
        cmd(21, 0, 0, 0, nan, nan, nan, nan)
        end = time.time() + 120
        while time.time() < end:
            if armed() is False:
                break
    finally:
        stop.set()
        m.close()


def newest_log(work: Path, suffix: str) -> Path | None:
    logs = sorted(work.rglob(f"*{suffix}"), key=lambda p: p.stat().st_mtime)
    return logs[-1] if logs else None


def run(autopilot: str, binary: Path, out: Path, hover_s: float, mass_kg: float) -> dict[str, Any]:
    from support import sitl_maps

    out.mkdir(parents=True, exist_ok=True)
    tmap = sitl_maps.ardupilot_map() if autopilot == "ardupilot" else sitl_maps.px4_map()
    map_path = out / "map.json"
    tmap.save(map_path)
    sitl = (start_ardupilot if autopilot == "ardupilot" else start_px4)(binary, out)
    live: subprocess.Popen[str] | None = None
    result: dict[str, Any] = {"autopilot": autopilot, "out": str(out), "map": str(map_path)}
    live_out = open(out / "live.out", "w")  # noqa: SIM115 - closed below, after the process
    try:
        live = subprocess.Popen(
            [
                sys.executable, "-m", "thrustmap", "gamma", "live", "udpin:127.0.0.1:14550",
                "--map", str(map_path), "--mass-kg", str(mass_kg), "-o", str(out / "live.json"),
                "--record", str(out / "live.tlog"), "--no-panel", "--start-timeout-s", "120",
            ],
            env=_env(), stdout=live_out, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip
        (fly_ardupilot if autopilot == "ardupilot" else fly_px4)(hover_s)
        result["live_exit"] = live.wait(timeout=60)
    except Exception as exc:
        result["error"] = f"{type(exc).__name__}: {exc}"
    finally:
        for proc in (live, sitl):
            if proc is not None and proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        live_out.close()
    suffix = ".BIN" if autopilot == "ardupilot" else ".ulg"
    log = newest_log(out, suffix)
    result["log"] = None if log is None else str(log)
    result["live_out"] = (out / "live.out").read_text() if (out / "live.out").exists() else ""
    return result


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("autopilot", choices=["ardupilot", "px4"])
    ap.add_argument("binary", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--hover-s", type=float, default=30.0)
    ap.add_argument("--in-netns", action="store_true", help="(internal) already in a namespace")
    args = ap.parse_args(argv)
    if not args.in_netns and shutil.which("unshare") and os.geteuid() == 0:
        inner = [sys.executable, "-m", "support.sitl_flight", *(argv or sys.argv[1:]), "--in-netns"]
        script = "ip link set lo up 2>/dev/null || true; exec " + " ".join(f"'{a}'" for a in inner)
        sys.exit(subprocess.call(["unshare", "-n", "sh", "-c", script], env=_env()))
    mass = 3.0 if args.autopilot == "ardupilot" else 1.0
    print(json.dumps(run(args.autopilot, args.binary, args.out, args.hover_s, mass)))


if __name__ == "__main__":
    main()
