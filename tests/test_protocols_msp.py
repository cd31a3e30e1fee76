"""MSP framing and message codecs: hand-computed vectors, round trips, hostile streams."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thrustmap.core.errors import ConfigError, ThrustmapError
from thrustmap.protocols.msp.framing import (
    MSP_MAX_REQUEST_PAYLOAD,
    MspChecksumError,
    MspCommand,
    MspDecoder,
    MspDirection,
    MspFrame,
    MspLengthError,
    MspPayloadError,
    MspProtocolError,
    MspVersion,
    crc8_dvb_s2,
    encode_error,
    encode_frame,
    encode_reply,
    encode_request,
)
from thrustmap.protocols.msp.messages import (
    REPLY_TYPES,
    REQUEST_TYPES,
    Analog,
    ApiVersion,
    ArmingDisable,
    BatteryConfig,
    BatteryState,
    BoardInfo,
    FcVariant,
    FcVersion,
    InavAnalog,
    SetArmingDisabled,
    Status,
    StatusEx,
    decode_reply,
    decode_request,
)
from thrustmap.protocols.msp.motor import (
    AdvancedConfig,
    EscTelemetry,
    Motor,
    MotorConfig,
    MotorProtocol,
    MotorTelemetry,
    SetMotor,
    external_to_fraction,
    external_to_native,
    native_to_external,
    throttle_scale_for,
)


def _chunks(data: bytes, cuts: list[int]) -> list[bytes]:
    bounds = sorted({0, len(data), *(c for c in cuts if c <= len(data))})
    return [data[a:b] for a, b in zip(bounds, bounds[1:], strict=False)]


def _crc8_bitwise(data: bytes) -> int:
    """An independent bit-by-bit crc8 DVB-S2 (poly 0xD5, init 0, MSB first)."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0xD5) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


# --------------------------------------------------------------------------- vectors


def test_v1_api_version_request_vector() -> None:
    assert encode_request(MspCommand.API_VERSION) == bytes.fromhex("24 4d 3c 00 01 01")


def test_v1_status_request_vector() -> None:
    assert encode_request(101) == bytes.fromhex("24 4d 3c 00 65 65")


def test_v1_set_motor_stop_vector() -> None:
    # size 16, cmd 0xd6, eight e8 03 pairs XOR to 0, so checksum = 0x10 ^ 0xd6 = 0xc6
    frame = encode_request(214, SetMotor.stop_all().encode())
    assert frame == bytes.fromhex("24 4d 3c 10 d6" + " e8 03" * 8 + " c6")


def test_v1_error_reply_vector() -> None:
    assert encode_error(214) == bytes.fromhex("24 4d 21 00 d6 d6")


def test_crc8_check_value() -> None:
    assert crc8_dvb_s2(b"123456789") == 0xBC  # the CRC catalogue check value for DVB-S2
    assert crc8_dvb_s2(b"\x00\x01\x00\x00\x00") == _crc8_bitwise(b"\x00\x01\x00\x00\x00")


def test_v2_request_vector() -> None:
    # $X< flag 0, cmd 0x2002, size 0, crc over 00 02 20 00 00
    body = bytes.fromhex("00 02 20 00 00")
    crc = _crc8_bitwise(body)
    assert encode_request(0x2002, version=MspVersion.V2) == b"$X<" + body + bytes((crc,))


def test_v2_over_v1_vector() -> None:
    inner = bytes.fromhex("00 6e 00 00 00")
    inner += bytes((_crc8_bitwise(inner),))
    outer_xor = 6 ^ 255
    for b in inner:
        outer_xor ^= b
    expected = b"$M<" + bytes((6, 255)) + inner + bytes((outer_xor,))
    assert encode_request(110, version=MspVersion.V2_OVER_V1) == expected


def test_jumbo_reply_layout_and_decode() -> None:
    payload = bytes(range(256)) * 2  # 512 bytes
    raw = encode_reply(116, payload)
    assert raw[:8] == b"$M>" + bytes((255, 116, 0x00, 0x02)) + payload[:1]
    frames = MspDecoder().feed(raw)
    assert frames == [MspFrame(MspVersion.V1, MspDirection.REPLY, 116, payload)]


