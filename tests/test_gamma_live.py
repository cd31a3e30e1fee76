"""`thrustmap gamma live`: γ(B) from MAVLink telemetry, live over UDP and replayed from a .tlog.

The recorded fixture (fixtures/flightlogs/live_hover.tlog, tests/support/telemetry_flight.py)
is a simulated flight with a known γ(B), written by thrustmap's own recorder. Live runs stream
the same messages over UDP loopback from a test thread standing in for the vehicle; it also
collects what `gamma live` sends, which must be rate requests and parameter reads only.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import support.simulate_flight as simulate_flight
from support import telemetry_flight as tf
from support.sockets import wait_until_bound

from thrustmap.cli.gammalive import PANEL_WIDTH, panel_lines
from thrustmap.fitting.df_options import DfOptions
from thrustmap.fitting.gamma_live import LiveGamma
from thrustmap.fitting.mapfile import ThrustMap
from thrustmap.flightlogs.telemetry import Telemetry

ROOT = Path(__file__).resolve().parent.parent
FIX = ROOT / "fixtures" / "flightlogs"
MAP = FIX / "sim_map.json"
LIVE = FIX / tf.FIXTURE


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "thrustmap", *args],
        cwd=cwd,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )


def _gamma(map_path: Path) -> tuple[list[float], list[float]]:
    corr = json.loads(map_path.read_text())["correction"]
    return list(corr["coefficients"]), list(corr["voltage_v"])


def _df_rows(path: Path) -> list[str]:
    """The Df CSV without its flight-id column (the id names the URL or file it came from)."""
    return [line.split(",", 1)[1] for line in path.read_text().splitlines()]


# -- replay ----------------------------------------------------------------------------------


def test_replay_gives_what_extract_and_gamma_fit_give(tmp_path: Path) -> None:
    live = _cli(
        "gamma", "live", f"replay://{LIVE}", "--map", str(MAP), "--mass-kg", "1", "-o", "m.json",
        cwd=tmp_path,
    )  # fmt: skip
    assert live.returncode == 0, live.stderr
    assert "landed and disarmed" in live.stdout
    ext = _cli(
        "flightlog", "extract", str(LIVE), "--map", str(MAP), "--mass-kg", "1", "-o", "e.csv",
        cwd=tmp_path,
    )  # fmt: skip
    assert ext.returncode == 0, ext.stderr
    fit = _cli("gamma", "fit", "e.csv", "--map", str(MAP), "-o", "f.json", cwd=tmp_path)
    assert fit.returncode == 0, fit.stderr
    # the same Df, sample for sample, and the same γ(B)
    assert _df_rows(tmp_path / "m.df.csv") == _df_rows(tmp_path / "e.csv")
    (g_live, box_live), (g_fit, box_fit) = _gamma(tmp_path / "m.json"), _gamma(tmp_path / "f.json")
    assert len(g_live) == len(g_fit)
    np.testing.assert_allclose(g_live, g_fit, rtol=1e-9, atol=1e-12)
    assert box_live == box_fit
    # and near the γ(B) the simulation flew with (voltage from the Df)
    flight = simulate_flight.simulate_hover(tf.LIVE_SIM)
    b = np.linspace(box_live[0], box_live[1], 5)
    truth = flight.gamma(b)
    ours = np.polynomial.polynomial.polyval(b, g_live)
    assert np.max(np.abs(ours / truth - 1)) < 0.02


def test_replay_names_a_stream_without_voltage_and_exits_2(tmp_path: Path) -> None:
    rec = tf.write_tlog(tf.without(tf.flight_messages(), ("SYS_STATUS",)), tmp_path / "nov.tlog")
    res = _cli(
        "gamma", "live", f"replay://{rec}", "--map", str(MAP), "--mass-kg", "1", "-o", "m.json",
        cwd=tmp_path,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    errors = [x for x in res.stderr.splitlines() if x.startswith("error:")]
    assert len(errors) == 1 and "battery voltage" in errors[0], res.stderr
    assert not (tmp_path / "m.json").exists()


def test_replay_names_a_stream_without_acceleration(tmp_path: Path) -> None:
    rec = tf.write_tlog(tf.without(tf.flight_messages(), ("HIGHRES_IMU",)), tmp_path / "noa.tlog")
    res = _cli(
        "gamma", "live", f"replay://{rec}", "--map", str(MAP), "--mass-kg", "1", cwd=tmp_path
    )
    assert res.returncode == 2
    assert "acceleration" in res.stderr.splitlines()[-1]


def test_replay_refuses_a_recording_that_is_not_a_tlog(tmp_path: Path) -> None:
    res = _cli(
        "gamma", "live", f"replay://{MAP}", "--map", str(MAP), "--mass-kg", "1", cwd=tmp_path
    )
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and ".tlog" in res.stderr


def test_refits_as_the_stream_grows_and_panel_fits_80_columns() -> None:
    from pymavlink import mavutil

    tel = Telemetry("replay", "tlog")
    live = LiveGamma(tel, DfOptions(mass_kg=1.0), ThrustMap.load(MAP))
    mlog = mavutil.mavlink_connection(str(LIVE))
    samples = []
    try:
        while (m := mlog.recv_match(blocking=False)) is not None:
            tel.add(m, float(m._timestamp))
            if live.due(float(m._timestamp)):
                st = live.refit(float(m._timestamp))
                samples.append(st.samples)
                for line in panel_lines("replay://x", tel, st, 1.0, {"HIGHRES_IMU": "denied"}):
                    assert len(line) <= PANEL_WIDTH, line
    finally:
        mlog.close()
    assert len(samples) >= 5
    assert samples[0] == 0 and samples[-1] > samples[1]  # grows as the flight goes on
    st = live.compute()
    assert st.samples > 250
    assert st.gamma_fit is not None and st.hover_vehicle is not None
    assert st.hover_ours is not None and abs(st.hover_ours - st.hover_vehicle) < 0.03


# -- live over UDP ------------------------------------------------------------------------------


class Vehicle(threading.Thread):
    """Sends the flight's frames to 127.0.0.1:port, ``speed`` times faster than recorded, and
    keeps what it receives. ``stop_after_s`` (stream time) cuts the link."""

    def __init__(self, port: int, speed: float, stop_after_s: float | None = None) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.speed = speed
        self.stop_after_s = stop_after_s
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.0)
        self.received: list[Any] = []
        self.halt = threading.Event()

    def run(self) -> None:
        from pymavlink.dialects.v20 import common

        parser = common.MAVLink(None)
        parser.robust_parsing = True
        frames = list(tf.packed(tf.flight_messages()))
        t_first = frames[0][0]
        start = time.monotonic()
        for t_us, frame in frames:
            if self.halt.is_set():
                break
            rel = (t_us - t_first) / 1e6
            if self.stop_after_s is not None and rel > self.stop_after_s:
                break
            delay = start + rel / self.speed - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            self.sock.sendto(frame, ("127.0.0.1", self.port))
            try:
                while True:
                    data = self.sock.recv(65535)
                    self.received.extend(parser.parse_buffer(data) or [])
            except (BlockingIOError, OSError):
                pass
        self.sock.close()


def _free_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


def _start_live(tmp_path: Path, port: int, *extra: str) -> subprocess.Popen[str]:
    args = [
        sys.executable, "-m", "thrustmap", "gamma", "live", f"udpin:127.0.0.1:{port}",
        "--map", str(MAP), "--mass-kg", "1", "-o", "live.json", "--record", "live.tlog",
        "--rate-hz", "40", "--settle-s", "0.5", "--link-timeout-s", "2", *extra,
    ]  # fmt: skip
    proc = subprocess.Popen(
        args, cwd=tmp_path, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    if not wait_until_bound(proc.pid, port):  # the interpreter starts and binds the port
        proc.kill()
        _, err = proc.communicate(timeout=10)
        raise AssertionError(f"gamma live never bound udp port {port}: {err[-2000:]}")
    return proc


def test_live_run_replays_to_the_same_gamma_and_only_requests_rates(tmp_path: Path) -> None:
    port = _free_port()
    proc = _start_live(tmp_path, port)
    vehicle = Vehicle(port, speed=4.0)
    vehicle.start()
    try:
        out, err = proc.communicate(timeout=90)
    finally:
        vehicle.halt.set()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "landed and disarmed" in out
    # what gamma live sent: SET_MESSAGE_INTERVAL and parameter reads, nothing else
    sent = {(m.get_type(), getattr(m, "command", None)) for m in vehicle.received}
    assert sent == {("COMMAND_LONG", 511), ("PARAM_REQUEST_READ", None)}, sent
    asked = {int(m.param1) for m in vehicle.received if m.get_type() == "COMMAND_LONG"}
    assert {1, 105, 36, 83} <= asked  # voltage, IMU, outputs, thrust command
    replay = _cli(
        "gamma", "live", "replay://live.tlog", "--map", str(MAP), "--mass-kg", "1",
        "-o", "replay.json", "--rate-hz", "40", "--settle-s", "0.5", cwd=tmp_path,
    )  # fmt: skip
    assert replay.returncode == 0, replay.stderr
    assert _df_rows(tmp_path / "live.df.csv") == _df_rows(tmp_path / "replay.df.csv")
    g_live, box_live = _gamma(tmp_path / "live.json")
    g_replay, box_replay = _gamma(tmp_path / "replay.json")
    np.testing.assert_allclose(g_replay, g_live, rtol=1e-9, atol=1e-12)
    assert box_live == box_replay


def test_lost_link_writes_what_it_had_and_exits_1(tmp_path: Path) -> None:
    port = _free_port()
    proc = _start_live(tmp_path, port)
    vehicle = Vehicle(port, speed=4.0, stop_after_s=30.0)
    vehicle.start()
    try:
        out, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, err
    lines = [x for x in err.splitlines() if x.startswith("error:")]
    assert len(lines) == 1 and "lost link" in lines[0], err
    assert (tmp_path / "live.df.csv").exists() and (tmp_path / "live.df.json").exists()
    assert (tmp_path / "live.tlog").stat().st_size > 10_000


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_interrupt_writes_the_files_and_exits_130(tmp_path: Path, sig: int) -> None:
    port = _free_port()
    proc = _start_live(tmp_path, port)
    vehicle = Vehicle(port, speed=4.0)
    vehicle.start()
    time.sleep(5.0)  # 20 s of flight
    proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=60)
    finally:
        vehicle.halt.set()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert (tmp_path / "live.df.csv").exists() and (tmp_path / "live.tlog").exists()
    assert "wrote Df" in out + err


def test_record_never_replaces_a_file(tmp_path: Path) -> None:
    (tmp_path / "live.tlog").write_bytes(b"precious")
    res = _cli(
        "gamma", "live", "udpin:127.0.0.1:1", "--map", str(MAP), "--mass-kg", "1",
        "--record", "live.tlog", "--start-timeout-s", "1", cwd=tmp_path,
    )  # fmt: skip
    assert res.returncode == 2
    assert (tmp_path / "live.tlog").read_bytes() == b"precious"
    assert "never overwritten" in res.stderr


def test_taking_off_and_landing_count_as_airborne_as_in_a_log() -> None:
    """ArduCopter reports TAKEOFF for its whole climb and LANDING for its whole descent; a log's
    land detector has both airborne (the Df filters drop climbs and margins). UNDEFINED is not
    a landed state."""
    from pymavlink.dialects.v20 import common

    tel = Telemetry("x", "tlog")
    tel.add(common.MAVLink_heartbeat_message(2, 3, 128, 0, 4, 3), 0.0)
    for t, state in enumerate((1, 3, 2, 4, 0, 1), start=1):
        tel.add(common.MAVLink_extended_sys_state_message(0, state), float(t))
    landed = tel.flight_log().landed
    assert landed is not None
    assert landed.values.tolist() == [1.0, 0.0, 0.0, 0.0, 1.0]  # the UNDEFINED row is skipped


def test_a_signing_key_signs_the_link_and_unsigned_vehicles_are_not_heard() -> None:
    """`gamma live --signing-key`: the link signs what it sends (the rate requests) and takes
    no unsigned message as the vehicle's (issue 36: signing on every MAVLink command)."""
    from pymavlink.dialects.v20 import common

    from thrustmap.protocols.mavlink.signing import parse_signing_key, signing_enabled
    from thrustmap.rig.fc.telemetry_stream import LinkLost, open_stream

    port = _free_port()
    key = parse_signing_key("ab" * 32)
    stream = open_stream(f"udpin:127.0.0.1:{port}", signing_key=key, start_timeout_s=1.0)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    unsigned = common.MAVLink(None, srcSystem=1, srcComponent=1)
    beat = unsigned.heartbeat_encode(2, 12, 0, 0, 3).pack(unsigned)  # a PX4 quad, unsigned
    stop = threading.Event()

    def beats() -> None:
        while not stop.is_set():
            sender.sendto(beat, ("127.0.0.1", port))
            time.sleep(0.1)

    th = threading.Thread(target=beats, daemon=True)
    th.start()
    try:
        assert signing_enabled(stream.link)
        with pytest.raises(LinkLost, match="no vehicle heard"):
            for _ in stream.messages():
                pass
    finally:
        stop.set()
        th.join()
        sender.close()
        stream.close()


def test_gamma_live_takes_a_signing_key(tmp_path: Path) -> None:
    out = _cli("gamma", "live", "--help", cwd=tmp_path)
    assert out.returncode == 0 and "--signing-key" in out.stdout
