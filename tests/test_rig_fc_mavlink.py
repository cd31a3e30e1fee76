"""PX4 and ArduPilot MAVLink throttle outputs against the simulated vehicles, the recorded
fixtures (strict replay), a loopback pymavlink link and the runner. SimClock only."""

from __future__ import annotations

import logging
import math
import os
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support.mavlink_transcripts import (
    SCENARIOS,
    record_scenario,
    replay_scenario,
)

from thrustmap.core.clock import MonotonicClock, SimClock
from thrustmap.core.errors import ConfigError, SafetyError
from thrustmap.core.stand_recording import DsWriter
from thrustmap.core.units import SCALES
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink.codec import decode_flight_sw_version
from thrustmap.protocols.mavlink.link import MavlinkSerialLink
from thrustmap.protocols.transcript import read_transcript
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig import plans
from thrustmap.rig.fc.ardupilot import ArduPilotThrottleOutput
from thrustmap.rig.fc.mavlink import open_mavlink_output
from thrustmap.rig.fc.mavlink_output import MavlinkThrottleOutput
from thrustmap.rig.fc.mavlink_session import MavlinkLinkLost, MotorTestRefused, UnsupportedAutopilot
from thrustmap.rig.fc.px4 import Px4ThrottleOutput
from thrustmap.rig.interfaces import DeviceIdentity, Stand, StandSample
from thrustmap.rig.interlocks import Limits
from thrustmap.rig.runner import Runner
from thrustmap.rig.sigterm import Terminated, terminate_as_exception
from thrustmap.rig.sim.mavlink_loopback import UdpVehicleLink
from thrustmap.rig.sim.mavlink_peers import ArduPilotVehicle, PX4Vehicle
from thrustmap.rig.sim.mavlink_vehicle import SimMavlinkVehicle
from thrustmap.rig.sim.physics import make_plant
from thrustmap.rig.sim.plant import ConstantPlant, Plant

R = mav.MavResult
FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "transcripts"


# ------------------------------------------------------------------------------------------
# Helpers and test doubles (test-only; the drivers never see them as anything but bytes)
# ------------------------------------------------------------------------------------------
class SilenceablePeer:
    """Test double: forwards to a vehicle; once ``silent`` the vehicle's bytes are dropped
    (it still hears the host, so the test can check what reached it)."""

    def __init__(self, vehicle: SimMavlinkVehicle) -> None:
        self.vehicle = vehicle
        self.silent = False

    def write(self, data: bytes, now_s: float) -> None:
        self.vehicle.write(data, now_s)

    def read(self, now_s: float) -> bytes:
        data = self.vehicle.read(now_s)
        return b"" if self.silent else data


def connect(vehicle: SimMavlinkVehicle) -> tuple[SimClock, MavlinkSerialLink, SilenceablePeer]:
    clock = SimClock()
    peer = SilenceablePeer(vehicle)
    return clock, MavlinkSerialLink(SimSerial(peer, clock, timeout=0), clock), peer


def px4(
    vehicle: PX4Vehicle | None = None, **kwargs: Any
) -> tuple[Px4ThrottleOutput, PX4Vehicle, SimClock, SilenceablePeer]:
    vehicle = vehicle if vehicle is not None else PX4Vehicle(ConstantPlant())
    clock, link, peer = connect(vehicle)
    return Px4ThrottleOutput(link, clock, **kwargs), vehicle, clock, peer


def ardupilot(
    vehicle: ArduPilotVehicle | None = None, **kwargs: Any
) -> tuple[ArduPilotThrottleOutput, ArduPilotVehicle, SimClock, SilenceablePeer]:
    vehicle = vehicle if vehicle is not None else ArduPilotVehicle(ConstantPlant())
    clock, link, peer = connect(vehicle)
    return ArduPilotThrottleOutput(link, clock, **kwargs), vehicle, clock, peer


def received(vehicle: SimMavlinkVehicle, command: int) -> list[mav.CommandLong]:
    return [c for c in vehicle.commands_received if c.command == command]


def is_px4_stop(c: mav.CommandLong) -> bool:
    return c.command == mav.MAV_CMD_ACTUATOR_TEST and math.isnan(c.params[0])


def is_ardupilot_stop(c: mav.CommandLong) -> bool:
    return c.command == mav.MAV_CMD_DO_MOTOR_TEST and c.params[3] == 0.0 and c.params[2] == 0.0


def spin_for(
    out: MavlinkThrottleOutput, clock: SimClock, seconds: float, every_s: float = 0.5
) -> None:
    for _ in range(round(seconds / every_s)):
        clock.sleep_s(every_s)
        out.keepalive()