def test_v1_rejects_cmd_over_254() -> None:
    with pytest.raises(ValueError):
        encode_request(0x2002, version=MspVersion.V1)


# --------------------------------------------------------------------------- decoder


def test_decoder_reports_checksum_error_and_keeps_next_frame() -> None:
    good = encode_reply(1, ApiVersion(0, 1, 46).encode())
    bad = bytearray(good)
    bad[-1] ^= 0xFF
    decoder = MspDecoder()
    events = decoder.feed_events(bytes(bad) + good)
    assert isinstance(events[0], MspChecksumError)
    assert events[0].cmd == 1
    assert isinstance(events[1], MspFrame)
    assert ApiVersion.decode(events[1].payload) == ApiVersion(0, 1, 46)
    assert decoder.error_count == 1


def test_feed_keeps_errors_aside() -> None:
    bad = bytearray(encode_reply(2, b"BTFL", MspVersion.V2))
    bad[8] ^= 0x01
    decoder = MspDecoder()
    frames = decoder.feed(bytes(bad) + encode_reply(2, b"INAV", MspVersion.V2))
    assert [FcVariant.decode(f.payload).identifier for f in frames] == ["INAV"]
    assert len(decoder.errors) == 1 and isinstance(decoder.errors[0], MspChecksumError)


def test_length_limit_is_reported_and_resyncs() -> None:
    decoder = MspDecoder(max_payload=MSP_MAX_REQUEST_PAYLOAD)
    big = encode_request(214, bytes(200), MspVersion.V2)
    events = decoder.feed_events(big + encode_request(1))
    assert isinstance(events[0], MspLengthError)
    assert isinstance(events[-1], MspFrame) and events[-1].cmd == 1


def test_v2_over_v1_inner_errors() -> None:
    inner = bytes.fromhex("00 6e 00 05 00")  # claims 5 payload bytes, carries none
    inner += bytes((_crc8_bitwise(inner),))
    raw = encode_frame(MspFrame(MspVersion.V1, MspDirection.REPLY, 0, b""))[:0]
    xor = 6 ^ 255
    for b in inner:
        xor ^= b
    raw = b"$M>" + bytes((6, 255)) + inner + bytes((xor,))
    (event,) = MspDecoder().feed_events(raw)
    assert isinstance(event, MspLengthError)


def test_garbage_and_cli_text_are_skipped() -> None:
    decoder = MspDecoder()
    stream = b"# CLI\r\n$$$M$X" + encode_reply(104, Motor((1500,) * 8).encode()) + b"\x00$Mzz"
    frames = decoder.feed(stream)
    assert [Motor.decode(f.payload).values for f in frames] == [(1500,) * 8]
    assert decoder.error_count == 0
    assert decoder.skipped_bytes >= len(b"# CLI\r\n$$$M$X")


def test_errors_are_thrustmap_errors() -> None:
    assert issubclass(MspProtocolError, ThrustmapError)
    assert issubclass(MspPayloadError, MspProtocolError)


_versions = st.sampled_from(list(MspVersion))
_dirs = st.sampled_from(list(MspDirection))


@st.composite
def frames(draw: st.DrawFn) -> MspFrame:
    version = draw(_versions)
    cmd = draw(st.integers(0, 254) if version is MspVersion.V1 else st.integers(0, 0xFFFF))
    flag = 0 if version is MspVersion.V1 else draw(st.integers(0, 255))
    return MspFrame(version, draw(_dirs), cmd, draw(st.binary(max_size=80)), flag)


@given(frames())
def test_frame_round_trip(frame: MspFrame) -> None:
    assert MspDecoder().feed(encode_frame(frame)) == [frame]


@settings(max_examples=20)
@given(st.binary(min_size=255, max_size=700), _versions)
def test_large_frames_round_trip(payload: bytes, version: MspVersion) -> None:
    frame = MspFrame(version, MspDirection.REPLY, 7, payload)
    assert MspDecoder().feed(encode_frame(frame)) == [frame]


