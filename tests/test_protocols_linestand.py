"""Configurable line stands: decoding, commands, presets, hostile input."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.generic_stand import GENERIC_3COL as STM32_HX711

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.protocols.stands.line import (
    PRESETS,
    REFERENCE,
    RP2040_WHOOP,
    Column,
    LineComment,
    LineError,
    LineHeader,
    LineSample,
    LineStandDecoder,
    LineStandSpec,
)
from thrustmap.protocols.stands.line_presets import preset

REF_STREAM = (
    b"# thrustmap-line demo v1\r\n"
    b"#COLS t_us,throttle_us,thrust_mN,torque_mNm,voltage_mV,current_mA,rpm\r\n"
    b"1000000,1500,4021,-52,16012,8340,21050\r\n"
    b"1004000,1500,4030,-53,16010,8342,21070\r\n"
)


def test_reference_stream_values() -> None:
    decoder = LineStandDecoder(REFERENCE)
    events = decoder.feed_events(REF_STREAM)
    assert events[0] == LineComment(1, "thrustmap-line demo v1")
    assert isinstance(events[1], LineHeader) and events[1].names[2] == "thrust_mN"
    sample = events[2]
    assert isinstance(sample, LineSample) and sample.line_no == 3
    assert sample.time_s == pytest.approx(1.0)
    assert sample.throttle == 1500.0
    assert sample.thrust_n == pytest.approx(4.021)
    assert sample.torque_nm == pytest.approx(-0.052)
    assert sample.voltage_v == pytest.approx(16.012)
    assert sample.current_a == pytest.approx(8.34)
    assert sample.rpm == 21050.0
    assert decoder.error_count == 0


def test_header_reordering_is_followed() -> None:
    decoder = LineStandDecoder(REFERENCE)
    stream = b"#COLS rpm,thrust_mN,t_us,throttle_us,voltage_mV,current_mA,torque_mNm,extra\n"
    stream += b"9000,1500,20,1100,12000,500,7,99\n"
    (sample,) = decoder.feed(stream)
    assert (sample.rpm, sample.thrust_n) == (9000.0, 1.5)
    assert sample.time_s == pytest.approx(2e-5)


@pytest.mark.parametrize("cut", range(len(REF_STREAM) + 1))
def test_any_split_decodes_identically(cut: int) -> None:
    whole = LineStandDecoder(REFERENCE).feed(REF_STREAM)
    d = LineStandDecoder(REFERENCE)
    assert d.feed(REF_STREAM[:cut]) + d.feed(REF_STREAM[cut:]) == whole


def test_cr_lf_and_crlf_line_ends() -> None:
    body = REF_STREAM.replace(b"\r\n", b"\n")
    for ending in (b"\n", b"\r", b"\r\n"):
        samples = LineStandDecoder(REFERENCE).feed(body.replace(b"\n", ending))
        assert [s.line_no for s in samples] == [3, 4]


def test_bad_lines_report_line_number_and_reason() -> None:
    decoder = LineStandDecoder(REFERENCE)
    events = decoder.feed_events(
        b"1,2,3\n"  # before the header
        + REF_STREAM.split(b"\r\n", 2)[1]
        + b"\n1000,1500\n1000,1500,abc,0,0,0,0\n1000,1500,nan,0,0,0,0\n"
        + b"\xff\xfe\n"
    )
    errors = [e for e in events if isinstance(e, LineError)]
    assert [e.line for e in errors] == [1, 3, 4, 5, 6]
    assert "header" in errors[0].message
    assert "at least" in errors[1].message
    assert errors[2].column == "thrust_mN" and "'abc'" in errors[2].message
    assert isinstance(errors[0], DataFormatError)
    assert str(errors[2]).startswith("line 4: column 'thrust_mN'")


def test_header_missing_a_named_column() -> None:
    (event,) = [
        e
        for e in LineStandDecoder(REFERENCE).feed_events(b"#COLS t_us,throttle_us\n")
        if isinstance(e, LineError)
    ]
    assert "thrust_mN" in event.message


def test_overlong_line_is_an_error_not_a_crash() -> None:
    decoder = LineStandDecoder(STM32_HX711)
    events = decoder.feed_events(b"1" * 10000 + b"\n10,1500,123\n")
    assert isinstance(events[0], LineError) and "longer" in events[0].message
    assert isinstance(events[1], LineSample) and events[1].thrust_n == 123.0


def test_stm32_preset_by_index_and_calibration() -> None:
    spec = STM32_HX711.with_load_cell("thrust_n", tare=8000.0, si_per_count=0.002)
    (s,) = LineStandDecoder(spec).feed(b"2500, 1432, 9000\n")
    assert s.time_s == pytest.approx(2.5) and s.throttle == 1432.0
    assert s.thrust_n == pytest.approx(2.0)
    assert spec.command_for(1432) == b"1432\n"
    assert spec.stop_bytes() == b"1000\n"
    assert spec.keepalive_bytes() is None
    assert spec.parse_command("1700") == pytest.approx(70.0)


def test_rp2040_preset() -> None:
    stream = (
        b"# whoop stand fw 1.2\n#COLS t_us,phase,throttle_pct,dshot,rpm,thrust_raw,bus_mv,bus_ua\n"
    )
    stream += b"4000, 2, 35.5, 757, 28000, 51234, 4105, 2300000\n"
    (s,) = LineStandDecoder(RP2040_WHOOP).feed(stream)
    assert s.throttle == 35.5 and s.rpm == 28000.0 and s.thrust_n == 51234.0
    assert s.voltage_v == pytest.approx(4.105) and s.current_a == pytest.approx(2.3)
    assert RP2040_WHOOP.command_for(35.5) == b"HOLD,35.5,0,0\n"
    assert RP2040_WHOOP.parse_command("HOLD,35.5,0,0\r\n") == pytest.approx(35.5)
    assert RP2040_WHOOP.parse_command("STOP") == 0.0
    assert RP2040_WHOOP.parse_command("PING") is None


def test_reference_commands() -> None:
    assert REFERENCE.command_for(1500) == b"THR 1500\n"
    assert REFERENCE.command_for(2500) == b"THR 2000\n"  # clamped to the scale
    assert REFERENCE.stop_bytes() == b"STOP\n"
    assert REFERENCE.keepalive_bytes() == b"PING\n"
    assert REFERENCE.parse_command("THR 1234") == pytest.approx(23.4)
    assert REFERENCE.parse_command("THR abc") is None


def test_other_templates() -> None:
    spec = LineStandSpec(
        "arduino-2hx711",
        columns={"thrust_n": Column(index=0, scale=0.00980665)},
        header_prefix=None,
        throttle_scale="percent",
        throttle_command="thr({pct:.0f})",
    )
    assert spec.command_for(42.4) == b"thr(42)"
    assert spec.stop_bytes() == b"thr(0)"
    assert spec.parse_command("thr(42)") == 42.0


def test_sample_lines_round_trip_through_the_spec() -> None:
    values = {"time_s": 1.5, "throttle": 1600.0, "thrust_n": 3.25, "voltage_v": 15.9}
    line = REFERENCE.format_sample(values)
    header = REFERENCE.header_line()
    assert header is not None
    (s,) = LineStandDecoder(REFERENCE).feed(f"{header}\n{line}\n".encode())
    assert (s.time_s, s.throttle, s.thrust_n, s.voltage_v) == pytest.approx(
        (1.5, 1600.0, 3.25, 15.9)
    )


def test_spec_validation() -> None:
    with pytest.raises(ConfigError, match="thrust_n"):
        LineStandSpec("x", columns={"rpm": Column(index=0)})
    with pytest.raises(ConfigError, match="unknown fields"):
        LineStandSpec("x", columns={"thrust_n": Column(index=0), "pressure": Column(index=1)})
    with pytest.raises(ConfigError, match="exactly one"):
        LineStandSpec("x", columns={"thrust_n": Column()})
    with pytest.raises(ConfigError, match="no header"):
        LineStandSpec("x", columns={"thrust_n": Column(name="f")}, header_prefix=None)
    with pytest.raises(ConfigError, match="template"):
        LineStandSpec("x", columns={"thrust_n": Column(index=0)}, throttle_command="{speed}")
    with pytest.raises(ConfigError, match="no throttle command"):
        STM32_HX711.__class__("y", columns={"thrust_n": Column(index=0)}).command_for(1500)
    with pytest.raises(ConfigError, match="expected one of"):
        preset("teensy")
    assert preset("THRUSTMAP-LINE") is REFERENCE and set(PRESETS) >= {"generic-hold-csv"}


_pieces = st.one_of(
    st.sampled_from(
        [b"\n", b"\r", b"\r\n", b"#", b"#COLS ", b"t_us,thrust_mN", b",", b"1.5", b"nan", b"-"]
    ),
    st.binary(max_size=12),
    st.text(max_size=12).map(str.encode),
)


@settings(max_examples=200)
@given(st.lists(_pieces, max_size=25), st.lists(st.integers(0, 300), max_size=6))
def test_random_input_never_raises(pieces: list[bytes], cuts: list[int]) -> None:
    data = b"".join(pieces)
    bounds = sorted({0, len(data), *(c for c in cuts if c <= len(data))})
    for spec in PRESETS.values():
        decoder = LineStandDecoder(spec)
        for a, b in zip(bounds, bounds[1:], strict=False):
            for event in decoder.feed_events(data[a:b]):
                assert isinstance(event, (LineSample, LineComment, LineHeader, LineError))
                if isinstance(event, LineError):
                    assert event.line is not None and event.line >= 1
