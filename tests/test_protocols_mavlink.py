"""MAVLink helpers: command builders, SI decoders with sentinels, codec chunking, ESC_STATUS."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from pymavlink.generator import mavparse

from thrustmap.core.errors import ConfigError
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink import encode as enc
from thrustmap.protocols.mavlink.ext import ESC_STATUS_XML, MAVLink_esc_status_message
from thrustmap.protocols.mavlink.params import ParamEncoding


def round_trip(msg: object) -> mav.Decoded | None:
    data = mav.MavlinkCodec(1, 1).encode(msg)
    assert data[0] == 0xFD  # MAVLink 2 frame
    (parsed,) = mav.MavlinkCodec().feed(data)
    return mav.decode(parsed)


optional_voltage = st.none() | st.floats(0.0, 65.0)
optional_current = st.none() | st.floats(0.0, 300.0)


@given(voltage_v=optional_voltage, current_a=optional_current, pct=st.none() | st.integers(0, 100))
def test_sys_status_round_trip_and_sentinels(
    voltage_v: float | None, current_a: float | None, pct: int | None
) -> None:
    decoded = round_trip(enc.sys_status_message(voltage_v, current_a, pct))
    assert isinstance(decoded, mav.SysStatus)
    if voltage_v is None:
        assert decoded.voltage_v is None
    else:
        assert decoded.voltage_v == pytest.approx(
            voltage_v, abs=0.00051
        )  # half a mV, ties included
    if current_a is None:
        assert decoded.current_a is None
    else:
        assert decoded.current_a == pytest.approx(
            current_a, abs=0.0051
        )  # half a centi-unit, rounding ties included
    assert decoded.remaining_pct == pct


def test_sys_status_raw_sentinels_decode_to_none() -> None:
    msg = mavlink2.MAVLink_sys_status_message(0, 0, 0, 0, 65535, -1, -1, 0, 0, 0, 0, 0, 0)
    assert round_trip(msg) == mav.SysStatus(voltage_v=None, current_a=None, remaining_pct=None)


@given(
    cells=st.lists(st.floats(2.5, 4.35), min_size=1, max_size=10),
    current_a=optional_current,
    temperature_c=st.none() | st.floats(-20.0, 80.0),
)
def test_battery_status_cells_round_trip(
    cells: list[float], current_a: float | None, temperature_c: float | None
) -> None:
    decoded = round_trip(enc.battery_status_message(cells, current_a, temperature_c=temperature_c))
    assert isinstance(decoded, mav.BatteryStatus)
    assert decoded.voltages_v == pytest.approx(cells, abs=0.0005)
    assert decoded.total_voltage_v == pytest.approx(sum(cells), abs=0.0005 * len(cells))
    assert decoded.cell_voltages_v == (decoded.voltages_v if len(cells) > 1 else ())
    assert (decoded.current_a is None) == (current_a is None)
    assert (decoded.temperature_c is None) == (temperature_c is None)
    assert decoded.consumed_mah is None and decoded.energy_consumed_j is None


def test_battery_status_total_in_first_entry_and_absent_cells() -> None:
    decoded = round_trip(enc.battery_status_message([16.2], 12.5, consumed_mah=321))
    assert isinstance(decoded, mav.BatteryStatus)
    assert decoded.voltages_v == (16.2,) and decoded.total_voltage_v == pytest.approx(16.2)
    assert decoded.cell_voltages_v == ()
    assert decoded.current_a == pytest.approx(12.5) and decoded.consumed_mah == 321.0


@given(
    rpm=st.lists(st.integers(0, 60000), min_size=4, max_size=4),
    volts=st.lists(st.floats(0.0, 60.0), min_size=4, max_size=4),
    amps=st.lists(st.floats(0.0, 600.0), min_size=4, max_size=4),
    temps=st.lists(st.integers(0, 150), min_size=4, max_size=4),
)
def test_esc_telemetry_round_trip(
    rpm: list[int], volts: list[float], amps: list[float], temps: list[int]
) -> None:
    msg = enc.esc_telemetry_message(rpm=rpm, voltage_v=volts, current_a=amps, temperature_c=temps)
    decoded = round_trip(msg)
    assert isinstance(decoded, mav.EscTelemetry)
    assert decoded.first_index == 0
    assert decoded.rpm == tuple(float(r) for r in rpm)
    assert decoded.voltage_v == pytest.approx(volts, abs=0.0051)
    assert decoded.current_a == pytest.approx(amps, abs=0.0051)
    assert decoded.temperature_c == tuple(float(t) for t in temps)


@given(
    rpm=st.lists(st.integers(-100000, 100000), min_size=4, max_size=4),
    volts=st.lists(st.floats(0.0, 60.0, width=32), min_size=4, max_size=4),
    time_s=st.floats(0.0, 1e6),
    first=st.sampled_from([0, 4, 8]),
)
def test_esc_status_round_trip(
    rpm: list[int], volts: list[float], time_s: float, first: int
) -> None:
    msg = enc.esc_status_message(
        time_s=time_s, rpm=rpm, voltage_v=volts, current_a=[1.5] * 4, first_index=first
    )
    decoded = round_trip(msg)
    assert isinstance(decoded, mav.EscStatus)
    assert decoded.first_index == first
    assert decoded.rpm == tuple(float(r) for r in rpm)
    assert decoded.voltage_v == pytest.approx(volts)
    assert decoded.current_a == (1.5, 1.5, 1.5, 1.5)
    assert decoded.time_s == pytest.approx(time_s, abs=1e-6)


def test_esc_status_definition_matches_pymavlinks_generator(tmp_path: Path) -> None:
    xml = tmp_path / "esc.xml"
    xml.write_text(
        f'<?xml version="1.0"?><mavlink><version>3</version><messages>{ESC_STATUS_XML}</messages></mavlink>'
    )
    (definition,) = mavparse.MAVXML(str(xml), mavparse.PROTOCOL_2_0).message
    assert definition.id == MAVLink_esc_status_message.id
    assert definition.crc_extra == MAVLink_esc_status_message.crc_extra
    assert definition.wire_length == MAVLink_esc_status_message.unpacker.size
    assert [
        f.name for f in definition.ordered_fields
    ] == MAVLink_esc_status_message.ordered_fieldnames


@given(outputs=st.lists(st.integers(0, 2500), min_size=0, max_size=16), time_s=st.floats(0, 4000))
def test_servo_output_raw_round_trip(outputs: list[int], time_s: float) -> None:
    decoded = round_trip(enc.servo_output_raw_message(time_s, outputs))
    assert isinstance(decoded, mav.ServoOutputRaw)
    assert decoded.outputs_us == tuple(outputs) + (0,) * (16 - len(outputs))


@pytest.mark.parametrize(("autopilot", "firmware"), [(12, "px4"), (3, "ardupilot"), (0, "other")])
@pytest.mark.parametrize("armed", [True, False])
def test_heartbeat(autopilot: int, firmware: str, armed: bool) -> None:
    decoded = round_trip(enc.heartbeat_message(autopilot, armed=armed))
    assert isinstance(decoded, mav.Heartbeat)
    assert decoded.armed is armed and decoded.firmware == firmware
    assert decoded.system_id == 1 and decoded.is_vehicle


@pytest.mark.parametrize("result", list(range(10)))
def test_command_ack_results(result: int) -> None:
    decoded = round_trip(enc.command_ack_message(310, result))
    assert isinstance(decoded, mav.CommandAck)
    assert decoded.command == 310 and int(decoded.result) == result
    assert decoded.accepted is (result == 0)
    assert isinstance(decoded.result, mav.MavResult)


def test_statustext_and_param_value() -> None:
    text = round_trip(enc.statustext_message("Motor Test: Safety switch", mav.Severity.CRITICAL))
    assert text == mav.StatusText(mav.Severity.CRITICAL, "Motor Test: Safety switch")
    param = round_trip(enc.param_value_message("THR_MDL_FAC", 0.25, 3, 7))
    assert param == mav.ParamValue("THR_MDL_FAC", struct.pack("<f", 0.25), 9, 3, 7)
    assert param.number(ParamEncoding.BYTEWISE) == param.number(ParamEncoding.C_CAST) == 0.25


def test_decode_ignores_other_messages() -> None:
    assert round_trip(mav.actuator_test(1, 0.1).to_message()) is None


# -- commands ---------------------------------------------------------------------------------
def test_do_motor_test_params() -> None:
    cmd = mav.motor_test(2, 1350, timeout_s=4.0, motor_count=1, target_system=3)
    assert cmd.command == 209 and cmd.target_system == 3
    assert cmd.params == (2.0, 1.0, 1350.0, 4.0, 1.0, 0.0, 0.0)
    pct = mav.motor_test(1, 40, timeout_s=2, throttle_type=mav.MotorTestThrottleType.PERCENT)
    assert pct.params[:4] == (1.0, 0.0, 40.0, 2.0)
    stop = mav.motor_test_stop(3)
    assert stop.params[:4] == (3.0, 1.0, 0.0, 0.0)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"motor_instance": 0, "value": 1200, "timeout_s": 1},
        {"motor_instance": 1, "value": 1200, "timeout_s": 601},
        {"motor_instance": 1, "value": 1200, "timeout_s": -1},
        {"motor_instance": 1, "value": 3000, "timeout_s": 1},
        {
            "motor_instance": 1,
            "value": 101,
            "timeout_s": 1,
            "throttle_type": mav.MotorTestThrottleType.PERCENT,
        },
    ],
)
def test_do_motor_test_rejects_bad_values(kwargs: dict[str, float]) -> None:
    with pytest.raises(ConfigError):
        mav.motor_test(**kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize(("given_s", "sent_s"), [(0.0, 3.0), (0.5, 0.5), (3.0, 3.0), (10.0, 3.0)])
def test_actuator_test_timeout_clamped_like_px4(given_s: float, sent_s: float) -> None:
    cmd = mav.actuator_test(4, 0.3, timeout_s=given_s)
    assert cmd.command == 310
    assert cmd.params[0] == pytest.approx(0.3) and cmd.params[1] == sent_s and cmd.params[4] == 4.0


def test_actuator_test_stop_is_nan_and_range_checks() -> None:
    assert math.isnan(mav.actuator_test_stop(1).params[0])
    for bad in (1.01, -1.5):
        with pytest.raises(ConfigError):
            mav.actuator_test(1, bad)
    with pytest.raises(ConfigError):
        mav.actuator_test(17, 0.1)
    with pytest.raises(ConfigError):
        mav.actuator_test(0, 0.1)


@given(
    value=st.floats(-1.0, 1.0, width=32) | st.just(math.nan),
    motor=st.integers(1, 16),
    timeout_s=st.floats(0.0, 100.0),
)
def test_command_long_survives_the_wire(value: float, motor: int, timeout_s: float) -> None:
    cmd = mav.actuator_test(motor, value, timeout_s=timeout_s)
    (parsed,) = mav.MavlinkCodec().feed(mav.MavlinkCodec(255, 190).encode(cmd.to_message()))
    back = mav.CommandLong.from_message(parsed)
    assert back.command == cmd.command and back.params[4] == float(motor)
    assert (math.isnan(back.params[0]) and math.isnan(value)) or back.params[0] == pytest.approx(
        value
    )
    assert back.params[1] == pytest.approx(cmd.params[1], rel=1e-6)


def test_set_message_interval() -> None:
    assert mav.set_message_interval(291, 0.02).params[:2] == (291.0, 20000.0)
    assert mav.set_message_interval(36, None).params[:2] == (36.0, -1.0)


# -- codec ------------------------------------------------------------------------------------
@settings(max_examples=50)
@given(cuts=st.lists(st.integers(0, 200), max_size=8))
def test_codec_parses_any_chunking(cuts: list[int]) -> None:
    sender = mav.MavlinkCodec(1, 1)
    msgs = [
        enc.heartbeat_message(12, armed=False),
        enc.sys_status_message(15.2, 3.5),
        enc.command_ack_message(209, 3),
        enc.esc_status_message(
            time_s=1.0, rpm=[1, 2, 3, 4], voltage_v=[15.0] * 4, current_a=[0.5] * 4
        ),
    ]
    data = b"".join(sender.encode(m) for m in msgs)
    points = sorted({min(c, len(data)) for c in cuts} | {0, len(data)})
    receiver = mav.MavlinkCodec()
    parsed = []
    for a, b in zip(points[:-1], points[1:], strict=True):
        parsed += receiver.feed(data[a:b])
    assert [p.get_type() for p in parsed] == [
        "HEARTBEAT",
        "SYS_STATUS",
        "COMMAND_ACK",
        "ESC_STATUS",
    ]
    assert [p.get_seq() for p in parsed] == [0, 1, 2, 3]


def test_codec_drops_a_corrupted_frame_and_resynchronises() -> None:
    sender = mav.MavlinkCodec(1, 1)
    first = bytearray(sender.encode(enc.sys_status_message(15.2, 3.5)))
    first[12] ^= 0xFF  # payload byte: CRC fails
    second = sender.encode(enc.command_ack_message(310, 2))
    receiver = mav.MavlinkCodec()
    parsed = receiver.feed(bytes(first) + b"\x00garbage" + second)
    assert [mav.decode(p) for p in parsed] == [mav.CommandAck(310, mav.MavResult.DENIED)]
    assert receiver.bad_frames >= 1