@settings(max_examples=50)
@given(frames())
def test_frame_split_at_every_boundary(frame: MspFrame) -> None:
    raw = encode_frame(frame)
    for cut in range(len(raw) + 1):
        decoder = MspDecoder()
        assert decoder.feed(raw[:cut]) + decoder.feed(raw[cut:]) == [frame]


@given(st.binary(max_size=400), st.lists(st.integers(0, 400), max_size=12))
def test_random_bytes_only_yield_typed_events(data: bytes, cuts: list[int]) -> None:
    decoder = MspDecoder(max_payload=300)
    for chunk in _chunks(data, cuts):
        for event in decoder.feed_events(chunk):
            assert isinstance(event, (MspFrame, MspProtocolError))


@st.composite
def _mutated(draw: st.DrawFn) -> bytes:
    raw = bytearray(encode_frame(draw(frames())))
    for _ in range(draw(st.integers(0, 3))):
        raw[draw(st.integers(0, len(raw) - 1))] = draw(st.integers(0, 255))
    return bytes(raw[: draw(st.integers(0, len(raw)))])


_hostile_piece = st.one_of(
    st.sampled_from([b"$", b"$M", b"$X", b"<", b">", b"!", b"\xff", b"$M<\xff", b"$X>\x00"]),
    st.binary(max_size=6),
    _mutated(),
)


@given(st.lists(_hostile_piece, max_size=15), st.lists(st.integers(0, 300), max_size=8))
def test_hostile_streams_only_yield_typed_events(pieces: list[bytes], cuts: list[int]) -> None:
    data = b"".join(pieces)
    decoder = MspDecoder(max_payload=100)
    for chunk in _chunks(data, cuts):
        for event in decoder.feed_events(chunk):
            assert isinstance(event, (MspFrame, MspProtocolError))
    assert decoder.pending_bytes <= len(data)


@given(st.lists(frames(), min_size=1, max_size=4), st.lists(st.binary(max_size=20), max_size=5))
def test_garbage_between_frames(frame_list: list[MspFrame], garbage: list[bytes]) -> None:
    # garbage without '$' can never start a frame, so every frame must come through intact
    clean = [g.replace(b"$", b"") for g in garbage]
    clean += [b""] * (len(frame_list) + 1 - len(clean))
    stream = b"".join(clean[i] + encode_frame(f) for i, f in enumerate(frame_list))
    stream += b"".join(clean[len(frame_list) :])
    assert MspDecoder().feed(stream) == frame_list


@given(frames(), st.binary(max_size=30), st.data())
def test_chunked_stream_equals_whole(frame: MspFrame, junk: bytes, data: st.DataObject) -> None:
    stream = junk.replace(b"$", b"?") + encode_frame(frame) + encode_frame(frame)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=6)))
    decoder = MspDecoder()
    out: list[MspFrame] = []
    for chunk in _chunks(stream, cuts):
        out += decoder.feed(chunk)
    assert out == [frame, frame]


# --------------------------------------------------------------------------- messages

_u8 = st.integers(0, 255)
_u16 = st.integers(0, 0xFFFF)
_u32 = st.integers(0, 0xFFFFFFFF)
_i16 = st.integers(-0x8000, 0x7FFF)


def _c(raw: int, res: float) -> float:
    return raw * res


