"""run_spin as a library: caps, ramp, reports, and the stop on every way out (fake output)."""

from __future__ import annotations

from collections.abc import Mapping

import pytest

from thrustmap.core.clock import SimClock
from thrustmap.core.errors import ConfigError, SafetyError
from thrustmap.core.units import SCALES
from thrustmap.rig.interfaces import DeviceIdentity, Telemetry, ThrottleOutput
from thrustmap.rig.spin import SpinRequest, check_spin, run_spin


class FakeOutput(ThrottleOutput):
    throttle_scale = SCALES["pwm"]

    def __init__(self, clock: SimClock, *, fail_at_s: float | None = None, motors: int = 4):
        self.clock = clock
        self.fail_at_s = fail_at_s
        self.motors = motors
        self.commands: list[tuple[float, dict[int, float]]] = []
        self.running: dict[int, float] = {}
        self.stops = 0
        self.closed = 0
        self.keepalives = 0

    def identify(self) -> DeviceIdentity:
        return DeviceIdentity(kind="fake", motor_count=self.motors)

    def set_throttle(self, values: Mapping[int, float]) -> None:
        if self.fail_at_s is not None and self.clock.now_s() >= self.fail_at_s:
            raise OSError("link lost")
        self.commands.append((self.clock.now_s(), dict(values)))
        self.running = dict(values)

    def keepalive(self) -> None:
        self.keepalives += 1

    def stop(self) -> None:
        self.stops += 1
        self.running = {}

    def verify_stopped(self) -> bool:
        return not self.running

    def read_telemetry(self) -> Telemetry:
        return Telemetry(self.clock.now_s(), voltage_v=16.0)

    def close(self) -> None:
        self.closed += 1


def test_caps() -> None:
    check_spin(SpinRequest(0, 20.0, 10.0))
    with pytest.raises(SafetyError, match="--max-throttle 21"):
        check_spin(SpinRequest(0, 20.5, 1.0))
    check_spin(SpinRequest(0, 20.5, 1.0), max_throttle_pct=21.0)
    with pytest.raises(SafetyError, match="at most 10 s"):
        check_spin(SpinRequest(0, 5.0, 10.5))
    with pytest.raises(SafetyError):
        check_spin(SpinRequest(0, 5.0, 0.0))
    with pytest.raises(ConfigError):
        check_spin(SpinRequest(0, float("nan"), 1.0))
    with pytest.raises(ConfigError):
        check_spin(SpinRequest(0, 5.0, 1.0), max_throttle_pct=0.0)
    with pytest.raises(ConfigError):
        check_spin(SpinRequest(0, 5.0, 1.0, tick_s=0.0))


def test_ramp_hold_reports_and_stop() -> None:
    """The spin is a plan on the sweep's runner: ramp, hold, keep-alives, reports, stop."""
    clock = SimClock()
    out = FakeOutput(clock)
    reports = []
    result = run_spin(out, clock, SpinRequest(1, 10.0, 3.0, ramp_s=0.5), on_report=reports.append)
    assert result.status == "completed" and result.stop_verified
    sent = [values[1] for _, values in out.commands]
    assert sent == sorted(sent) and sent[-1] == pytest.approx(1100.0)
    assert 1000.0 < sent[1] < 1100.0  # a ramp, not a step
    reached = next(t for t, values in out.commands if values[1] == pytest.approx(1100.0))
    assert reached - out.commands[0][0] == pytest.approx(0.5, abs=0.06)
    assert all(set(values) == {1} for _, values in out.commands)
    assert 4 <= out.keepalives <= 6  # the hold re-sent every 0.5 s (resend_s)
    assert [round(r.elapsed_s, 6) for r in reports] == pytest.approx([0.0, 1.0, 2.0], abs=0.06)
    assert reports[-1].telemetry is not None and reports[-1].telemetry.voltage_v == 16.0
    assert result.max_commanded_pct == pytest.approx(10.0)
    assert result.duration_s == pytest.approx(3.0, abs=0.15)  # a tick per segment end
    assert out.stops == 2 and out.closed == 1  # the runner's verified stop, the context's


def test_a_silent_output_ends_the_spin_within_the_link_timeout() -> None:
    """The runner's link watchdog: telemetry stops answering -> stopped within ~1 s."""
    clock = SimClock()

    class Silent(FakeOutput):
        def read_telemetry(self) -> Telemetry:
            if self.clock.now_s() >= 1.0:
                raise OSError("no answer")
            return super().read_telemetry()

    out = Silent(clock)
    result = run_spin(out, clock, SpinRequest(0, 10.0, 5.0))
    assert result.status == "failed" and "lost link to the throttle output" in result.reason
    assert result.stop_verified and out.running == {}
    assert result.duration_s == pytest.approx(1.0 + 1.0, abs=0.3)


def test_driver_failure_still_stops() -> None:
    clock = SimClock()
    out = FakeOutput(clock, fail_at_s=0.2)
    result = run_spin(out, clock, SpinRequest(0, 10.0, 3.0))
    assert result.status == "failed" and "link lost" in result.reason
    assert result.stop_verified and out.running == {} and out.closed == 1
    with pytest.raises(SafetyError, match="commands failing: link lost"):
        result.raise_error()


def test_missing_motor_fails_before_any_command() -> None:
    clock = SimClock()
    out = FakeOutput(clock, motors=1)
    result = run_spin(out, clock, SpinRequest(3, 10.0, 1.0))
    assert result.status == "failed" and "motor 4 does not exist" in result.reason
    assert out.commands == [] and result.stop_verified


def test_unverified_stop_is_reported() -> None:
    clock = SimClock()

    class Stuck(FakeOutput):
        def verify_stopped(self) -> bool:
            return False

    out = Stuck(clock)
    result = run_spin(out, clock, SpinRequest(0, 5.0, 1.0))
    assert result.status == "completed" and not result.stop_verified
    assert out.stops >= 2  # retried (the runner), then again on the context manager's exit