def rpm(vehicle: SimMavlinkVehicle, clock: SimClock) -> list[float]:
    return vehicle.plant.state(clock.now_s()).rpm


# ------------------------------------------------------------------------------------------
# PX4
# ------------------------------------------------------------------------------------------
def test_px4_identify_reads_params_cells_motors_and_asks_for_rates() -> None:
    out, vehicle, _, _ = px4(PX4Vehicle(ConstantPlant(motor_count=6), cells=6))
    ident = out.identify()
    assert (ident.kind, ident.motor_count, ident.battery_cells) == ("px4", 6, 6)
    assert ident.details["THR_MDL_FAC"] == "0" and ident.details["COM_MOT_TEST_EN"] == "1"
    assert (ident.details["PWM_MAIN_MIN6"], ident.details["PWM_MAIN_DIS1"]) == ("1000", "900")
    assert ident.details["motor_count_source"] == "parameter"  # CA_ROTOR_COUNT, bytewise INT32
    assert out.throttle_scale == SCALES["norm"]
    rates = received(vehicle, mav.MAV_CMD_SET_MESSAGE_INTERVAL)
    assert sorted((int(c.params[0]), c.params[1]) for c in rates) == [
        (1, 100000.0),
        (36, 100000.0),
        (147, 100000.0),
        (291, 100000.0),
    ]
    assert received(vehicle, mav.MAV_CMD_ACTUATOR_TEST) == []  # identify spins nothing
    assert out.identify() is ident  # cached, no second conversation


def test_px4_keepalive_keeps_the_motor_running_past_the_firmware_timeout() -> None:
    out, vehicle, clock, _ = px4()
    out.identify()
    out.set_throttle({0: 0.5})
    spin_for(out, clock, 10.0)  # 5x the 2 s test timeout
    assert vehicle.running_motors() == {0: pytest.approx(0.5)}
    assert rpm(vehicle, clock)[0] == pytest.approx(15000.0)
    tests = received(vehicle, mav.MAV_CMD_ACTUATOR_TEST)
    assert len(tests) == 21  # the first command and 20 re-sends
    assert all(c.params[:2] == (0.5, 2.0) and c.params[4] == 1.0 for c in tests)
    tel = out.read_telemetry()
    assert tel.rpm == (15000.0, 0.0, 0.0, 0.0) and tel.current_a == pytest.approx(3.75)
    assert tel.voltage_v == pytest.approx(16.764) and tel.temperature_c is None


def test_px4_motor_stops_by_itself_without_keepalive() -> None:
    """The other half of the keep-alive test: the firmware timeout is real."""
    out, vehicle, clock, _ = px4()
    out.identify()
    out.set_throttle({0: 0.5})
    clock.sleep_s(2.5)
    out.poll()
    assert vehicle.running_motors() == {} and rpm(vehicle, clock)[0] == 0.0


def test_px4_maintain_resends_only_when_due() -> None:
    out, vehicle, clock, _ = px4(keepalive_interval_s=0.5)
    out.identify()
    out.set_throttle({0: 0.25})
    for _ in range(50):  # 5 s of a 0.1 s polling loop
        clock.sleep_s(0.1)
        out.maintain()
    sent = received(vehicle, mav.MAV_CMD_ACTUATOR_TEST)
    assert 10 <= len(sent) <= 11  # every 0.5 s, not every poll
    assert vehicle.running_motors() == {0: pytest.approx(0.25)}


def test_px4_timeout_is_capped_at_3_s_and_keepalive_must_fit_inside() -> None:
    link = MavlinkSerialLink(SimSerial(PX4Vehicle(ConstantPlant()), SimClock(), timeout=0))
    with pytest.raises(ConfigError, match=r"\(0, 3\]"):
        Px4ThrottleOutput(link, SimClock(), test_timeout_s=5.0)
    with pytest.raises(ConfigError, match="half the motor-test timeout"):
        Px4ThrottleOutput(link, SimClock(), test_timeout_s=1.0, keepalive_interval_s=0.8)
    out, vehicle, clock, _ = px4(test_timeout_s=3.0)
    out.identify()
    out.set_throttle({1: 0.4})
    value, timeout_s, _, _, function = received(vehicle, mav.MAV_CMD_ACTUATOR_TEST)[-1].params[:5]
    assert (timeout_s, function) == (3.0, 2.0)  # MOTOR2
    assert value == pytest.approx(0.4)  # float32 on the wire