_messages = st.one_of(
    st.builds(ApiVersion, _u8, _u8, _u8),
    st.builds(FcVariant, st.sampled_from(["BTFL", "INAV", "EMUF"])),
    st.builds(FcVersion, _u8, _u8, _u8, st.none() | st.text("0123456789.-RC", max_size=20)),
    st.builds(BoardInfo, st.sampled_from(["S405", "MTKS"]), _u16, st.binary(max_size=20)),
    st.builds(
        Status,
        cycle_time_us=_u16,
        mode_flags=_u32,
        cpu_load=_u16,
        profile_word=_u16,
        extra_mode_flags=st.binary(max_size=15),
        arming_disable_count=_u8,
        arming_disable_flags=st.none() | _u32,
        tail=st.binary(max_size=5),
    ).map(
        lambda s: (
            s
            if s.arming_disable_flags is not None
            else Status(cycle_time_us=s.cycle_time_us, mode_flags=s.mode_flags, cpu_load=s.cpu_load)
        )
    ),
    st.builds(StatusEx, mode_flags=_u32, arming_disable_count=_u8, arming_disable_flags=_u32),
    st.builds(SetArmingDisabled, st.booleans(), st.none() | st.booleans()),
    st.builds(Motor, st.lists(_u16, min_size=8, max_size=8).map(tuple)),
    st.builds(SetMotor, st.lists(_u16, min_size=1, max_size=8).map(tuple)),
    st.builds(MotorConfig, _u16, _u16, _u16, _u8, _u8, st.booleans(), st.booleans()),
    st.builds(
        MotorTelemetry,
        st.lists(
            st.builds(
                EscTelemetry,
                _u32.map(float),
                _u16.map(lambda r: r / 100),
                _u8.map(float),
                _u16.map(lambda r: r / 100),
                _u16.map(lambda r: r / 100),
                _u16,
            ),
            max_size=8,
        ).map(tuple),
    ),
    st.builds(AdvancedConfig, st.integers(0, 10), _u16, _u16.map(lambda r: r / 100), _u8),
    st.builds(
        Analog,
        _u16.map(lambda r: r / 100),
        _i16.map(lambda r: r / 100),
        _u16,
        _u16,
        _u8.map(lambda r: r / 10),
    ),
    st.builds(
        BatteryState,
        _u8,
        _u16,
        _u16.map(lambda r: r / 100),
        _i16.map(lambda r: r / 100),
        _u16,
        _u8,
        _u8.map(lambda r: r / 10),
    ),
    st.builds(
        BatteryConfig,
        st.integers(0, 2550).map(lambda r: r / 100),
        st.integers(0, 2550).map(lambda r: r / 100),
        st.integers(0, 2550).map(lambda r: r / 100),
        _u16,
    ),
    st.builds(
        InavAnalog,
        _u16.map(lambda r: r / 100),
        _u16.map(lambda r: r / 100),
        _u32.map(lambda r: r / 100),
        _u32,
        _u32,
        _u32,
        _u8,
        _u16,
        _u8,
    ),
)


@given(_messages, _versions)
def test_every_message_round_trips_through_frames(message: object, version: MspVersion) -> None:
    cmd = message.CMD  # type: ignore[attr-defined]
    if version is MspVersion.V1 and cmd > 254:
        version = MspVersion.V2
    payload = message.encode()  # type: ignore[attr-defined]
    if isinstance(message, (SetMotor, SetArmingDisabled)):
        (frame,) = MspDecoder().feed(encode_request(cmd, payload, version))
        assert decode_request(frame) == message
    else:
        (frame,) = MspDecoder().feed(encode_reply(cmd, payload, version))
        assert decode_reply(frame) == message
    assert type(message).decode(payload).encode() == payload  # type: ignore[attr-defined]


def test_registry_covers_every_command() -> None:
    known = set(REPLY_TYPES) | set(REQUEST_TYPES)
    assert known == {c for c in MspCommand if c != MspCommand.REBOOT}


def test_battery_state_reads_every_byte() -> None:
    # 4S, 1500 mAh, vbat 16.8 V (168), 321 mAh, 12.34 A, OK, 16.81 V
    payload = bytes((4,)) + struct.pack("<H", 1500) + bytes((168,))
    payload += struct.pack("<Hh", 321, 1234) + bytes((0,)) + struct.pack("<H", 1681)
    state = BatteryState.decode(payload)
    assert state.cell_count == 4 and state.capacity_mah == 1500
    assert state.voltage_coarse_v == pytest.approx(16.8)
    assert state.consumed_mah == 321
    assert state.current_a == pytest.approx(12.34)
    assert state.voltage_v == pytest.approx(16.81)


def test_analog_values() -> None:
    payload = bytes((162,)) + struct.pack("<HHhH", 55, 1023, -150, 1623)
    a = Analog.decode(payload)
    assert (a.voltage_v, a.current_a, a.consumed_mah, a.rssi) == (16.23, -1.5, 55, 1023)
    legacy = Analog.decode(payload[:7])
    assert legacy.voltage_v == pytest.approx(16.2)


