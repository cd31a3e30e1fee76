"""The motor-stop watchdog (issue 11, item 10) against a simulated FC on a real TCP socket:
thrustmap is killed mid-spin and the watchdog, a separate process, stops the motor."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from support.msp_tcp import MspTcpServer

from thrustmap.core.clock import SimClock
from thrustmap.protocols.transport import open_transport
from thrustmap.rig.fc.msp import MspThrottleOutput, msp_port_url, watchdog_target
from thrustmap.rig.sim.msp_peer import MspPeer
from thrustmap.rig.sim.plant import ConstantPlant
from thrustmap.rig.watchdog import wait_for_parent

PROJECT = Path(__file__).resolve().parents[1]

CHILD = textwrap.dedent(
    """
    import sys, time
    from thrustmap.core.clock import MonotonicClock
    from thrustmap.rig.devices.opening import open_throttle_output
    from thrustmap.rig.sigterm import terminate_as_exception

    url, log, mode = sys.argv[1], sys.argv[2], sys.argv[3]
    out = open_throttle_output(url, MonotonicClock(), kind="msp", watchdog_log=log)
    out.identify()
    out.set_throttle({0: 1300.0})
    if mode == "clean":
        print("spinning", out.watchdog.pid, flush=True)
        with out:
            pass
        print("done", flush=True)
    elif mode == "close":  # the session ends without a stop the FC confirmed
        print("spinning", out.watchdog.pid, flush=True)
        out.close()
        print("closed", flush=True)
    elif mode == "term":
        with terminate_as_exception(), out:
            print("spinning", out.watchdog.pid, flush=True)
            time.sleep(60)
    else:
        print("spinning", out.watchdog.pid, flush=True)
        time.sleep(60)
    """
)


@pytest.fixture
def server() -> Iterator[MspTcpServer]:
    peer = MspPeer(ConstantPlant(4), "betaflight-4", serial_rate_hz=None)
    with MspTcpServer(peer) as srv:
        yield srv


def spawn(server: MspTcpServer, log: Path, mode: str) -> tuple[subprocess.Popen[str], int]:
    env = dict(os.environ, PYTHONPATH=str(PROJECT))
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, server.url, str(log), mode],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    assert child.stdout is not None
    line = child.stdout.readline()
    assert line.startswith("spinning"), f"child said {line!r}"
    return child, int(line.split()[1])


def gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as fh:
            return any(ln.startswith("State:") and "Z" in ln for ln in fh)
    except FileNotFoundError:
        return True


def wait_until(predicate: object, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return True
        time.sleep(0.05)
    return False


def test_sigkill_mid_spin_the_watchdog_stops_and_verifies(
    server: MspTcpServer, tmp_path: Path
) -> None:
    log = tmp_path / "watchdog.log"
    child, watchdog_pid = spawn(server, log, "hold")
    assert server.peer.motor_values[0] > 1000  # spinning
    killed_at = time.monotonic()
    child.send_signal(signal.SIGKILL)
    child.wait(timeout=5)
    assert wait_until(lambda: server.peer.motors_at_rest, 10.0), server.peer.motor_values
    stopped_in_s = time.monotonic() - killed_at
    assert wait_until(lambda: gone(watchdog_pid), 10.0)
    text = log.read_text(encoding="utf-8")
    assert "ended without a confirmed motor stop" in text
    assert "motors stopped" in text and "verified by MSP_MOTOR" in text
    after = [values for t, _, values in server.set_motors if t >= killed_at]
    assert after and all(v <= 1000 for values in after for v in values)  # only stops
    assert server.connections == 2  # the dead session's, then the watchdog's
    assert stopped_in_s < 5.0
    # arming re-enabled, as the driver does after its own verified stop
    assert not server.peer.arming_disable_flags


def test_a_clean_exit_disarms_the_watchdog(server: MspTcpServer, tmp_path: Path) -> None:
    log = tmp_path / "watchdog.log"
    child, watchdog_pid = spawn(server, log, "clean")
    assert child.stdout is not None
    assert child.stdout.readline().strip() == "done"
    assert child.wait(timeout=10) == 0
    assert wait_until(lambda: gone(watchdog_pid), 5.0)
    time.sleep(0.3)
    assert server.connections == 1  # the watchdog never reopened the port
    assert server.peer.motors_at_rest
    assert "disarmed" in log.read_text(encoding="utf-8")


def test_sigterm_is_a_clean_stop_and_the_watchdog_stays_out(
    server: MspTcpServer, tmp_path: Path
) -> None:
    """SIGTERM unwinds (the driver's exit stops and verifies); the watchdog only watches."""
    child, watchdog_pid = spawn(server, tmp_path / "watchdog.log", "term")
    child.send_signal(signal.SIGTERM)
    child.wait(timeout=10)
    assert server.peer.motors_at_rest
    assert wait_until(lambda: gone(watchdog_pid), 5.0)
    assert server.connections == 1


def test_wait_for_parent_disarm_eof_and_dead_parent() -> None:
    read_fd, write_fd = os.pipe()
    with os.fdopen(read_fd, "rb", buffering=0) as reader:
        os.write(write_fd, b"disarm\n")
        assert wait_for_parent(reader, os.getppid(), 0.05) is True
    read_fd, write_fd = os.pipe()
    with os.fdopen(read_fd, "rb", buffering=0) as reader:
        os.close(write_fd)  # the parent died: EOF without disarm
        assert wait_for_parent(reader, os.getppid(), 0.05) is False
    read_fd, write_fd = os.pipe()
    with os.fdopen(read_fd, "rb", buffering=0) as reader:
        # the pipe stays open (held elsewhere) but the parent pid is not ours: gone
        assert wait_for_parent(reader, 2**22 + 12345, 0.05) is False
    os.close(write_fd)


def test_no_watchdog_for_simulated_or_replayed_ports() -> None:
    assert watchdog_target("sim://betaflight") is None
    assert watchdog_target("replay://x.jsonl") is None
    assert watchdog_target("record://sim://betaflight?file=x.jsonl") is None
    assert watchdog_target("record://socket://127.0.0.1:5761?file=x.jsonl") == (
        "socket://127.0.0.1:5761"
    )
    assert watchdog_target("/dev/ttyACM0") == "/dev/ttyACM0"
    assert msp_port_url("tcp://127.0.0.1:5761") == "socket://127.0.0.1:5761"
    assert msp_port_url("tcp:localhost:5761") == "socket://localhost:5761"
    from thrustmap.rig.devices.urls import load_sim_peers

    load_sim_peers()  # the rig binds sim://betaflight (this test opens it below the rig)
    clock = SimClock()
    out = MspThrottleOutput(
        open_transport("sim://betaflight", clock=clock, timeout=0), clock, url="sim://betaflight"
    )
    out.set_throttle({0: 600.0})
    assert out.watchdog is None
    assert out.stop_and_verify()
    out.close()


def test_a_probe_sends_only_stops_and_disarms_its_watchdog(
    server: MspTcpServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import thrustmap.rig.devices.opening as opening
    import thrustmap.rig.devices.probe as probe
    from thrustmap.core.clock import MonotonicClock

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))  # the default log goes here

    log = tmp_path / "watchdog.log"
    output = opening.open_throttle_output(
        server.url, MonotonicClock(), kind="msp", watchdog_log=str(log)
    )
    with output:
        output.identify()
        watchdog = output.watchdog  # type: ignore[attr-defined]
        assert watchdog is not None  # running before any motor command
    assert watchdog.process.wait(timeout=5) == 0
    assert "disarmed" in log.read_text(encoding="utf-8")
    report = probe.probe_device(server.url, MonotonicClock(), kind="msp")
    assert report.identity is not None and report.identity.kind == "betaflight"
    assert all(v <= 1000 for _, _, values in server.set_motors for v in values)
    time.sleep(0.3)
    assert server.connections == 2  # no watchdog ever reopened the port
    assert "disarmed" in (tmp_path / "state" / "thrustmap" / "watchdog.log").read_text("utf-8")


def test_an_unconfirmed_stop_is_handed_to_the_watchdog(
    server: MspTcpServer, tmp_path: Path
) -> None:
    """The session ended (the port closed) with a motor commanded and no confirmed stop: the
    watchdog, not disarmed, reopens the port and stops it."""
    log = tmp_path / "watchdog.log"
    child, watchdog_pid = spawn(server, log, "close")
    assert child.stdout is not None
    assert child.stdout.readline().strip() == "closed"
    assert wait_until(lambda: server.peer.motors_at_rest, 10.0), server.peer.motor_values
    assert wait_until(lambda: gone(watchdog_pid), 10.0)
    child.wait(timeout=10)
    assert server.connections == 2
    assert "verified by MSP_MOTOR" in log.read_text(encoding="utf-8")
