"""The simulated MSP flight controller answers with real firmware's quirks."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thrustmap.core.clock import SimClock
from thrustmap.core.errors import ConfigError
from thrustmap.protocols.msp.framing import (
    MspCommand,
    MspDecoder,
    MspDirection,
    MspFrame,
    MspVersion,
    encode_request,
)
from thrustmap.protocols.msp.messages import (
    Analog,
    ApiVersion,
    ArmingDisable,
    BatteryState,
    FcVariant,
    FcVersion,
    InavAnalog,
    SetArmingDisabled,
    StatusEx,
    decode_reply,
)
from thrustmap.protocols.msp.motor import (
    Motor,
    MotorConfig,
    MotorProtocol,
    MotorTelemetry,
    SetMotor,
)
from thrustmap.protocols.peer import BytePeer
from thrustmap.protocols.transport import open_transport
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.sim.msp_peer import MspPeer, msp_peer_from_options
from thrustmap.rig.sim.plant import ConstantPlant


def ask(
    peer: MspPeer, cmd: int, payload: bytes = b"", version: MspVersion = MspVersion.V1, t: float = 0
) -> list[MspFrame]:
    peer.write(encode_request(cmd, payload, version), t)
    return MspDecoder().feed(peer.read(t + 1.0))


def ask_one(peer: MspPeer, cmd: int, payload: bytes = b"", t: float = 0.0) -> MspFrame:
    (frame,) = ask(peer, cmd, payload, t=t)
    return frame


def test_is_a_byte_peer() -> None:
    assert isinstance(MspPeer(ConstantPlant()), BytePeer)


@pytest.mark.parametrize(
    ("firmware", "variant", "version", "api"),
    [
        ("betaflight-4", "BTFL", "4.5.1", (0, 1, 46)),
        ("betaflight-2025", "BTFL", "2025.12.0", (0, 1, 47)),
        ("inav", "INAV", "8.0.0", (0, 2, 5)),
    ],
)
def test_identity(firmware: str, variant: str, version: str, api: tuple[int, int, int]) -> None:
    peer = MspPeer(ConstantPlant(), firmware)
    assert FcVariant.decode(ask_one(peer, 2).payload).identifier == variant
    assert str(FcVersion.decode(ask_one(peer, 3, t=1).payload)) == version
    assert ApiVersion.decode(ask_one(peer, 1, t=2).payload) == ApiVersion(*api)


@pytest.mark.parametrize("version", list(MspVersion))
def test_replies_in_the_request_version(version: MspVersion) -> None:
    (frame,) = ask(MspPeer(ConstantPlant()), MspCommand.API_VERSION, version=version)
    assert frame.version is version and frame.direction is MspDirection.REPLY


def test_unknown_command_gets_error_reply() -> None:
    frame = ask_one(MspPeer(ConstantPlant()), 250)
    assert frame.direction is MspDirection.ERROR and frame.cmd == 250 and frame.payload == b""


def test_bad_checksum_and_oversized_requests_get_no_reply() -> None:
    peer = MspPeer(ConstantPlant())
    bad = bytearray(encode_request(1))
    bad[-1] ^= 0x55
    peer.write(bytes(bad), 0.0)
    peer.write(encode_request(214, bytes(200), MspVersion.V2), 0.0)
    assert peer.read(5.0) == b""
    assert ask_one(peer, 1, t=6).cmd == 1  # resynchronised: the next good request is served
    assert peer.requests_ignored == 2


def test_set_motor_drives_the_plant_and_persists_forever() -> None:
    plant = ConstantPlant(4)
    peer = MspPeer(plant, motor_protocol=MotorProtocol.DSHOT600)
    reply = ask_one(peer, 214, SetMotor.for_motors({0: 1500, 2: 2000}).encode())
    assert reply.direction is MspDirection.REPLY and reply.payload == b""
    state = plant.state(10.0)
    assert state.rpm[0] == pytest.approx(30000 * (1500 - 1001) / 999)
    assert state.rpm[1] == 0.0 and state.rpm[2] == pytest.approx(30000)
    peer.close()  # the host goes away: nothing stops the motors
    motor = Motor.decode(ask_one(peer, 104, t=3600.0).payload)
    assert motor.values == (1500, 1000, 2000, 1000, 0, 0, 0, 0)
    assert plant.state(3601.0).rpm[0] > 0


def test_pwm_mapping() -> None:
    plant = ConstantPlant(1)
    peer = MspPeer(plant, motor_protocol=MotorProtocol.PWM)
    ask(peer, 214, SetMotor.for_motors([1250]).encode())
    assert plant.state(1.0).rpm[0] == pytest.approx(30000 * 0.25)


def test_short_set_motor_depends_on_firmware_generation() -> None:
    short = SetMotor((1300, 1300, 1300, 1300)).encode()
    new = MspPeer(ConstantPlant(), "betaflight-2025")
    assert ask_one(new, 214, short).direction is MspDirection.ERROR
    assert Motor.decode(ask_one(new, 104, t=1).payload).values[:4] == (1000,) * 4
    old = MspPeer(ConstantPlant(), "betaflight-4")
    assert ask_one(old, 214, short).direction is MspDirection.REPLY
    assert Motor.decode(ask_one(old, 104, t=1).payload).values[:4] == (1300,) * 4
    inav = MspPeer(ConstantPlant(), "inav")
    assert ask_one(inav, 214, short).direction is MspDirection.ERROR


def test_set_motor_refused_while_armed_and_restored_on_disarm() -> None:
    plant = ConstantPlant(4)
    peer = MspPeer(plant)
    ask(peer, 214, SetMotor.for_motors([1400] * 4).encode())
    peer.arm(1.0)
    assert plant.state(1.5).rpm[0] == 0.0
    assert ask_one(peer, 214, SetMotor.stop_all().encode(), t=2).direction is MspDirection.ERROR
    peer.disarm(3.0)
    assert plant.state(3.5).rpm[0] > 0  # the old value is back: this is why hosts must stop


def test_arming_disabled_is_reported_and_disarms() -> None:
    peer = MspPeer(ConstantPlant())
    status = StatusEx.decode(ask_one(peer, 150).payload)
    assert status.arming_disable_flags == 0 and not status.armed
    peer.arm(0.5)
    assert StatusEx.decode(ask_one(peer, 150, t=0.6).payload).armed
    ask(peer, 99, SetArmingDisabled(True).encode(), t=1)
    status = StatusEx.decode(ask_one(peer, 150, t=2).payload)
    assert not status.armed and status.arming_disable_flags == ArmingDisable.MSP
    ask(peer, 99, SetArmingDisabled(False).encode(), t=3)
    assert StatusEx.decode(ask_one(peer, 150, t=4).payload).arming_disable_flags == 0


def test_battery_and_telemetry_come_from_the_plant() -> None:
    plant = ConstantPlant(4, voltage_v=16.8)
    peer = MspPeer(plant)
    ask(peer, 214, SetMotor.for_motors([2000] * 4).encode())
    analog = Analog.decode(ask_one(peer, 110, t=1).payload)
    expected = plant.state(1.0)
    assert analog.voltage_v == pytest.approx(expected.voltage_v, abs=0.005)
    assert analog.current_a == pytest.approx(120.0, abs=0.005)
    battery = BatteryState.decode(ask_one(peer, 130, t=2).payload)
    assert battery.cell_count == 4 and battery.voltage_v == pytest.approx(15.6, abs=0.005)
    assert battery.voltage_coarse_v == pytest.approx(15.6)
    telem = MotorTelemetry.decode(ask_one(peer, 139, t=3).payload)
    assert len(telem.motors) == 4
    assert telem.motors[0].rpm == 30000 and telem.motors[0].current_a == pytest.approx(30.0)
    assert telem.motors[0].consumed_mah == int(30.0 * 1000 * 3 / 3600)


def test_consumed_mah_integrates_current() -> None:
    plant = ConstantPlant(1)
    peer = MspPeer(plant)
    ask(peer, 214, SetMotor.for_motors([2000]).encode())  # 30 A
    analog = Analog.decode(ask_one(peer, 110, t=360.0).payload)
    assert abs(analog.consumed_mah - 3000) <= 1  # 30 A for 0.1 h


def test_pwm_has_no_rpm_telemetry() -> None:
    peer = MspPeer(ConstantPlant(), motor_protocol=MotorProtocol.PWM)
    ask(peer, 214, SetMotor.for_motors([1600] * 4).encode())
    telem = MotorTelemetry.decode(ask_one(peer, 139, t=1).payload)
    assert all(m.rpm == 0 for m in telem.motors)
    config = MotorConfig.decode(ask_one(peer, 131, t=2).payload)
    assert not config.use_dshot_telemetry and config.motor_count == 4


def test_inav_analog_only_on_inav() -> None:
    inav = MspPeer(ConstantPlant(voltage_v=12.6), "inav")
    (frame,) = ask(inav, 0x2002, version=MspVersion.V2)
    reading = decode_reply(frame)
    assert isinstance(reading, InavAnalog) and reading.voltage_v == pytest.approx(12.6)
    (err,) = ask(MspPeer(ConstantPlant()), 0x2002, version=MspVersion.V2)
    assert err.is_error


def test_one_request_per_serial_task_run() -> None:
    peer = MspPeer(ConstantPlant(), serial_rate_hz=100.0)
    peer.write(encode_request(1) + encode_request(2), 0.0)
    assert len(MspDecoder().feed(peer.read(0.0))) == 1
    assert len(MspDecoder().feed(peer.read(0.005))) == 0
    assert len(MspDecoder().feed(peer.read(0.0101))) == 1


def test_stray_hash_enters_cli_and_silences_msp() -> None:
    peer = MspPeer(ConstantPlant())
    peer.write(b"#", 0.0)
    assert peer.in_cli
    assert ask(peer, 1, t=1) == []


def test_through_sim_serial_with_sim_clock() -> None:
    clock = SimClock()
    port = SimSerial(MspPeer(ConstantPlant()), clock, timeout=0.1)
    port.write(encode_request(101, version=MspVersion.V2))
    raw = port.read(64)
    (frame,) = MspDecoder().feed(raw)
    assert frame.cmd == 101 and frame.version is MspVersion.V2
    assert clock.now_s() <= 0.1  # a simulated wait, not a real one


def test_options_factory() -> None:
    peer = msp_peer_from_options({"firmware": "inav", "motors": "2", "protocol": "pwm"})
    assert peer.motor_count == 2 and peer.motor_protocol is MotorProtocol.PWM
    with pytest.raises(ConfigError, match="unknown simulated firmware"):
        msp_peer_from_options({"firmware": "kiss"})
    with pytest.raises(ConfigError, match="motor protocol"):
        msp_peer_from_options({"protocol": "dshot9000"})
    with pytest.raises(ConfigError, match="unknown MSP sim options"):
        msp_peer_from_options({"baud": "115200"})


@settings(max_examples=200)
@given(st.lists(st.binary(max_size=40), max_size=10))
def test_random_input_never_crashes_and_output_is_valid(chunks: list[bytes]) -> None:
    peer = MspPeer(ConstantPlant())
    out = b""
    for i, chunk in enumerate(chunks):
        peer.write(chunk.replace(b"#", b"").replace(b"R", b""), float(i))
        out += peer.read(float(i) + 0.5)
    decoder = MspDecoder()
    frames = decoder.feed(out)
    assert decoder.error_count == 0 and decoder.skipped_bytes == 0
    assert all(f.direction is not MspDirection.REQUEST for f in frames)


def test_sim_url_builds_the_registered_peer() -> None:
    from thrustmap.rig.devices.urls import load_sim_peers

    # the rig binds sim:// names (rig.sim.peers); importing a peer module registers nothing, and
    # protocols/ never finds the simulator by itself (test_rig_session checks that)
    load_sim_peers()
    clock = SimClock()
    port = open_transport("sim://inav?motors=2&rate_hz=unlimited", timeout=0.1, clock=clock)
    port.write(encode_request(2))
    (frame,) = MspDecoder().feed(port.read(16))
    assert FcVariant.decode(frame.payload).identifier == "INAV"
    port.close()
    with pytest.raises(ConfigError):
        open_transport("sim://betaflight?firmware=kiss", clock=clock)
