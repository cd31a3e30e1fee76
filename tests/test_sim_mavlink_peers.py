"""Simulated PX4 and ArduPilot vehicles: the motor-test quirks, telemetry, and a loopback link."""

from __future__ import annotations

import math
import struct
import time
from typing import Any

import pytest
from pymavlink import mavutil

from thrustmap.core.clock import SimClock
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink.link import MavlinkSerialLink, open_mavlink
from thrustmap.protocols.mavlink.params import ParamEncoding, ParamType
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.sim.mavlink_loopback import UdpVehicleLink
from thrustmap.rig.sim.mavlink_peers import ArduPilotVehicle, PX4Vehicle
from thrustmap.rig.sim.mavlink_vehicle import SimMavlinkVehicle
from thrustmap.rig.sim.plant import ConstantPlant

R = mav.MavResult


def connect(vehicle: SimMavlinkVehicle) -> tuple[SimClock, MavlinkSerialLink]:
    clock = SimClock()
    return clock, MavlinkSerialLink(SimSerial(vehicle, clock, timeout=0), clock)


def command(link: MavlinkSerialLink, cmd: mav.CommandLong) -> mav.CommandAck:
    link.mav.send(cmd.to_message())
    ack = mav.decode(link.recv_match(type="COMMAND_ACK", blocking=True, timeout=1.0))
    assert isinstance(ack, mav.CommandAck) and ack.command == cmd.command
    return ack


def collect(link: MavlinkSerialLink, clock: SimClock, kind: str, until_s: float) -> list[Any]:
    """Every ``kind`` message received until the sim clock reaches ``until_s``, decoded."""
    out = []
    while clock.now_s() < until_s:
        msg = link.recv_match(type=kind, blocking=True, timeout=until_s - clock.now_s())
        if msg is not None:
            out.append(mav.decode(msg) if mav.decode(msg) is not None else msg)
    return out


def latest(link: MavlinkSerialLink, clock: SimClock, kind: str, until_s: float) -> Any:
    messages = collect(link, clock, kind, until_s)
    assert messages, f"no {kind} before t={until_s}"
    return messages[-1]


# ------------------------------------------------------------------------------------------
# PX4
# ------------------------------------------------------------------------------------------
def test_px4_heartbeat_at_1hz_and_identity() -> None:
    clock, link = connect(PX4Vehicle(ConstantPlant()))
    beats = collect(link, clock, "HEARTBEAT", 4.99)
    assert len(beats) == 5  # t = 0, 1, 2, 3, 4
    assert all(b.autopilot == mav.Autopilot.PX4 and not b.armed for b in beats)


def test_px4_answers_do_motor_test_unsupported() -> None:
    vehicle = PX4Vehicle(ConstantPlant())
    _, link = connect(vehicle)
    assert command(link, mav.motor_test(1, 1500, timeout_s=2)).result == R.UNSUPPORTED
    assert vehicle.running_motors() == {}


@pytest.mark.parametrize(("timeout_s", "effective_s"), [(0.0, 3.0), (10.0, 3.0), (1.0, 1.0)])
def test_px4_actuator_test_timeout_is_capped_and_motor_stops_by_itself(
    timeout_s: float, effective_s: float
) -> None:
    vehicle = PX4Vehicle(ConstantPlant())
    clock, link = connect(vehicle)
    raw = mav.actuator_test(1, 0.5, timeout_s=3.0)  # builder clamps; send the raw timeout instead
    cmd = mav.CommandLong(raw.command, (0.5, timeout_s, 0, 0, 1, 0, 0))
    assert command(link, cmd).result == R.ACCEPTED
    start_s = clock.now_s()
    running = latest(link, clock, "SERVO_OUTPUT_RAW", start_s + effective_s - 0.05)
    assert running.outputs_us[:4] == (1500, 900, 900, 900)
    assert vehicle.plant.state(clock.now_s()).rpm[0] == pytest.approx(15000.0)
    stopped = latest(link, clock, "SERVO_OUTPUT_RAW", start_s + effective_s + 0.25)
    assert stopped.outputs_us[0] == 900
    assert vehicle.plant.state(clock.now_s()).rpm[0] == 0.0


def test_px4_nan_stops_at_once() -> None:
    vehicle = PX4Vehicle(ConstantPlant())
    clock, link = connect(vehicle)
    command(link, mav.actuator_test(3, 0.8, timeout_s=3.0))
    assert vehicle.running_motors() == {2: pytest.approx(0.8)}
    assert command(link, mav.actuator_test_stop(3)).result == R.ACCEPTED
    assert vehicle.running_motors() == {}
    assert vehicle.plant.state(clock.now_s()).rpm[2] == 0.0