def test_px4_refuses_an_armed_vehicle_before_any_motor_command() -> None:
    out, vehicle, _, _ = px4(PX4Vehicle(ConstantPlant(), armed=True))
    with pytest.raises(SafetyError, match="ARMED"):
        out.identify()
    assert received(vehicle, mav.MAV_CMD_ACTUATOR_TEST) == []


def test_px4_denied_while_armed_is_a_safety_error_with_the_reason() -> None:
    out, vehicle, clock, _ = px4()
    out.identify()
    vehicle.pilot_armed = True  # someone arms it after identify
    clock.sleep_s(1.1)  # the next HEARTBEAT says so
    with pytest.raises(MotorTestRefused, match="DENIED.*the vehicle reports ARMED") as info:
        out.set_throttle({0: 0.3})
    assert info.value.result == R.DENIED and isinstance(info.value, SafetyError)
    assert vehicle.running_motors() == {}


def test_px4_com_mot_test_en_off_is_refused_at_identify() -> None:
    vehicle = PX4Vehicle(ConstantPlant(), params={"COM_MOT_TEST_EN": 0.0})
    out, _, _, _ = px4(vehicle)
    with pytest.raises(SafetyError, match="COM_MOT_TEST_EN=0.*set COM_MOT_TEST_EN=1"):
        out.identify()
    assert received(vehicle, mav.MAV_CMD_ACTUATOR_TEST) == []


def test_px4_thr_mdl_fac_is_recorded_and_warned(caplog: pytest.LogCaptureFixture) -> None:
    vehicle = PX4Vehicle(ConstantPlant(), params={"THR_MDL_FAC": 0.4})
    out, _, clock, _ = px4(vehicle)
    with caplog.at_level(logging.WARNING, logger="thrustmap.rig.fc.mavlink"):
        ident = out.identify()
    assert ident.details["THR_MDL_FAC"] == "0.4"
    assert any("THR_MDL_FAC=0.4 shapes" in r.getMessage() for r in caplog.records)
    out.set_throttle({0: 0.5})  # the vehicle applies its thrust model: the driver just records it
    u = (-0.6 + math.sqrt(0.36 + 0.8)) / 0.8
    assert vehicle.running_motors()[0] == pytest.approx(u)


def test_px4_several_motors_dropping_one_stops_it_and_stop_covers_all() -> None:
    out, vehicle, clock, _ = px4()
    out.identify()
    out.set_throttle({0: 0.2, 2: 0.6})
    assert vehicle.running_motors() == {0: pytest.approx(0.2), 2: pytest.approx(0.6)}
    out.set_throttle({2: 0.6})
    assert vehicle.running_motors() == {2: pytest.approx(0.6)}
    assert out.stop_and_verify()
    stops = [c for c in vehicle.commands_received[-4:] if is_px4_stop(c)]
    assert [int(c.params[4]) for c in stops] == [1, 2, 3, 4]  # every motor, in one burst
    assert vehicle.running_motors() == {} and rpm(vehicle, clock) == [0.0] * 4


def test_px4_refuses_values_outside_the_scale_and_unknown_motors() -> None:
    out, vehicle, _, _ = px4()
    out.identify()
    for bad in ({0: 1.2}, {0: -0.1}, {0: math.nan}, {7: 0.3}):
        with pytest.raises(SafetyError):
            out.set_throttle(bad)
    assert received(vehicle, mav.MAV_CMD_ACTUATOR_TEST) == []


class VersionedPX4(PX4Vehicle):
    """Test double: answers MAV_CMD_REQUEST_MESSAGE(AUTOPILOT_VERSION) like real PX4."""

    def _request_message(self, command: mav.CommandLong) -> int:
        if int(command.params[0]) == 148:
            sw = (1 << 24) | (14 << 16) | (3 << 8) | 255
            self.send(
                mavlink2.MAVLink_autopilot_version_message(
                    59647,
                    sw,
                    0,
                    0,
                    0x00380000,
                    [0] * 8,
                    [0] * 8,
                    [0] * 8,
                    0x26AC,
                    0x11,
                    0,
                    [0] * 18,
                )
            )
            return R.ACCEPTED
        return R.DENIED


def test_px4_firmware_version_from_autopilot_version() -> None:
    out, _, _, _ = px4(VersionedPX4(ConstantPlant()))
    ident = out.identify()
    assert ident.firmware_version == "1.14.3"
    assert ident.details["board_version"] == str(0x00380000)
    assert decode_flight_sw_version((1 << 24) | (15 << 16) | (0 << 8) | 128) == "1.15.0-beta"
    assert decode_flight_sw_version((4 << 24) | (5 << 16) | (7 << 8) | 255) == "4.5.7"


