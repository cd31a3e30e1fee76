"""Tyto Series 1585 codec: vectors, round trips, hostile streams, calibration files."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thrustmap.protocols.stands.tyto import (
    TYTO_POLL_CODE,
    LoadCell,
    TytoCalibration,
    TytoCalibrationError,
    TytoChecksumError,
    TytoDecoder,
    TytoFrame,
    TytoPayloadError,
    TytoPoll,
    TytoProtocolError,
    TytoReading,
    TytoReady,
)

CAL = TytoCalibration(
    thrust=LoadCell(tare=1000.0, n_per_count=-0.001),
    torque_left=LoadCell(tare=50.0, n_per_count=0.0005),
    torque_right=LoadCell(tare=-20.0, n_per_count=0.0004),
    arm_length_m=0.04,
    electrical_rpm_factor=1.0 / 7.0,
    vibration_g_per_count=0.01,
)


def reading(**overrides: float) -> TytoReading:
    base: dict[str, float] = dict(
        esc_voltage=16.0,
        esc_current=10.0,
        esc_power=160.0,
        load_thrust=1000.0,
        load_left=50.0,
        rot_e=70000.0,
        rot_o=0.0,
        temp0=25.0,
        temp1=26.0,
        temp2=27.0,
        basic_data_flag=1,
        acc_x=0,
        acc_y=0,
        acc_z=2048,
        vibration=15,
        raw_pressure_p=0,
        raw_pressure_t=0,
        load_right=-20.0,
        pro_data_flag=1,
    )
    base.update(overrides)
    return TytoReading(**base)  # type: ignore[arg-type]


def test_poll_vector() -> None:
    # len 8, code 3, payload dc 05 00.., xor = 08 ^ 03 ^ dc ^ 05 = d2
    assert TytoPoll(1500).frame() == bytes.fromhex("24 52 3c 08 03 dc 05 00 00 00 00 00 00 d2")


def test_reply_struct_size_and_order() -> None:
    r = reading(esc_voltage=12.5, load_right=-3.25, pro_data_flag=0x41)
    payload = r.encode()
    assert len(payload) == 58
    assert struct.unpack_from("<f", payload, 0)[0] == 12.5  # esc_voltage first
    assert struct.unpack_from("<f", payload, 53)[0] == -3.25  # load_right after the shorts
    assert payload[-1] == 0x41
    assert TytoReading.decode(payload) == r


def test_decoder_ready_banner_then_reply() -> None:
    decoder = TytoDecoder()
    stream = b"\x00garbage\r\nRe" + b"ady\r\n" + reading().frame()
    events = decoder.feed_events(stream[:5]) + decoder.feed_events(stream[5:])
    assert isinstance(events[0], TytoReady) and decoder.ready_seen
    assert isinstance(events[1], TytoFrame) and events[1].code == TYTO_POLL_CODE
    assert TytoReading.decode(events[1].payload) == reading()


def test_checksum_error_is_reported_and_next_frame_kept() -> None:
    bad = bytearray(reading().frame())
    bad[-1] ^= 1
    decoder = TytoDecoder()
    events = decoder.feed_events(bytes(bad) + reading(temp0=30.0).frame())
    assert isinstance(events[0], TytoChecksumError)
    assert isinstance(events[1], TytoFrame)
    assert TytoReading.decode(events[1].payload).temp0 == 30.0


def test_wrong_payload_size() -> None:
    with pytest.raises(TytoPayloadError):
        TytoReading.decode(b"\x00" * 57)
    with pytest.raises(TytoPayloadError):
        TytoPoll.decode(b"\x00" * 6)


def test_request_direction_decoder_ignores_replies() -> None:
    decoder = TytoDecoder("<")
    frames = decoder.feed(reading().frame() + TytoPoll(1200).frame())
    assert [TytoPoll.decode(f.payload) for f in frames] == [TytoPoll(1200)]


_f32 = st.floats(width=32, allow_nan=False)
_i16 = st.integers(-0x8000, 0x7FFF)
_readings = st.builds(
    TytoReading,
    _f32,
    _f32,
    _f32,
    _f32,
    _f32,
    _f32,
    _f32,
    _f32,
    _f32,
    _f32,
    st.integers(0, 255),
    _i16,
    _i16,
    _i16,
    _i16,
    _i16,
    _i16,
    _f32,
    st.integers(0, 255),
)


@given(_readings)
def test_reading_round_trip(r: TytoReading) -> None:
    (frame,) = TytoDecoder().feed(r.frame())
    assert TytoReading.decode(frame.payload) == r


@given(st.integers(0, 0xFFFF), st.integers(0, 0xFFFF))
def test_poll_round_trip(esc_us: int, servo_us: int) -> None:
    poll = TytoPoll(esc_us, servo_us)
    (frame,) = TytoDecoder("<").feed(poll.frame())
    assert TytoPoll.decode(frame.payload) == poll


@settings(max_examples=40)
@given(_readings)
def test_split_at_every_boundary(r: TytoReading) -> None:
    raw = r.frame()
    for cut in range(len(raw) + 1):
        decoder = TytoDecoder()
        frames = decoder.feed(raw[:cut]) + decoder.feed(raw[cut:])
        assert [TytoReading.decode(f.payload) for f in frames] == [r]


_pieces = st.one_of(
    st.sampled_from([b"$", b"$R", b"$R>", b"$R>\xff", b"Ready\r\n", b"\n", b"$R<"]),
    st.binary(max_size=8),
    _readings.map(lambda r: r.frame()[: len(r.frame()) // 2]),
)


@settings(max_examples=40)
@given(st.lists(_pieces, max_size=12), st.lists(st.integers(0, 200), max_size=6))
def test_hostile_stream_only_typed_events(pieces: list[bytes], cuts: list[int]) -> None:
    data = b"".join(pieces)
    bounds = sorted({0, len(data), *(c for c in cuts if c <= len(data))})
    decoder = TytoDecoder()
    for a, b in zip(bounds, bounds[1:], strict=False):
        for event in decoder.feed_events(data[a:b]):
            assert isinstance(event, (TytoFrame, TytoReady, TytoProtocolError))


@settings(max_examples=40)
@given(st.lists(_readings, min_size=1, max_size=3), st.binary(max_size=30))
def test_garbage_between_frames_is_skipped(rs: list[TytoReading], junk: bytes) -> None:
    junk = junk.replace(b"$", b"")
    stream = b"".join(junk + r.frame() for r in rs) + junk
    assert [TytoReading.decode(f.payload) for f in TytoDecoder().feed(stream)] == rs


# --------------------------------------------------------------------------- calibration


def test_to_si_values() -> None:
    m = CAL.to_si(reading(load_thrust=-1000.0, load_left=250.0, load_right=-520.0))
    assert m.thrust_n == pytest.approx(2.0)  # (-1000 - 1000) * -0.001
    # F_left = 200 * 0.0005 = 0.1 N; F_right = -500 * 0.0004 = -0.2 N; 0.04 * 0.3
    assert m.torque_nm == pytest.approx(0.012)
    assert m.rpm_electrical == pytest.approx(10000.0)
    assert m.vibration_g == pytest.approx(0.15)
    assert (m.voltage_v, m.current_a, m.power_w) == (16.0, 10.0, 160.0)
    assert m.temperatures_c == (25.0, 26.0, 27.0)


@given(st.floats(-50, 50), st.floats(-2, 2))
def test_inverse_calibration(thrust_n: float, torque_nm: float) -> None:
    t, left, right = CAL.raw_counts(thrust_n, torque_nm)
    m = CAL.to_si(reading(load_thrust=t, load_left=left, load_right=right))
    assert m.thrust_n == pytest.approx(thrust_n, abs=1e-9)
    assert m.torque_nm == pytest.approx(torque_nm, abs=1e-9)


def test_tare_and_two_point() -> None:
    tared = CAL.tared(reading(load_thrust=1234.0, load_left=1.0, load_right=2.0))
    zero = tared.to_si(reading(load_thrust=1234.0, load_left=1.0, load_right=2.0))
    assert zero.thrust_n == 0.0 and zero.torque_nm == 0.0
    cell = LoadCell.from_two_points(100.0, -900.0, 9.80665)  # 1 kg pulls the count down
    assert cell.force_n(-900.0) == pytest.approx(9.80665)
    with pytest.raises(TytoCalibrationError):
        LoadCell.from_two_points(5.0, 5.0, 1.0)
