"""``thrustmap ports/probe/spin`` through the real CLI against sim:// peers on a simulated clock.

Every spin exit path (normal end, exception, Ctrl-C, SIGTERM) must leave the simulated FC's
motors commanded to stop, and the CLI must say the stop was verified."""

from __future__ import annotations

import json
import os
import re
import signal
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
from click.testing import CliRunner, Result

import thrustmap.protocols.peer as protocols_peer
from thrustmap.cli import cli, hardware
from thrustmap.core.clock import MonotonicClock, SimClock
from thrustmap.core.errors import ConfigError, SafetyError
from thrustmap.protocols.msp.messages import ArmingDisable
from thrustmap.protocols.msp.motor import MotorProtocol, native_to_external
from thrustmap.protocols.peer import BytePeer
from thrustmap.protocols.urlhandlers import protocol_sim
from thrustmap.rig import session
from thrustmap.rig.fc.msp import MspThrottleOutput
from thrustmap.rig.sigterm import Terminated

# --------------------------------------------------------------------------- harness


@dataclass
class Spy:
    """A peer created by a sim:// URL, with a snapshot of its motor state after every write."""

    name: str
    inner: Any
    history: list[Any] = field(default_factory=list)
    times: list[float] = field(default_factory=list)

    def write(self, data: bytes, now_s: float) -> None:
        self.inner.write(data, now_s)
        self.history.append(self.motor_state())
        self.times.append(now_s)

    def stopped_at(self, after_s: float, at_rest: Any) -> float | None:
        """The first write at or after ``after_s`` that left the motors at rest."""
        for t, state in zip(self.times, self.history, strict=True):
            if t >= after_s and state == at_rest:
                return t
        return None

    def read(self, now_s: float) -> bytes:
        data: bytes = self.inner.read(now_s)
        return data

    def close(self) -> None:
        close = getattr(self.inner, "close", None)
        if callable(close):
            close()

    def motor_state(self) -> Any:
        peer = self.inner
        if self.name in ("betaflight", "inav"):
            return tuple(peer.motor_values)
        if self.name == "px4":
            return dict(peer.running_motors())
        if self.name == "ardupilot":
            return peer.motor_test_running
        if self.name == "line-stand":
            return peer.throttle_pct
        if self.name == "tyto-1585":
            return peer.esc_us
        return None


@pytest.fixture
def peers(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[Spy]]:
    import thrustmap.rig.sim.peers  # noqa: F401 - the bench-plant registrations

    created: list[Spy] = []
    original = protocols_peer.create_peer

    def spy(name: str, options: Any = None) -> BytePeer:
        wrapped = Spy(name.lower(), original(name, options))
        created.append(wrapped)
        return wrapped

    monkeypatch.setattr(protocol_sim, "create_peer", spy)
    yield created