class StuckPX4(PX4Vehicle):
    """Test double: acknowledges the stop but keeps the motor running (a firmware fault)."""

    def handle_command(self, command: mav.CommandLong, now_s: float) -> int:
        if command.command == mav.MAV_CMD_ACTUATOR_TEST and math.isnan(command.params[0]):
            return R.ACCEPTED
        return super().handle_command(command, now_s)

    def update(self, now_s: float) -> None:
        pass  # and never times out


def test_px4_stop_not_verified_when_outputs_keep_running(caplog: pytest.LogCaptureFixture) -> None:
    out, vehicle, clock, _ = px4(StuckPX4(ConstantPlant()))
    out.identify()
    out.set_throttle({0: 0.5})
    with caplog.at_level(logging.WARNING):
        assert out.stop_and_verify() is False
    assert "outputs not at stop" in caplog.text and "COULD NOT VERIFY MOTOR STOP" in caplog.text
    assert len([c for c in vehicle.commands_received if is_px4_stop(c)]) == 3 * 4  # 3 attempts


def test_px4_verify_accepts_a_coasting_rotor_on_the_physics_plant() -> None:
    plant = make_plant("xnova-2207-6s", rotors_on_esc=1, seed=1, noise=False)
    out, vehicle, clock, _ = px4(PX4Vehicle(plant, cells=6))
    assert out.identify().motor_count == 4  # the quadx vehicle; one rotor of it on the stand
    out.set_throttle({0: 0.6})
    spin_for(out, clock, 3.0)
    spinning = out.read_telemetry().rpm
    assert spinning is not None and spinning[0] > 20000
    assert out.stop_and_verify()
    coasting = out.read_telemetry().rpm
    assert coasting is not None and 0 < coasting[0] < 0.5 * spinning[0]  # unpowered, slowing


# ------------------------------------------------------------------------------------------
# ArduPilot
# ------------------------------------------------------------------------------------------
def test_ardupilot_identify_pwm_range_from_params() -> None:
    out, vehicle, _, _ = ardupilot(
        ArduPilotVehicle(ConstantPlant(), params={"MOT_PWM_MIN": 1100, "MOT_PWM_MAX": 1900})
    )
    ident = out.identify()
    assert (ident.kind, ident.motor_count, ident.battery_cells) == ("ardupilot", 4, None)
    assert (out.throttle_scale.lo, out.throttle_scale.hi, out.throttle_scale.unit) == (
        1100.0,
        1900.0,
        "us",
    )
    assert ident.details["pwm_range_source"] == "MOT_PWM_MIN/MAX"
    rates = received(vehicle, mav.MAV_CMD_SET_MESSAGE_INTERVAL)
    assert sorted(int(c.params[0]) for c in rates) == [1, 36, 147, 11030]
    unset, _, _, _ = ardupilot(
        ArduPilotVehicle(ConstantPlant(), params={"MOT_PWM_MIN": 0, "MOT_PWM_MAX": 0})
    )
    assert unset.identify().details["pwm_range_source"] == "default"  # no RC3_* in the sim
    assert (unset.throttle_scale.lo, unset.throttle_scale.hi) == (1000.0, 2000.0)


def test_ardupilot_spin_keepalive_armed_during_test_and_verified_stop() -> None:
    out, vehicle, clock, _ = ardupilot()
    out.identify()
    out.set_throttle({0: 1500.0})
    spin_for(out, clock, 8.0)  # 4x the 2 s timeout; HEARTBEAT says ARMED all along
    assert vehicle.motor_test_running and vehicle.armed
    assert out.session.heartbeat is not None and out.session.heartbeat.value.armed
    out.set_throttle({0: 1300.0})  # ARMED during our own test is not a pre-armed vehicle
    spin_for(out, clock, 1.0)
    tel = out.read_telemetry()
    assert tel.rpm == (9000.0, 0.0, 0.0, 0.0) and tel.temperature_c == (25.0,) * 4
    assert tel.voltage_v == pytest.approx(16.792)
    tests = received(vehicle, mav.MAV_CMD_DO_MOTOR_TEST)
    assert all(c.params[:2] == (1.0, 1.0) and c.params[3] == 2.0 for c in tests)  # PWM, 2 s
    assert [c.params[2] for c in tests] == [1500.0] * 17 + [1300.0] * 3
    assert out.stop_and_verify()
    assert is_ardupilot_stop(vehicle.commands_received[-1])
    assert (vehicle.armed, rpm(vehicle, clock)[0]) == (False, 0.0)