def test_px4_denies_when_armed_or_safety_on() -> None:
    for vehicle in (
        PX4Vehicle(ConstantPlant(), armed=True),
        PX4Vehicle(ConstantPlant(), safety_on=True),
    ):
        _, link = connect(vehicle)
        assert command(link, mav.actuator_test(1, 0.3)).result == R.DENIED
        assert vehicle.running_motors() == {}


def test_px4_denies_unless_com_mot_test_en_and_params_round_trip() -> None:
    vehicle = PX4Vehicle(ConstantPlant())
    clock, link = connect(vehicle)
    int32 = {"param_type": ParamType.INT32, "encoding": ParamEncoding.BYTEWISE}
    link.mav.send(mav.param_set("COM_MOT_TEST_EN", 0, **int32))  # as a GCS sets it on PX4
    echo = mav.decode(link.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0))
    assert isinstance(echo, mav.ParamValue) and echo.name == "COM_MOT_TEST_EN"
    assert echo.param_type == ParamType.INT32 and echo.number(ParamEncoding.BYTEWISE) == 0.0
    assert command(link, mav.actuator_test(1, 0.3)).result == R.DENIED
    link.mav.send(mav.param_set("COM_MOT_TEST_EN", 1, **int32))
    link.mav.send(mav.param_request_read("THR_MDL_FAC"))
    values = [
        mav.decode(m)
        for m in (link.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0) for _ in range(2))
    ]
    assert [
        (v.name, v.number(ParamEncoding.BYTEWISE)) for v in values if isinstance(v, mav.ParamValue)
    ] == [("COM_MOT_TEST_EN", 1.0), ("THR_MDL_FAC", 0.0)]
    # Bytewise on the wire, as real PX4: the float view of INT32 1 is the denormal 1.4e-45.
    enabled = values[0]
    assert isinstance(enabled, mav.ParamValue)
    assert struct.unpack("<f", enabled.raw)[0] == pytest.approx(1.4013e-45, rel=1e-3)
    assert command(link, mav.actuator_test(1, 0.3)).result == R.ACCEPTED


def test_px4_value_passes_through_thr_mdl_fac() -> None:
    vehicle = PX4Vehicle(ConstantPlant(), params={"THR_MDL_FAC": 0.5})
    clock, link = connect(vehicle)
    command(link, mav.actuator_test(1, 0.5))
    u = -0.5 + math.sqrt(1.25)  # solves 0.5·u² + 0.5·u = 0.5
    assert vehicle.running_motors()[0] == pytest.approx(u)
    assert vehicle.plant.state(clock.now_s()).rpm[0] == pytest.approx(30000.0 * u)


def test_px4_telemetry_reports_the_plant() -> None:
    vehicle = PX4Vehicle(ConstantPlant(voltage_v=16.0), cells=4)
    clock, link = connect(vehicle)
    command(link, mav.actuator_test(2, 1.0))
    esc = latest(link, clock, "ESC_STATUS", 0.5)
    state = vehicle.plant.state(clock.now_s())
    assert esc.rpm == (0.0, 30000.0, 0.0, 0.0)
    assert esc.current_a[1] == pytest.approx(30.0)
    sys_status = latest(link, clock, "SYS_STATUS", 0.8)
    assert sys_status.voltage_v == pytest.approx(state.voltage_v, abs=0.001)
    assert sys_status.current_a == pytest.approx(30.0, abs=0.01)
    battery = latest(link, clock, "BATTERY_STATUS", 1.0)
    assert len(battery.cell_voltages_v) == 4
    assert battery.total_voltage_v == pytest.approx(state.voltage_v, abs=0.004)


def test_sim_url_with_options_and_message_interval() -> None:
    from thrustmap.rig.devices.urls import load_sim_peers

    load_sim_peers()  # the rig binds sim://px4 (this test opens it below the rig)
    clock = SimClock()
    link = open_mavlink("sim://px4?armed=1&motors=2&rate_hz=5", clock=clock)
    hb = mav.decode(link.wait_heartbeat(timeout=1.0))
    assert isinstance(hb, mav.Heartbeat) and hb.armed
    assert command(link, mav.actuator_test(1, 0.2)).result == R.DENIED
    start_s = clock.now_s()
    assert 4 <= len(collect(link, clock, "ESC_STATUS", start_s + 1.0)) <= 6  # rate_hz=5
    assert command(link, mav.set_message_interval(291, 0.02)).accepted
    start_s = clock.now_s()
    assert 49 <= len(collect(link, clock, "ESC_STATUS", start_s + 1.0)) <= 52
    assert command(link, mav.set_message_interval(291, None)).accepted  # disable
    assert collect(link, clock, "ESC_STATUS", clock.now_s() + 1.0) == []
    assert len(collect(link, clock, "SYS_STATUS", clock.now_s() + 1.0)) >= 4  # others go on