class Trigger:
    """Installs a SimClock for the CLI that does ``action`` once, when it passes ``at_s``."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, at_s: float, action: Any) -> None:
        self.at_s = at_s
        self.action = action
        self.fired_at: float | None = None
        self.clocks: list[SimClock] = []
        trigger = self

        class TriggerClock(SimClock):
            def __init__(self) -> None:
                super().__init__()
                trigger.clocks.append(self)

            def sleep_s(self, duration_s: float) -> None:
                super().sleep_s(duration_s)
                if trigger.fired_at is None and self.now_s() >= trigger.at_s:
                    trigger.fired_at = self.now_s()
                    trigger.fire()

        monkeypatch.setattr(session, "SimClock", TriggerClock)  # the one clock rule

    def fire(self) -> None:
        if callable(self.action):
            self.action()
            return
        if self.action == "exception":
            raise RuntimeError("driver blew up")
        if self.action == "ctrl-c":
            raise KeyboardInterrupt
        if self.action == "sigterm":
            # Only with our handler in place: the default one would end the test process.
            assert signal.getsignal(signal.SIGTERM) not in (signal.SIG_DFL, signal.SIG_IGN, None)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        raise AssertionError(self.action)


def run(*args: str, input: str | None = None) -> Result:  # noqa: A002 - click's name
    return CliRunner().invoke(cli, list(args), input=input)


def dshot_external(pct: float) -> int:
    native = 48.0 + pct / 100.0 * 1999.0
    return int(round(native_to_external(native, MotorProtocol.DSHOT600)))


# --------------------------------------------------------------------------- spin: MSP


def test_spin_betaflight_normal_end(peers: list[Spy]) -> None:
    result = run(
        "spin",
        "sim://betaflight?rotors=4",
        "--motor",
        "2",
        "--throttle",
        "15",
        "--seconds",
        "3",
        "--yes",
    )
    assert result.exit_code == 0, result.output
    (fc,) = peers
    assert max(state[1] for state in fc.history) == dshot_external(15.0)
    assert all(state[i] == 1000 for state in fc.history for i in (0, 2, 3))  # others stay still
    assert fc.inner.motor_values == [1000] * 4
    assert not fc.inner.arming_disable_flags & ArmingDisable.MSP  # arming re-enabled
    assert "motor 2 stopped (verified)" in result.output
    lines = [ln for ln in result.output.splitlines() if ln.startswith("t=")]
    assert len(lines) == 3
    assert " 15.0 % " in lines[1] and "dshot" in lines[1]
    rpm = int(lines[2].split(" rpm")[0].rsplit(" ", 1)[-1])
    assert rpm > 5000  # the plant's motor 2 spun (read back from MOTOR_TELEMETRY)


@pytest.mark.parametrize(
    ("action", "exit_code", "message"),
    [
        ("exception", 1, "driver blew up"),
        ("ctrl-c", 130, "interrupted (Ctrl-C)"),
        ("sigterm", 130, "terminated (signal 15)"),
    ],
)
def test_spin_betaflight_every_way_out_stops_and_verifies(
    peers: list[Spy], monkeypatch: pytest.MonkeyPatch, action: str, exit_code: int, message: str
) -> None:
    previous = signal.getsignal(signal.SIGTERM)
    trigger = Trigger(monkeypatch, 1.5, action)
    result = run(
        "spin", "sim://betaflight", "--motor", "1", "--throttle", "12", "--seconds", "5", "--yes"
    )
    assert trigger.fired_at is not None
    assert result.exit_code == exit_code, result.output
    if action == "exception":
        assert isinstance(result.exception, RuntimeError)
    else:
        assert message in result.output
    (fc,) = peers
    assert max(state[0] for state in fc.history) == dshot_external(12.0)  # it was spinning
    assert fc.inner.motor_values == [1000] * 4  # and is commanded to stop
    assert fc.history[-1] == (1000, 1000, 1000, 1000)
    assert "motor 1 stopped (verified)" in result.output
    stopped = fc.stopped_at(trigger.fired_at, (1000, 1000, 1000, 1000))
    assert stopped is not None and stopped - trigger.fired_at < 0.1  # at once, not at 5 s
    assert signal.getsignal(signal.SIGTERM) == previous  # handler restored


def test_spin_stop_not_verified_exits_3(peers: list[Spy], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(MspThrottleOutput, "_judge", lambda self, values: "running")
    result = run(
        "spin", "sim://betaflight", "--motor", "1", "--throttle", "5", "--seconds", "1", "--yes"
    )
    assert result.exit_code == 3
    assert "STOP NOT VERIFIED" in result.output
    assert peers[0].inner.motor_values == [1000] * 4  # the stop itself was still sent


def test_spin_fc_gone_silent_is_reported_as_unverified(
    peers: list[Spy], monkeypatch: pytest.MonkeyPatch
) -> None:
    def unplug() -> None:
        peers[0].inner.in_cli = True  # the FC stops answering MSP (as after a stray '#')

    Trigger(monkeypatch, 1.0, unplug)
    result = run(
        "spin", "sim://betaflight", "--motor", "1", "--throttle", "8", "--seconds", "3", "--yes"
    )
    assert result.exit_code == 3, result.output
    assert "STOP NOT VERIFIED on motor 1 - disconnect the battery now" in result.output
    assert "lost link to the throttle output" in result.output
    assert peers[0].inner.motor_values[0] > 1000  # honest: the FC really is still spinning


def test_spin_refuses_a_motor_the_fc_does_not_have(peers: list[Spy]) -> None:
    result = run("spin", "sim://betaflight", "--motor", "5", "--throttle", "5", "--yes")
    assert isinstance(result.exception, ConfigError)
    assert "motor 5 does not exist" in str(result.exception)
    assert all(state == (1000,) * 4 for state in peers[0].history)


# --------------------------------------------------------------------------- spin: MAVLink


@pytest.mark.parametrize("firmware", ["px4", "ardupilot"])
def test_spin_mavlink_normal_end(peers: list[Spy], firmware: str) -> None:
    result = run(
        "spin", f"sim://{firmware}", "--motor", "1", "--throttle", "10", "--seconds", "3", "--yes"
    )
    assert result.exit_code == 0, result.output
    (vehicle,) = peers
    if firmware == "px4":
        assert any(0 in state for state in vehicle.history)
        assert vehicle.inner.running_motors() == {}
    else:
        assert any(vehicle.history)
        assert not vehicle.inner.motor_test_running
    assert "motor 1 stopped (verified)" in result.output


@pytest.mark.parametrize("firmware", ["px4", "ardupilot"])
@pytest.mark.parametrize("action", ["sigterm", "ctrl-c"])
def test_spin_mavlink_interrupted_stops_before_the_vehicle_timeout(
    peers: list[Spy], monkeypatch: pytest.MonkeyPatch, firmware: str, action: str
) -> None:
    trigger = Trigger(monkeypatch, 1.0, action)
    result = run(
        "spin", f"sim://{firmware}", "--motor", "1", "--throttle", "10", "--seconds", "6", "--yes"
    )
    assert result.exit_code == 130, result.output
    (vehicle,) = peers
    assert trigger.fired_at is not None
    # stopped by us at once, long before the motor test would have timed out on the vehicle
    stopped = vehicle.stopped_at(trigger.fired_at, {} if firmware == "px4" else False)
    assert stopped is not None and stopped - trigger.fired_at < 0.1
    if firmware == "px4":
        assert any(0 in state for state in vehicle.history)
        assert vehicle.history[-1] == {} and vehicle.inner.running_motors() == {}
    else:
        assert any(vehicle.history)
        assert vehicle.history[-1] is False and not vehicle.inner.motor_test_running
    assert "motor 1 stopped (verified)" in result.output


# --------------------------------------------------------------------------- spin: stands


@pytest.mark.parametrize("action", [None, "sigterm", "exception"])
def test_spin_line_stand_esc(
    peers: list[Spy], monkeypatch: pytest.MonkeyPatch, action: str | None
) -> None:
    if action is not None:
        Trigger(monkeypatch, 1.2, action)
    result = run(
        "spin", "sim://line-stand", "--motor", "1", "--throttle", "20", "--seconds", "2", "--yes"
    )
    (stand,) = peers
    assert max(stand.history) == pytest.approx(20.0)
    assert stand.inner.throttle_pct == 0.0
    assert stand.inner.watchdog_trips == 0  # PINGs kept it fed
    assert "motor 1 stopped (verified)" in result.output
    assert result.exit_code == {None: 0, "sigterm": 130, "exception": 1}[action]
    if action is None:
        assert "thrust" in result.output


def test_spin_tyto_esc(peers: list[Spy]) -> None:
    result = run(
        "spin", "sim://tyto-1585", "--motor", "1", "--throttle", "10", "--seconds", "2", "--yes"
    )
    assert result.exit_code == 0, result.output
    (stand,) = peers
    assert max(stand.history) == 1100
    assert stand.inner.esc_us == 1000


def test_spin_with_a_separate_stand_shows_thrust(peers: list[Spy]) -> None:
    result = run(
        "spin",
        "sim://betaflight",
        "--stand",
        "sim://tyto-1585?drive_esc=0",
        "--motor",
        "1",
        "--throttle",
        "20",
        "--seconds",
        "3",
        "--yes",
    )
    assert result.exit_code == 0, result.output
    last = [ln for ln in result.output.splitlines() if ln.startswith("t=")][-1]
    thrust = float(last.split("thrust ")[1].split(" N")[0])
    assert thrust > 0.3  # the stand on the same simulated bench saw the FC's motor pull
    fc = next(p for p in peers if p.name == "betaflight")
    assert fc.inner.motor_values == [1000] * 4


# --------------------------------------------------------------------------- spin: refusals


@pytest.mark.parametrize(
    ("args", "error", "match"),
    [
        (["--throttle", "30"], SafetyError, "above the 20 % cap"),
        (["--throttle", "30", "--max-throttle", "25"], SafetyError, "above the 25 % cap"),
        (["--throttle", "10", "--seconds", "11"], SafetyError, "at most 10 s"),
        (["--throttle", "10", "--max-throttle", "150"], ConfigError, r"\(0, 100\]"),
        (["--throttle", "-1"], ConfigError, "0..100"),
        (["--throttle", "10", "--motor", "0"], ConfigError, "1-based"),
    ],
)
def test_spin_refusals_open_nothing(
    peers: list[Spy], args: list[str], error: type[Exception], match: str
) -> None:
    base = ["spin", "sim://betaflight", "--yes"]
    if "--motor" not in args:
        base += ["--motor", "1"]
    result = run(*base, *args)
    assert isinstance(result.exception, error)
    assert re.search(match, str(result.exception))
    assert peers == []  # refused before anything was opened


def test_spin_above_the_default_cap_when_raised_explicitly(peers: list[Spy]) -> None:
    result = run(
        "spin",
        "sim://betaflight",
        "--motor",
        "1",
        "--throttle",
        "30",
        "--max-throttle",
        "30",
        "--seconds",
        "2",
        "--yes",
    )
    assert result.exit_code == 0, result.output
    assert max(state[0] for state in peers[0].history) == dshot_external(30.0)


def test_spin_asks_first(peers: list[Spy]) -> None:
    result = run("spin", "sim://betaflight", "--motor", "1", "--throttle", "10", input="n\n")
    assert result.exit_code == 2  # refused, nothing spun (not 130: nothing was interrupted)
    assert "Propellers on?" in result.output and "refused: nothing spun" in result.output
    assert peers == []
    result = run(
        "spin",
        "sim://betaflight",
        "--motor",
        "1",
        "--throttle",
        "10",
        "--seconds",
        "1",
        input="y\n",
    )
    assert result.exit_code == 0, result.output
    assert max(state[0] for state in peers[0].history) == dshot_external(10.0)


def test_clock_choice() -> None:
    assert isinstance(hardware.make_clock("auto", ["sim://px4"]), SimClock)
    assert isinstance(hardware.make_clock("auto", ["replay://x.jsonl", "sim://px4"]), SimClock)
    assert isinstance(hardware.make_clock("auto", ["sim://px4", "/dev/ttyACM0"]), MonotonicClock)
    assert isinstance(hardware.make_clock("real", ["sim://px4"]), MonotonicClock)
    with pytest.raises(ConfigError, match="/dev/ttyACM0 is real"):
        hardware.make_clock("sim", ["/dev/ttyACM0"])


def test_sigterm_is_a_keyboard_interrupt() -> None:
    assert issubclass(Terminated, KeyboardInterrupt)


# --------------------------------------------------------------------------- probe


def test_probe_betaflight(peers: list[Spy]) -> None:
    result = run("probe", "sim://betaflight?protocol=PWM")
    assert result.exit_code == 0, result.output
    out = result.output
    assert "msp (betaflight)" in out
    assert "motor protocol: PWM" in out and "motors: 4" in out and "battery cells: 6" in out
    assert "throttle scale: pwm" in out
    assert "motor values: 1000 1000 1000 1000 0 0 0 0" in out
    assert peers[0].inner.motor_values == [1000] * 4


def test_probe_json(peers: list[Spy]) -> None:
    result = run("probe", "sim://px4", "--json")
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert data["kind"] == "mavlink" and data["firmware"] == "px4"
    assert data["identity"]["kind"] == "px4"
    assert data["telemetry"]["voltage_v"] == pytest.approx(24.87, abs=0.1)


def test_probe_line_stand(peers: list[Spy]) -> None:
    result = run("probe", "sim://line-stand", "--seconds", "2", "--json")
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert 195 <= data["stand"]["samples"] <= 210
    assert data["stand"]["rate_hz"] == pytest.approx(100.0, rel=0.02)
    assert data["identity"]["details"]["spec"] == "thrustmap-line"


def test_probe_tyto_text(peers: list[Spy]) -> None:
    result = run("probe", "sim://tyto-1585")
    assert result.exit_code == 0, result.output
    assert "tyto-1585" in result.output and "at 50 Hz" in result.output
    assert "mean voltage: 24.87 V" in result.output


def test_probe_bad_seconds() -> None:
    result = run("probe", "sim://tyto-1585", "--seconds", "0")
    assert isinstance(result.exception, ConfigError)


# --------------------------------------------------------------------------- ports


@dataclass
class FakePort:
    device: str
    vid: int | None
    pid: int | None
    description: str
    manufacturer: str | None = None
    product: str | None = None
    serial_number: str | None = None
    hwid: str = ""


FAKE_PORTS = [
    FakePort(
        "/dev/ttyACM0",
        0x0483,
        0x5740,
        "STM32 Virtual ComPort",
        "Betaflight",
        "Betaflight STM32F405",
    ),
    FakePort("/dev/ttyACM1", 0x0483, 0xDF11, "STM32 BOOTLOADER"),
    FakePort("/dev/ttyUSB0", 0x1A86, 0x7523, "USB Serial"),
]


def test_ports_lists_guesses_without_opening(monkeypatch: pytest.MonkeyPatch) -> None:
    from serial.tools import list_ports

    monkeypatch.setattr(list_ports, "comports", lambda: list(FAKE_PORTS))
    opened: list[str] = []
    from thrustmap.rig.devices import urls  # every device is opened through here

    monkeypatch.setattr(urls, "open_transport", lambda *a, **k: opened.append(a[0]))
    result = run("ports")
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0].startswith("/dev/ttyACM0  0483:5740  Betaflight flight controller")
    assert any("/dev/ttyACM1  0483:DF11  STM32 in DFU" in ln for ln in lines)
    assert any("/dev/ttyUSB0  1A86:7523  CH340" in ln for ln in lines)
    assert opened == []
    data = json.loads(run("ports", "--json").output)
    assert [d["usb_id"] for d in data] == ["0483:5740", "0483:DF11", "1A86:7523"]
    assert data[0]["kinds"] == ["msp"]


def test_ports_probe_skips_bootloaders(monkeypatch: pytest.MonkeyPatch) -> None:
    from serial.tools import list_ports

    import thrustmap.rig.devices.declaration as declaration
    import thrustmap.rig.devices.detect as detect

    monkeypatch.setattr(list_ports, "comports", lambda: list(FAKE_PORTS))
    probed: list[str] = []

    def fake_detect(url: str, clock: Any, **kwargs: Any) -> Any:
        probed.append(url)
        if url == "/dev/ttyUSB0":
            raise ConfigError("could not tell")
        return declaration.Detection("msp", "betaflight", evidence="MSP API 1.46")

    monkeypatch.setattr(detect, "detect_kind", fake_detect)
    result = run("ports", "--probe", "--json")
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert probed == ["/dev/ttyACM0", "/dev/ttyUSB0"]
    assert data[0]["probe"] == "msp (betaflight) — MSP API 1.46"
    assert data[1]["probe"] == "skipped (bootloader)"
    assert data[2]["probe"].startswith("unknown")


def test_ports_none(monkeypatch: pytest.MonkeyPatch) -> None:
    from serial.tools import list_ports

    monkeypatch.setattr(list_ports, "comports", lambda: [])
    assert run("ports").output.strip() == "no serial ports found"


def test_spin_help_lists_the_exit_codes_and_refusals_exit_2(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from thrustmap.cli import main

    main(["spin", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for code in ("0 done", "1 aborted", "2 refused", "3 stop NOT verified", "130 interrupted"):
        assert code in text
    with pytest.raises(SystemExit) as exc:
        main(["spin", "sim://betaflight", "--motor", "1", "--throttle", "50", "--yes"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "above the 20 % cap" in err[0]


def test_spin_runs_the_interlocks_of_the_table(peers: list[Spy]) -> None:
    """spin is a plan on the sweep's runner: the table's limits (here the current, read from the
    FC's telemetry) end it, stopped and verified, exit 1."""
    result = run(
        "spin", "sim://betaflight", "--motor", "1", "--throttle", "15", "--seconds", "3",
        "--max-current", "0.2", "--yes",
    )  # fmt: skip
    assert result.exit_code == 1, result.output
    assert "limit tripped: current" in result.output
    assert "motor 1 stopped (verified)" in result.output
    assert peers[0].inner.motor_values == [1000] * 4