def test_ardupilot_restart_right_after_stop_waits_for_a_fresh_heartbeat() -> None:
    """The last HEARTBEAT before the stop said ARMED (our test): that must not refuse a restart."""
    out, vehicle, clock, _ = ardupilot()
    out.identify()
    out.set_throttle({0: 1400.0})
    spin_for(out, clock, 1.5)
    out.stop()  # no verify: the latest HEARTBEAT still says ARMED
    assert out.session.heartbeat is not None and out.session.heartbeat.value.armed
    out.set_throttle({1: 1400.0})
    assert vehicle.motor_test_running and rpm(vehicle, clock)[1] == pytest.approx(12000.0)
    assert out.stop_and_verify()


class PilotArmedArduPilot(ArduPilotVehicle):
    """Test double: a vehicle a pilot has armed (no motor test running)."""

    @property
    def armed(self) -> bool:
        return True


def test_ardupilot_refuses_a_pre_armed_vehicle() -> None:
    out, vehicle, _, _ = ardupilot(PilotArmedArduPilot(ConstantPlant()))
    with pytest.raises(SafetyError, match="ARMED"):
        out.identify()
    assert received(vehicle, mav.MAV_CMD_DO_MOTOR_TEST) == []


def test_ardupilot_not_landed_failed_plus_statustext_is_a_safety_error() -> None:
    out, vehicle, clock, _ = ardupilot(ArduPilotVehicle(ConstantPlant(), landed=False))
    with out:
        out.identify()
        with pytest.raises(MotorTestRefused) as info:
            out.set_throttle({0: 1200.0})
    assert info.value.result == R.FAILED
    assert info.value.statustext == ("Motor Test: vehicle not landed",)
    assert "'Motor Test: vehicle not landed'" in str(info.value)
    assert out.last_stop_verified is True  # the refused stop is judged by HEARTBEAT and outputs
    assert rpm(vehicle, clock) == [0.0] * 4


def test_ardupilot_one_motor_at_a_time_and_instance_mapping() -> None:
    out, vehicle, clock, _ = ardupilot(instances=[1, 4, 2, 3])
    out.identify()
    with pytest.raises(SafetyError, match="one motor at a time"):
        out.set_throttle({0: 1200.0, 1: 1200.0})
    out.set_throttle({1: 1600.0})  # motor 2 -> instance 4 as given -> the sim's quad X: Motor3
    assert received(vehicle, mav.MAV_CMD_DO_MOTOR_TEST)[-1].params[0] == 4.0
    assert rpm(vehicle, clock) == [0.0, 0.0, pytest.approx(18000.0), 0.0]
    with pytest.raises(SafetyError):
        out.set_throttle({0: 2100.0})  # above MOT_PWM_MAX
    assert out.stop_and_verify()
    with pytest.raises(ConfigError):
        ardupilot(instances=[0, 1])


# ------------------------------------------------------------------------------------------
# Safety: every way out of the context manager puts the stop on the wire and verifies it
# ------------------------------------------------------------------------------------------
DRIVERS: dict[str, tuple[Callable[..., Any], float, Callable[[mav.CommandLong], bool]]] = {
    "px4": (px4, 0.5, is_px4_stop),
    "ardupilot": (ardupilot, 1500.0, is_ardupilot_stop),
}


class Boom(RuntimeError):
    pass


def _raise(kind: str) -> None:
    if kind == "exception":
        raise Boom("plan failed")
    if kind == "keyboard":
        raise KeyboardInterrupt
    if kind == "sigterm":
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0)  # the handler runs at the next bytecode boundary


@pytest.mark.parametrize("driver", sorted(DRIVERS))
@pytest.mark.parametrize("exit_path", ["normal", "exception", "keyboard", "sigterm"])
def test_every_exit_path_stops_and_verifies(driver: str, exit_path: str) -> None:
    make, level, is_stop = DRIVERS[driver]
    out, vehicle, clock, _ = make()
    expected = {"normal": None, "exception": Boom, "keyboard": KeyboardInterrupt}.get(
        exit_path, Terminated
    )
    with terminate_as_exception():
        try:
            with out:
                out.identify()
                out.set_throttle({0: level})
                spin_for(out, clock, 3.0)
                assert rpm(vehicle, clock)[0] > 0
                _raise(exit_path)
        except (Boom, KeyboardInterrupt) as exc:
            assert expected is not None and isinstance(exc, expected)
        else:
            assert expected is None
    assert out.last_stop_verified is True
    assert is_stop(vehicle.commands_received[-1])
    assert rpm(vehicle, clock) == [0.0] * 4 and not vehicle.armed
    assert not out.link.port.is_open  # closed after the stop