def test_fc_version_formats() -> None:
    old = FcVersion.decode(bytes((4, 5, 1)))
    assert str(old) == "4.5.1" and not old.is_year_based
    new = FcVersion.decode(bytes((25, 12, 0, 9)) + b"2025.12.0")
    assert new.is_year_based and str(new) == "2025.12.0" and new.major == 25
    assert str(FcVersion(25, 12, 2)) == "2025.12.2"


def test_status_ex_arming_flags() -> None:
    head = struct.pack("<HHHIBH", 125, 0, 0x23, 0b1, 0, 12) + bytes((3, 0))
    payload = head + bytes((0,)) + struct.pack("<BI", 26, int(ArmingDisable.MSP)) + b"\x00"
    s = StatusEx.decode(payload)
    assert s.armed and s.arming_disabled_by_msp and s.cycle_time_us == 125
    assert Status.decode(head).arming_disable_flags is None
    with pytest.raises(MspPayloadError):
        Status.decode(head + b"\x01")


def test_motor_telemetry_values() -> None:
    entry = struct.pack("<IHBHHH", 23456, 150, 41, 1598, 1234, 77)
    t = MotorTelemetry.decode(bytes((1,)) + entry)
    (m,) = t.motors
    assert (m.rpm, m.invalid_pct, m.temperature_c) == (23456.0, 1.5, 41.0)
    assert (m.voltage_v, m.current_a, m.consumed_mah) == (15.98, 12.34, 77)
    with pytest.raises(MspPayloadError):
        MotorTelemetry.decode(bytes((2,)) + entry)


def test_advanced_config_protocol() -> None:
    cfg = AdvancedConfig.decode(struct.pack("<BBBBHH", 1, 1, 0, 7, 480, 550) + b"\x00\x01")
    assert cfg.protocol is MotorProtocol.DSHOT600
    assert cfg.digital_idle_pct == pytest.approx(5.5)
    assert AdvancedConfig(42).protocol is None


def test_decode_reply_refuses_error_frames() -> None:
    (frame,) = MspDecoder().feed(encode_error(214))
    assert frame.is_error
    with pytest.raises(MspPayloadError):
        decode_reply(frame)


def test_set_motor_helpers() -> None:
    assert SetMotor.for_motors({0: 1200, 3: 1300}).values == (1200, 1000, 1000, 1300) + (1000,) * 4
    assert len(SetMotor.stop_all().encode()) == 16
    with pytest.raises(ConfigError):
        SetMotor.for_motors({8: 1100})


# --------------------------------------------------------------------------- throttle scales


@pytest.mark.parametrize(
    ("protocol", "lo", "hi"),
    [
        (MotorProtocol.PWM, 1000, 2000),
        (MotorProtocol.ONESHOT125, 125, 250),
        (MotorProtocol.ONESHOT42, 42, 84),
        (MotorProtocol.MULTISHOT, 5, 25),
        (MotorProtocol.DSHOT600, 48, 2047),
        (MotorProtocol.PROSHOT1000, 48, 2047),
    ],
)
def test_throttle_scales(protocol: MotorProtocol, lo: float, hi: float) -> None:
    s = throttle_scale_for(protocol)
    assert (s.lo, s.hi) == (lo, hi)
    if not protocol.is_digital:
        assert external_to_native(1000, protocol) == pytest.approx(lo)
        assert external_to_native(1500, protocol) == pytest.approx((lo + hi) / 2)


def test_dshot_external_mapping() -> None:
    p = MotorProtocol.DSHOT300
    assert external_to_native(1000, p) == 0.0
    assert external_to_native(1001, p) == pytest.approx(48)
    assert external_to_native(2000, p) == pytest.approx(2047)
    assert external_to_native(2500, p) == pytest.approx(2047)  # clamped as the FC does
    assert native_to_external(external_to_native(1534, p), p) == pytest.approx(1534)
    assert external_to_fraction(1000, p) == 0.0
    assert external_to_fraction(2000, p) == 1.0
    assert external_to_fraction(1500, MotorProtocol.PWM) == 0.5


def test_scale_for_disabled_protocol_is_config_error() -> None:
    with pytest.raises(ConfigError):
        throttle_scale_for(MotorProtocol.DISABLED)