# ------------------------------------------------------------------------------------------
# ArduPilot
# ------------------------------------------------------------------------------------------
def test_ardupilot_motor_test_arms_runs_and_times_out() -> None:
    vehicle = ArduPilotVehicle(ConstantPlant())
    clock, link = connect(vehicle)
    hb = mav.decode(link.wait_heartbeat(timeout=1.0))
    assert (
        isinstance(hb, mav.Heartbeat) and hb.autopilot == mav.Autopilot.ARDUPILOT and not hb.armed
    )
    assert command(link, mav.motor_test(1, 1500, timeout_s=2.0)).result == R.ACCEPTED
    assert latest(link, clock, "HEARTBEAT", 1.5).armed
    assert latest(link, clock, "SERVO_OUTPUT_RAW", 1.9).outputs_us[:4] == (1500, 1000, 1000, 1000)
    assert vehicle.plant.state(clock.now_s()).rpm[0] == pytest.approx(15000.0)
    assert not latest(link, clock, "HEARTBEAT", 3.5).armed
    assert latest(link, clock, "SERVO_OUTPUT_RAW", 3.6).outputs_us[0] == 1000
    assert vehicle.plant.state(clock.now_s()).rpm[0] == 0.0


def test_ardupilot_new_command_overwrites_throttle_and_restarts_timer() -> None:
    vehicle = ArduPilotVehicle(ConstantPlant())
    clock, link = connect(vehicle)
    command(link, mav.motor_test(1, 1500, timeout_s=2.0))
    clock.advance_s(1.5)
    command(link, mav.motor_test(1, 1700, timeout_s=2.0))
    restart_s = clock.now_s()
    assert latest(link, clock, "SERVO_OUTPUT_RAW", restart_s + 1.9).outputs_us[0] == 1700
    assert vehicle.motor_test_running  # the first timer (t=2.0) did not stop it
    assert latest(link, clock, "SERVO_OUTPUT_RAW", restart_s + 2.2).outputs_us[0] == 1000
    assert not vehicle.motor_test_running


@pytest.mark.parametrize(
    "stop",
    [
        mav.motor_test_stop(1),
        mav.motor_test(1, 1500, timeout_s=0.0),
        mav.motor_test(1, 2300, timeout_s=5.0),
        mav.motor_test(1, 700, timeout_s=5.0),
    ],
)
def test_ardupilot_timeout_zero_or_pwm_out_of_range_stops(stop: mav.CommandLong) -> None:
    vehicle = ArduPilotVehicle(ConstantPlant())
    clock, link = connect(vehicle)
    command(link, mav.motor_test(1, 1600, timeout_s=10.0))
    assert vehicle.plant.state(clock.now_s()).rpm[0] > 0
    assert command(link, stop).result == R.ACCEPTED
    assert not vehicle.motor_test_running and not vehicle.armed
    assert vehicle.plant.state(clock.now_s()).rpm[0] == 0.0


@pytest.mark.parametrize(
    ("kwargs", "throttle_type", "text"),
    [
        ({"landed": False}, mav.MotorTestThrottleType.PWM, "Motor Test: vehicle not landed"),
        (
            {"safety_switch_engaged": True},
            mav.MotorTestThrottleType.PWM,
            "Motor Test: Safety switch",
        ),
        ({"initialised": False}, mav.MotorTestThrottleType.PWM, "Motor Test: Board initialising"),
        (
            {"rc_calibrated": False},
            mav.MotorTestThrottleType.PERCENT,
            "Motor Test: RC not calibrated",
        ),
    ],
)
def test_ardupilot_precondition_failures(
    kwargs: dict[str, bool], throttle_type: mav.MotorTestThrottleType, text: str
) -> None:
    vehicle = ArduPilotVehicle(ConstantPlant(), **kwargs)  # type: ignore[arg-type]
    clock, link = connect(vehicle)
    value = 1500 if throttle_type == mav.MotorTestThrottleType.PWM else 50
    link.mav.send(mav.motor_test(1, value, timeout_s=2, throttle_type=throttle_type).to_message())
    status = mav.decode(link.recv_match(type="STATUSTEXT", blocking=True, timeout=1.0))
    ack = mav.decode(link.recv_match(type="COMMAND_ACK", blocking=True, timeout=1.0))
    assert status == mav.StatusText(mav.Severity.CRITICAL, text)
    assert isinstance(ack, mav.CommandAck) and ack.result == R.FAILED
    assert not vehicle.motor_test_running and vehicle.plant.state(clock.now_s()).rpm[0] == 0.0