@pytest.mark.parametrize("driver", sorted(DRIVERS))
def test_peer_disappearing_mid_run_raises_link_lost_and_still_sends_the_stop(
    driver: str, caplog: pytest.LogCaptureFixture
) -> None:
    make, level, is_stop = DRIVERS[driver]
    out, vehicle, clock, peer = make()
    with caplog.at_level(logging.WARNING), pytest.raises(MavlinkLinkLost), out:
        out.identify()
        out.set_throttle({0: level})
        spin_for(out, clock, 1.0)
        peer.silent = True  # the vehicle still hears us; we hear nothing
        silent_at = len(vehicle.commands_received)
        spin_for(out, clock, 5.0)  # keepalive's ACK never comes -> MavlinkLinkLost
    after = vehicle.commands_received[silent_at:]
    assert any(is_stop(c) for c in after)  # the stop reached the vehicle ...
    assert is_stop(vehicle.commands_received[-1])  # ... and was the last thing sent
    assert out.last_stop_verified is False  # no ACK, so not verified: the user is told
    assert "COULD NOT VERIFY MOTOR STOP" in caplog.text
    assert rpm(vehicle, clock) == [0.0] * 4  # the vehicle did act on it


def test_heartbeat_loss_is_detected_by_read_telemetry() -> None:
    out, _, clock, peer = px4()
    out.identify()
    peer.silent = True
    clock.sleep_s(2.0)
    out.read_telemetry()  # 2 s: still within the 3 s heartbeat timeout
    clock.sleep_s(1.5)
    with pytest.raises(MavlinkLinkLost, match="no HEARTBEAT"):
        out.read_telemetry()


def test_transport_failure_is_link_lost_and_stop_still_tries() -> None:
    out, vehicle, clock, _ = px4()
    out.identify()
    out.set_throttle({0: 0.4})
    out.link.port.close()  # USB unplugged
    with pytest.raises(MavlinkLinkLost, match="transport failed"):
        out.keepalive()
    assert out.stop_and_verify() is False  # tried, reported, did not raise


# ------------------------------------------------------------------------------------------
# Factory
# ------------------------------------------------------------------------------------------
class GenericVehicle(PX4Vehicle):
    autopilot = mav.Autopilot.GENERIC


def test_factory_picks_the_driver_by_heartbeat() -> None:
    for vehicle, cls in (
        (PX4Vehicle(ConstantPlant()), Px4ThrottleOutput),
        (ArduPilotVehicle(ConstantPlant()), ArduPilotThrottleOutput),
    ):
        clock, link, _ = connect(vehicle)
        out = open_mavlink_output(link, clock, test_timeout_s=1.5)
        assert type(out) is cls and out.test_timeout_s == 1.5
        assert (out.target_system, out.target_component) == (1, 1)
    clock, link, _ = connect(ArduPilotVehicle(ConstantPlant()))
    with pytest.raises(ConfigError, match="expected a px4 vehicle.*autopilot 3"):
        open_mavlink_output(link, clock, autopilot="px4")
    clock, link, _ = connect(GenericVehicle(ConstantPlant()))
    with pytest.raises(UnsupportedAutopilot, match="autopilot 0"):
        open_mavlink_output(link, clock)
    clock, link, peer = connect(PX4Vehicle(ConstantPlant()))
    peer.silent = True
    with pytest.raises(MavlinkLinkLost, match="no HEARTBEAT"):
        open_mavlink_output(link, clock, heartbeat_timeout_s=2.0)
    assert clock.now_s() == pytest.approx(2.0, abs=0.01)


def test_factory_opens_a_sim_url() -> None:
    clock = SimClock()
    out = open_mavlink_output("sim://ardupilot?motors=4", clock, autopilot="ardupilot")
    with out:
        assert out.identify().kind == "ardupilot"
    assert out.last_stop_verified is True


# ------------------------------------------------------------------------------------------
# Recorded fixtures: strict replay through the same driver code
# ------------------------------------------------------------------------------------------
def written_frames(path: Path) -> list[Any]:
    codec = mav.MavlinkCodec()
    return codec.feed(read_transcript(path).written())


