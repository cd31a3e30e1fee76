"""The bench session (rig/session.py) and the runner's phases before the plan (issue 11 item 7):
every device's link is serviced while the rotor comes to rest and the stand is tared, a silent
FC there aborts, Ctrl-C there stops at once with no CRITICAL, and the wait is not plan time.
All on the simulator with a SimClock."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest
from test_rig_runner import make_rig, sweep

from thrustmap.core.clock import MonotonicClock, SimClock
from thrustmap.core.errors import ConfigError
from thrustmap.protocols.msp.framing import MspCommand, MspDecoder
from thrustmap.protocols.msp.motor import SetMotor
from thrustmap.rig import plans
from thrustmap.rig.interfaces import DeviceIdentity, Stand, StandSample
from thrustmap.rig.interlocks import Limits
from thrustmap.rig.run_types import RunResult, Status
from thrustmap.rig.session import (
    EXIT_ABORTED,
    EXIT_DONE,
    EXIT_INTERRUPTED,
    EXIT_STOP_NOT_VERIFIED,
    BenchSession,
    Rig,
    choose_clock,
    exit_code,
    pairing_warnings,
)
from thrustmap.rig.sim import peers

PLAN = plans.stairs(10, 30, 10, dwell_s=1.0)
STOP_PAYLOAD = SetMotor.stop_all(8).encode()


class TurningStand(Stand):
    """The simulated stand, but its rotor still turns (rpm 3000) until ``until_s``: the runner
    must wait for it to come to rest before taring. ``on_read`` runs on every read."""

    def __init__(
        self,
        inner: Stand,
        clock: SimClock,
        until_s: float,
        on_read: Callable[[float], None] | None = None,
    ) -> None:
        self.inner, self.clock, self.until_s, self.on_read = inner, clock, until_s, on_read

    def identify(self) -> DeviceIdentity:
        return self.inner.identify()

    def read_samples(self) -> list[StandSample]:
        if self.on_read is not None:
            self.on_read(self.clock.now_s())
        samples = self.inner.read_samples()
        if self.clock.now_s() < self.until_s:
            return [replace(s, rpm=3000.0) for s in samples]
        return samples

    def tare(self, service: Callable[[], None] | None = None) -> None:
        self.inner.tare(service)

    def close(self) -> None:
        self.inner.close()


def msp_requests(writes: list[tuple[float, bytes]], cmd: int) -> list[float]:
    """Times at which the host wrote an MSP request ``cmd``."""
    out = []
    for t, data in writes:
        for frame in MspDecoder().feed(data):
            if frame.cmd == cmd:
                out.append(t)
    return out


def running_commands(writes: list[tuple[float, bytes]]) -> list[float]:
    """Times of SET_MOTOR frames that commanded anything but stop."""
    out = []
    for t, data in writes:
        for frame in MspDecoder().feed(data):
            if frame.cmd == MspCommand.SET_MOTOR and frame.payload != STOP_PAYLOAD:
                out.append(t)
    return out


@pytest.fixture(autouse=True)
def fresh_bench() -> None:
    peers.reset_benches()


def test_the_fc_is_read_while_waiting_at_rest_and_the_wait_is_its_own_phase(
    tmp_path: Path,
) -> None:
    rig = make_rig()
    stand = TurningStand(rig.stand, rig.clock, until_s=5.0)
    seen: list[Status] = []
    with rig.fc, rig.stand:
        result = sweep(rig, tmp_path / "w.csv", PLAN, stand=stand, monitor=seen.append)
    assert result.status == "completed" and result.stop_verified
    first_command = running_commands(rig.fc_port.writes)[0]
    assert first_command > 5.0 + 0.8  # rest waited for (0.8 s still at least), then the tare
    # the FC's telemetry was read all along the wait, at the telemetry period (0.2 s)
    reads = [t for t in msp_requests(rig.fc_port.writes, MspCommand.BATTERY_STATE)]
    before = [t for t in reads if t < first_command]
    gaps = [b - a for a, b in zip(before, before[1:], strict=False)]
    opened = rig.fc_port.writes[0][0]
    assert before[0] - opened < 0.2 and max(gaps) <= 0.25 and first_command - before[-1] <= 0.25
    # phases in order; the plan's progress starts at 0 when the plan starts
    phases = [s.phase for s in seen]
    assert phases[0] == "at-rest" and "tare" in phases and phases[-1] == "plan"
    assert phases.index("tare") > phases.index("at-rest")
    plan_status = [s for s in seen if s.phase == "plan"]
    assert plan_status[0].elapsed_s < 0.05 and plan_status[0].wait_s > 4.0
    assert plan_status[0].wait_s == pytest.approx(plan_status[0].time_s - seen[0].time_s, abs=0.05)
    assert all(s.elapsed_s == 0.0 for s in seen if s.phase != "plan")
    assert result.wait_s > 4.0
    assert result.duration_s == pytest.approx(PLAN.duration_s, abs=1.5)  # the plan, not the wait


def test_a_silent_fc_while_waiting_at_rest_aborts_before_any_command(tmp_path: Path) -> None:
    rig = make_rig()
    rig.fc_port.dead = lambda t: 3.0 <= t < 6.0  # the FC stops answering during the wait
    stand = TurningStand(rig.stand, rig.clock, until_s=12.0)
    limits = Limits(max_current_a=120, link_timeout_s=1.0)
    with rig.fc, rig.stand:
        result = sweep(rig, tmp_path / "s.csv", PLAN, stand=stand, limits=limits)
    assert result.status == "aborted" and "lost link to the throttle output" in result.reason
    assert result.outcome == "aborted" and not result.interrupted
    assert running_commands(rig.fc_port.writes) == []
    assert result.stop_latency_s is not None
    assert rig.clock.now_s() < 12.0  # it did not wait for the rotor: it gave up on the FC
    assert result.stop_verified  # once the link came back


def test_ctrl_c_while_waiting_at_rest_stops_at_once_without_a_false_alarm(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    rig = make_rig()
    fired: list[float] = []

    def ctrl_c(now_s: float) -> None:
        if now_s >= 2.0 and not fired:
            fired.append(now_s)
            raise KeyboardInterrupt

    stand = TurningStand(rig.stand, rig.clock, until_s=6.0, on_read=ctrl_c)
    with caplog.at_level(logging.WARNING), rig.fc, rig.stand:
        result = sweep(rig, tmp_path / "c.csv", PLAN, stand=stand)
    assert fired and result.outcome == "interrupted" and result.stop_verified
    assert exit_code(result.outcome, result.stop_verified) == EXIT_INTERRUPTED
    assert running_commands(rig.fc_port.writes) == []
    # nothing was commanded, so there is nothing to stop: no stop is sent (issue 20)
    assert rig.fc_port.stop_times(0.0) == []
    assert not [r for r in caplog.records if r.levelno >= logging.CRITICAL]


def test_ctrl_c_while_taring_stops_at_once(tmp_path: Path) -> None:
    rig = make_rig()
    fired: list[float] = []
    inner_tare = rig.stand.tare

    def tare(service: Callable[[], None] | None = None, polls: int = 20) -> None:
        def interrupt() -> None:
            if service is not None:
                service()
            fired.append(rig.clock.now_s())
            raise KeyboardInterrupt

        inner_tare(interrupt, polls)

    rig.stand.tare = tare  # type: ignore[method-assign]
    with rig.fc, rig.stand:
        result = sweep(rig, tmp_path / "t.csv", PLAN)
    assert fired and result.outcome == "interrupted" and result.stop_verified
    assert running_commands(rig.fc_port.writes) == []


def test_exit_codes() -> None:
    assert exit_code("completed", True) == EXIT_DONE == 0
    assert exit_code("interrupted", True) == EXIT_INTERRUPTED == 130
    assert exit_code("aborted", True) == EXIT_ABORTED == 1
    for outcome in ("completed", "interrupted", "aborted"):
        assert exit_code(outcome, False) == EXIT_STOP_NOT_VERIFIED == 3
    r = RunResult("aborted", "interrupted (Ctrl-C)", 0, 0.0, True, None, interrupted=True)
    assert r.outcome == "interrupted"
    assert RunResult("completed", "", 0, 0.0, True, None).outcome == "completed"


def test_clock_rule() -> None:
    assert isinstance(choose_clock(["sim://px4"]), SimClock)
    assert isinstance(choose_clock(["replay://x.jsonl", "record://sim://px4?file=y"]), SimClock)
    assert isinstance(choose_clock(["sim://px4", "/dev/ttyACM0"]), MonotonicClock)
    assert isinstance(choose_clock(["sim://px4"], "real"), MonotonicClock)
    with pytest.raises(ConfigError, match="/dev/ttyACM0 is real"):
        choose_clock(["/dev/ttyACM0"], "sim")
    with pytest.raises(ConfigError, match="clock must be one of"):
        choose_clock(["sim://px4"], "fast")


def test_a_simulated_stand_with_a_real_fc_is_warned() -> None:
    (warning,) = pairing_warnings(Rig(stand="sim://tyto-1585", throttle="/dev/ttyACM0"))
    assert "thrust will be noise" in warning
    assert pairing_warnings(Rig(stand="sim://tyto-1585", throttle="sim://betaflight")) == []
    assert pairing_warnings(Rig(stand="/dev/ttyUSB0", throttle="/dev/ttyACM0")) == []
    assert pairing_warnings(Rig(stand="/dev/ttyUSB0")) == []


def test_session_stops_verifies_and_closes_on_an_exception() -> None:
    clock = SimClock()
    session = BenchSession(Rig(throttle="sim://betaflight?bench=s"), clock)
    with pytest.raises(RuntimeError, match="boom"), session:
        out = session.output
        out.set_throttle({0: 1200.0})
        raise RuntimeError("boom")
    assert session.stop_verified is True
    with pytest.raises(RuntimeError, match="not open"):
        _ = session.output


def test_session_needs_a_device() -> None:
    with pytest.raises(ConfigError, match="stand URL, a throttle"):
        Rig()
    assert Rig(stand="sim://tyto-1585", throttle="stand").throttle is None


def test_protocols_import_has_no_side_effects_and_no_upward_arrow() -> None:
    """Importing protocols registers nothing with pyserial and loads nothing from rig/; the
    handlers are registered where a transport is opened."""
    import subprocess
    import sys

    program = """
import sys, serial
import thrustmap.protocols, thrustmap.protocols.peer, thrustmap.protocols.transport
import thrustmap.protocols.urlhandlers.protocol_sim
assert "thrustmap.protocols.urlhandlers" not in serial.protocol_handler_packages
assert not [m for m in sys.modules if m.startswith("thrustmap.rig")], "protocols imported rig"
from thrustmap.protocols.peer import UnknownPeerError, create_peer
try:
    create_peer("betaflight")
except UnknownPeerError:
    pass
else:
    raise AssertionError("protocols found a simulator by itself")
assert not [m for m in sys.modules if m.startswith("thrustmap.rig")]
from thrustmap.protocols.transport import open_transport
open_transport("loop://", timeout=0).close()
assert "thrustmap.protocols.urlhandlers" in serial.protocol_handler_packages
print("ok")
"""
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True)
    assert done.stdout.strip() == "ok", done.stderr