def test_ardupilot_pwm_type_does_not_need_rc_calibration_and_percent_maps_linearly() -> None:
    vehicle = ArduPilotVehicle(ConstantPlant(), rc_calibrated=False)
    clock, link = connect(vehicle)
    assert command(link, mav.motor_test(1, 1250, timeout_s=1)).accepted
    assert vehicle.outputs_us()[0] == 1250
    calibrated = ArduPilotVehicle(
        ConstantPlant(), params={"MOT_PWM_MIN": 1100, "MOT_PWM_MAX": 1900}
    )
    _, link2 = connect(calibrated)
    pct = mav.motor_test(1, 25, timeout_s=1, throttle_type=mav.MotorTestThrottleType.PERCENT)
    assert command(link2, pct).accepted
    assert calibrated.outputs_us()[0] == 1300


def test_ardupilot_motor_count_runs_motors_in_test_order() -> None:
    vehicle = ArduPilotVehicle(ConstantPlant(), test_order=[0, 3, 1, 2])  # test seq 2 = motor 4
    clock, link = connect(vehicle)
    command(link, mav.motor_test(1, 1400, timeout_s=1.0, motor_count=2))
    assert latest(link, clock, "SERVO_OUTPUT_RAW", 0.9).outputs_us[:4] == (1400, 1000, 1000, 1000)
    assert latest(link, clock, "SERVO_OUTPUT_RAW", 1.9).outputs_us[:4] == (1000, 1000, 1000, 1400)
    assert latest(link, clock, "SERVO_OUTPUT_RAW", 2.3).outputs_us[:4] == (1000, 1000, 1000, 1000)
    assert not vehicle.armed


def test_ardupilot_esc_telemetry_and_battery_total() -> None:
    vehicle = ArduPilotVehicle(ConstantPlant(voltage_v=12.0))
    clock, link = connect(vehicle)
    command(link, mav.motor_test(2, 2000, timeout_s=5))  # test order B = Motor4 on a quad X
    esc = latest(link, clock, "ESC_TELEMETRY_1_TO_4", 0.5)
    assert esc.rpm == (0.0, 0.0, 0.0, 30000.0)
    assert esc.current_a[3] == pytest.approx(30.0) and esc.temperature_c[3] == 25.0
    battery = latest(link, clock, "BATTERY_STATUS", 0.6)
    assert battery.cell_voltages_v == () and battery.total_voltage_v == pytest.approx(
        11.7, abs=0.001
    )


def test_ardupilot_rejects_actuator_test() -> None:
    _, link = connect(ArduPilotVehicle(ConstantPlant()))
    assert command(link, mav.actuator_test(1, 0.5)).result == R.UNSUPPORTED


# ------------------------------------------------------------------------------------------
# Loopback through pymavlink's own UDP connections (127.0.0.1 only, bounded)
# ------------------------------------------------------------------------------------------
def test_loopback_udp_with_stock_mavutil_connection() -> None:
    host = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255)
    port = host.port.getsockname()[1]
    clock = SimClock()
    vehicle = PX4Vehicle(ConstantPlant())
    started = time.monotonic()
    try:
        with UdpVehicleLink(vehicle, port, clock) as link:
            link.pump()
            hb = host.recv_match(type="HEARTBEAT", blocking=True, timeout=2.0)
            assert mav.decode(hb) is not None and hb.autopilot == mav.Autopilot.PX4
            host.mav.send(mav.actuator_test(1, 0.4, timeout_s=1.0).to_message())
            ack = None
            for _ in range(200):
                clock.advance_s(0.01)
                link.pump()
                ack = host.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.01)
                if ack is not None:
                    break
            assert ack is not None and ack.result == R.ACCEPTED
            assert vehicle.running_motors() == {0: pytest.approx(0.4)}
    finally:
        host.close()
    assert time.monotonic() - started < 5.0


def test_loopback_refuses_non_loopback_hosts() -> None:
    from thrustmap.core.errors import ConfigError

    with pytest.raises(ConfigError, match="loopback"):
        UdpVehicleLink(PX4Vehicle(ConstantPlant()), 14550, SimClock(), host="192.168.1.10")