EXPECTED_TELEMETRY = {
    "px4_spin": [(16.764, 3.75, (15000.0, 0.0, 0.0, 0.0), None)] * 6
    + [(16.792, 0.81, (9000.0, 0.0, 0.0, 0.0), None)] * 6,
    "ardupilot_spin": [(16.762, 3.75, (15000.0, 0.0, 0.0, 0.0), (25.0,) * 4)] * 6
    + [(16.792, 0.81, (9000.0, 0.0, 0.0, 0.0), (25.0,) * 4)] * 6,
}
EXPECTED_ERRORS = {
    "px4_denied_safety": "px4 refused ACTUATOR_TEST motor 1 (output 1) = 0.2 (DENIED). PX4 denies "
    "actuator "
    "tests while armed, with the safety switch on, or when COM_MOT_TEST_EN != 1 (check the "
    "safety switch)",
    "ardupilot_not_landed": "ardupilot refused DO_MOTOR_TEST motor 1 (test order A) = 1200 µs "
    "(FAILED): 'Motor Test: vehicle not landed'",
}


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_fixture_replays_strictly_with_the_recorded_values(name: str) -> None:
    result, port = replay_scenario(name, FIXTURES)
    report = port.assert_consumed()  # every recorded write matched byte for byte, all read
    assert report.write_bytes_matched > 0 and report.mismatches == 0
    assert result.identity is not None
    assert result.identity["kind"] == name.split("_")[0]
    assert (result.identity["motor_count"], result.identity["battery_cells"]) == (
        4,
        4 if name.startswith("px4") else None,
    )
    assert result.telemetry == EXPECTED_TELEMETRY.get(name, [])
    assert result.error == EXPECTED_ERRORS.get(name)
    assert result.error_type == ("MotorTestRefused" if name in EXPECTED_ERRORS else None)
    assert result.stop_verified is True


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_fixture_ends_with_the_stop_sequence_in_exact_bytes(name: str) -> None:
    frames = written_frames(FIXTURES / f"{name}.jsonl")
    commands = [
        (f, mav.CommandLong.from_message(f)) for f in frames if f.get_type() == "COMMAND_LONG"
    ]
    if name.startswith("px4"):
        expected = [mav.actuator_test_stop(m) for m in (1, 2, 3, 4)]
    elif name == "ardupilot_not_landed":
        # The refused command started nothing, and an ArduPilot "stop" sent while no test runs
        # STARTS one: the last command written is the refused one, no stop follows.
        assert [c.command for _, c in commands][-1] == mav.MAV_CMD_DO_MOTOR_TEST
        last = commands[-1][1]
        assert last.params[2] == 1200.0 and last.params[3] > 0
        assert frames[-1] is commands[-1][0]
        return
    else:
        expected = [mav.motor_test_stop(1)]
    tail = commands[-len(expected) :]
    assert [c for _, c in tail][0].command == expected[0].command
    for (frame, decoded), want in zip(tail, expected, strict=True):
        assert decoded.command == want.command and decoded.params[4] == want.params[4]
        assert decoded.params[1:] == want.params[1:] and (
            math.isnan(decoded.params[0]) == math.isnan(want.params[0])
        )
        # The exact bytes: what pymavlink packs for this command from (255, 190) at this seq.
        packer = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        packer.seq = frame.get_seq()
        assert bytes(frame.get_msgbuf()) == bytes(want.to_message().pack(packer))
    assert frames[-1] is tail[-1][0]  # nothing written after the stop (verify only listens)


def test_fixtures_are_current_with_the_generator(tmp_path: Path) -> None:
    """Regenerate with ``python -m support.mavlink_transcripts``; this fails if stale."""
    for name in SCENARIOS:
        path, _ = record_scenario(name, tmp_path)
        fresh, shipped = read_transcript(path), read_transcript(FIXTURES / f"{name}.jsonl")
        assert [(e.time_s, e.direction, e.data) for e in fresh.events] == [
            (e.time_s, e.direction, e.data) for e in shipped.events
        ], f"{name}: fixture is stale; run python -m support.mavlink_transcripts"


# ------------------------------------------------------------------------------------------
# Loopback through pymavlink's own UDP connection (127.0.0.1 only, bounded)
# ------------------------------------------------------------------------------------------
def test_px4_driver_over_stock_mavutil_udp_loopback() -> None:
    host = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255)
    port = host.port.getsockname()[1]
    clock = MonotonicClock()
    vehicle = PX4Vehicle(ConstantPlant())
    started = time.monotonic()
    try:
        with UdpVehicleLink(vehicle, port, clock) as vlink:
            host.idle_hooks.append(lambda _conn: vlink.pump())
            vlink.pump()
            out = open_mavlink_output(host, clock, param_timeout_s=0.1)
            with out:
                assert out.identify().motor_count == 4
                out.set_throttle({0: 0.4})
                assert vehicle.running_motors() == {0: pytest.approx(0.4)}
                out.keepalive()
            assert out.last_stop_verified is True and vehicle.running_motors() == {}
    finally:
        host.close()
    assert time.monotonic() - started < 5.0


# ------------------------------------------------------------------------------------------
# End to end: the runner with a MAVLink throttle output
# ------------------------------------------------------------------------------------------
class PlantStand(Stand):
    """Test double (this file only): a 'stand' reading the plant's state at the clock's time."""

    def __init__(self, plant: Plant, clock: SimClock) -> None:
        self.plant, self.clock = plant, clock

    def identify(self) -> DeviceIdentity:
        return DeviceIdentity(kind="test-plant-stand")

    def read_samples(self) -> list[StandSample]:
        s = self.plant.state(self.clock.now_s())
        return [StandSample(s.time_s, s.thrust_n, s.torque_nm, s.voltage_v, s.current_a)]

    def tare(self, service: object = None) -> None:
        pass

    def close(self) -> None:
        pass


@pytest.mark.parametrize("driver", ["px4", "ardupilot"])
def test_runner_sweeps_with_a_mavlink_output(driver: str, tmp_path: Path) -> None:
    plant = make_plant("xnova-2207-6s", rotors_on_esc=1, seed=1)
    vehicle: SimMavlinkVehicle = (
        PX4Vehicle(plant, cells=6) if driver == "px4" else ArduPilotVehicle(plant)
    )
    clock, link, _ = connect(vehicle)
    out = open_mavlink_output(link, clock, autopilot=driver)
    writer = DsWriter(tmp_path / "run.csv", out.throttle_scale, {"rig": driver})
    plan = plans.stairs(10, 40, 10, dwell_s=2.0)
    runner = Runner(plan, out, PlantStand(plant, clock), writer, clock, limits=Limits(cells=6))
    result = runner.run()
    assert (result.status, result.reason, result.stop_verified) == ("completed", "", True)
    assert result.samples > 300
    rows = (tmp_path / "run.csv").read_text().splitlines()
    header = rows[0].split(",")
    col = {name: header.index(name) for name in ("thrust_n", "rpm", "step", "phase")}
    table = [
        cells for cells in (row.split(",") for row in rows[1:]) if cells[col["phase"]] != "stop"
    ]
    by_step: dict[int, list[float]] = {}
    for cells in table:
        by_step.setdefault(int(float(cells[col["step"]])), []).append(float(cells[col["thrust_n"]]))
    ends = [values[-1] for _, values in sorted(by_step.items())]
    assert len(ends) == 4 and all(b > a for a, b in zip(ends, ends[1:], strict=False))
    assert all(cells[col["rpm"]] for cells in table[10:])  # ESC rpm from the FC, every row
    sent = [c for c in vehicle.commands_received if c.command in (209, 310)]
    runs = [c.params for c in sent if c.params[0 if driver == "px4" else 2] > 0]
    repeats = sum(a == b for a, b in zip(runs, runs[1:], strict=False))
    assert len(runs) >= 30 and repeats >= 12  # 4 slewed steps, and keep-alives every 0.5 s
    stop = vehicle.commands_received[-1]
    assert is_px4_stop(stop) if driver == "px4" else is_ardupilot_stop(stop)
    assert rpm(vehicle, clock)[0] < 0.5 * 20000  # unpowered and coasting down


@pytest.fixture(autouse=True)
def _no_real_sleep(
    monkeypatch: pytest.MonkeyPatch, request: pytest.FixtureRequest
) -> Iterator[None]:
    """Guard: only the loopback test may touch real time."""
    if "loopback" not in request.node.name:
        monkeypatch.setattr(time, "sleep", _forbidden_sleep)
    yield


def _forbidden_sleep(seconds: float) -> None:
    if seconds:
        raise AssertionError(f"a test slept for real ({seconds} s)")


def test_sim_px4_reports_a_consistent_vehicle() -> None:
    """Cells from the plant's pack (6S at 24.9 V, not 4), motors from the frame (a quadx, not the
    one rotor on the stand); motors off the stand are accepted and drive nothing."""
    plant = make_plant("xnova-2207-6s", rotors_on_esc=1, seed=1, noise=False)
    out, vehicle, clock, _ = px4(PX4Vehicle(plant))
    ident = out.identify()
    assert (ident.battery_cells, ident.motor_count) == (6, 4)
    tel = out.read_telemetry()
    assert tel.voltage_v is not None and 3.3 * 6 < tel.voltage_v < 4.35 * 6
    out.set_throttle({2: 0.3})  # motor 3: not on the stand
    spin_for(out, clock, 1.0)
    assert plant.state(clock.now_s()).rpm[0] == 0.0
    assert out.stop_and_verify()
    constant = PX4Vehicle(ConstantPlant(motor_count=1))  # 16.8 V: a 4S pack
    assert (constant.cells, constant.motor_count) == (4, 4)
