"""The line-stand driver: samples, timestamps, tare, keep-alive, bad lines, ESC output, JSON specs."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest
from support.generic_stand import GENERIC_3COL as STM32_HX711

from thrustmap.core.clock import SimClock
from thrustmap.core.errors import ConfigError, SafetyError
from thrustmap.protocols.stands.line import REFERENCE, Column, LineStandSpec
from thrustmap.protocols.stands.line_presets import preset
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.sim.plant import ConstantPlant
from thrustmap.rig.sim.stand_peers import LineStandPeer
from thrustmap.rig.stand.line import LineStand, LineStandError, LineStandEscOutput, LineStandTimeout
from thrustmap.rig.stand.line_spec import line_spec_from_dict, line_spec_to_dict, load_line_spec

HEADER = b"#COLS t_us,throttle_us,thrust_mN,torque_mNm,voltage_mV,current_mA,rpm\n"


class ScriptPeer:
    """Sends scripted bytes at scripted times and records what the host writes."""

    def __init__(self, script: list[tuple[float, bytes]]) -> None:
        self.script = sorted(script, key=lambda item: item[0])
        self.written: list[tuple[float, bytes]] = []

    def write(self, data: bytes, now_s: float) -> None:
        self.written.append((now_s, data))

    def read(self, now_s: float) -> bytes:
        out = b"".join(data for t, data in self.script if t <= now_s)
        self.script = [(t, d) for t, d in self.script if t > now_s]
        return out

    def lines_written(self) -> list[bytes]:
        return b"".join(d for _, d in self.written).splitlines()


class SpyPeer:
    """A simulated line stand that also records the host's writes."""

    def __init__(self, inner: LineStandPeer) -> None:
        self.inner = inner
        self.written: list[tuple[float, bytes]] = []

    def write(self, data: bytes, now_s: float) -> None:
        self.written.append((now_s, data))
        self.inner.write(data, now_s)

    def read(self, now_s: float) -> bytes:
        return self.inner.read(now_s)


def sim_stand(
    spec: LineStandSpec = REFERENCE, rate_hz: float = 100.0
) -> tuple[LineStand, SpyPeer, SimClock, ConstantPlant]:
    clock = SimClock()
    plant = ConstantPlant(1, voltage_v=16.0, max_thrust_n=10.0)
    peer = SpyPeer(LineStandPeer(plant, spec, rate_hz=rate_hz))
    return LineStand(SimSerial(peer, clock), clock, spec), peer, clock, plant


# --------------------------------------------------------------------------- samples


def test_samples_carry_the_plant_values_in_si() -> None:
    stand, peer, clock, _ = sim_stand()
    out = LineStandEscOutput(stand)
    stand.read_samples()
    out.set_throttle({0: 1500.0})  # 50 %: thrust 10 * 0.5² = 2.5 N, 15000 rpm
    clock.advance_s(0.2)
    samples = stand.read_samples()
    last = samples[-1]
    assert last.thrust_n == pytest.approx(2.5, abs=1e-3)  # mN integers on the wire
    assert last.rpm == pytest.approx(15000.0)
    assert last.voltage_v == pytest.approx(16.0 - 0.01 * 30 * 0.125, abs=1e-3)
    assert last.current_a == pytest.approx(30 * 0.125, abs=1e-3)
    assert last.torque_nm == pytest.approx(0.012 * 2.5, abs=1e-3)
    assert last.throttle_native == pytest.approx(1500.0)  # the stand drives the ESC
    assert stand.error_count == 0
    assert stand.identify().details["columns"].startswith("t_us,throttle_us")


def test_throttle_native_only_when_the_stand_drives_the_esc() -> None:
    stand, _, clock, _ = sim_stand()
    clock.advance_s(0.05)
    assert all(s.throttle_native is None for s in stand.read_samples())


def test_timestamps_keep_the_stands_spacing_and_end_now() -> None:
    stand, _, clock, _ = sim_stand(rate_hz=100.0)
    clock.advance_s(1.0)
    stand.read_samples()
    clock.advance_s(0.1)
    samples = stand.read_samples()
    assert len(samples) == 10
    times = [s.time_s for s in samples]
    assert times[-1] == pytest.approx(clock.now_s())
    assert [b - a for a, b in zip(times, times[1:], strict=False)] == pytest.approx([0.01] * 9)
    clock.advance_s(0.05)
    later = stand.read_samples()
    assert later[0].time_s > times[-1]


def test_without_device_time_a_burst_is_stamped_now() -> None:
    spec = LineStandSpec("no-time", {"thrust_n": Column(index=0, scale=1e-3)}, header_prefix=None)
    clock = SimClock()
    peer = ScriptPeer([(0.1, b"100\n200\n300\n")])
    stand = LineStand(SimSerial(peer, clock), clock, spec)
    clock.advance_s(0.2)
    samples = stand.read_samples()
    assert [s.thrust_n for s in samples] == pytest.approx([0.1, 0.2, 0.3])
    assert [s.time_s for s in samples] == [0.2, 0.2, 0.2]


def test_device_clock_reset_falls_back_to_now() -> None:
    clock = SimClock()
    peer = ScriptPeer([(0.1, HEADER + b"900000,1000,1,0,0,0,0\n5000,1000,2,0,0,0,0\n")])
    stand = LineStand(SimSerial(peer, clock), clock, REFERENCE)
    clock.advance_s(0.3)
    samples = stand.read_samples()
    assert [s.time_s for s in samples] == [0.3, 0.3]


def test_reads_data_before_the_header_with_the_documented_order() -> None:
    clock = SimClock()
    peer = ScriptPeer(
        [
            (0.0, b"1000,1500,2500,0,16000,1000,9000\n"),  # connected mid-stream
            (0.1, b"#COLS thrust_mN,t_us,voltage_mV\n7000,2000,15000\n"),  # reordered
        ]
    )
    stand = LineStand(SimSerial(peer, clock), clock, REFERENCE)
    first = stand.read_samples()
    assert [(s.thrust_n, s.voltage_v, s.rpm) for s in first] == [(2.5, 16.0, 9000.0)]
    clock.advance_s(0.1)
    # the new header lacks columns the preset names: the stand reports them as bad lines
    assert stand.read_samples() == []
    assert stand.error_count == 2
    assert stand.header_seen == ("thrust_mN", "t_us", "voltage_mV")


def test_bad_lines_are_counted_and_logged_with_line_numbers(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = SimClock()
    peer = ScriptPeer(
        [
            (
                0.0,
                HEADER
                + b"1,1000,100,0,0,0,0\n"
                + b"garbage\n"
                + b"3,1000,abc,0,0,0,0\n"
                + b"\xff\xfe\x00\n"
                + b"x" * 5000
                + b"\n"
                + b"# calibration 2026-01-01\n"
                + b"6,1000,600,0,0,0,0\n",
            )
        ]
    )
    stand = LineStand(SimSerial(peer, clock), clock, REFERENCE)
    with caplog.at_level(logging.WARNING, logger="thrustmap.rig.stand.line"):
        samples = stand.read_samples()
    assert [s.thrust_n for s in samples] == pytest.approx([0.1, 0.6])
    assert stand.error_count == 4
    text = caplog.text
    assert "line 3:" in text and "line 4:" in text and "line 5:" in text and "line 6:" in text
    assert "'abc' is not a finite number" in text
    assert stand.banner == ["calibration 2026-01-01"]


def test_error_logging_is_capped(caplog: pytest.LogCaptureFixture) -> None:
    clock = SimClock()
    peer = ScriptPeer([(0.0, HEADER + b"bad\n" * 250)])
    stand = LineStand(SimSerial(peer, clock), clock, REFERENCE, max_logged_errors=5)
    with caplog.at_level(logging.WARNING, logger="thrustmap.rig.stand.line"):
        assert stand.read_samples() == []
    assert stand.error_count == 250
    # 5 in full, one "no longer logged" note, then one summary per 100
    assert len(caplog.records) == 5 + 1 + 2


def test_watchdog_and_err_comments_are_counted() -> None:
    clock = SimClock()
    peer = ScriptPeer([(0.0, HEADER + b"#WATCHDOG\n#ERR FOO\n#ERR BAR\n")])
    stand = LineStand(SimSerial(peer, clock), clock, REFERENCE)
    stand.read_samples()
    assert (stand.watchdog_trips, stand.command_errors) == (1, 2)


# --------------------------------------------------------------------------- tare


def test_tare_zeroes_the_thrust_offset() -> None:
    clock = SimClock()
    lines = b"".join(f"{i},1000,{200 + (i % 3) - 1},0,0,0,0\n".encode() for i in range(60))
    later = b"99,1000,1200,0,0,0,0\n"
    peer = ScriptPeer([(0.0, HEADER + lines), (1.0, later)])
    stand = LineStand(SimSerial(peer, clock), clock, REFERENCE)
    stand.tare(samples=50)
    assert stand.tare_offset_n == pytest.approx(0.2, abs=1e-3)
    clock.advance_s(1.0)
    (sample,) = stand.read_samples()[-1:]
    assert sample.thrust_n == pytest.approx(1.0, abs=1e-3)


def test_tare_refuses_a_turning_rotor() -> None:
    stand, _, clock, plant = sim_stand()
    plant.set_throttle(0, 0.3, 0.0)
    with pytest.raises(LineStandError, match="rotor is turning"):
        stand.tare(samples=20)
    assert stand.tare_offset_n == 0.0


def test_tare_on_a_silent_stand_times_out() -> None:
    clock = SimClock()
    stand = LineStand(SimSerial(ScriptPeer([]), clock), clock, REFERENCE)
    with pytest.raises(LineStandTimeout, match="wrong port or baud rate"):
        stand.tare(timeout_s=0.5)
    assert clock.now_s() == pytest.approx(0.5, abs=0.01)


def test_wait_for_data_names_a_wrong_preset() -> None:
    clock = SimClock()
    peer = ScriptPeer([(0.0, b"1;2;3\n" * 10)])
    stand = LineStand(SimSerial(peer, clock), clock, STM32_HX711)
    with pytest.raises(LineStandTimeout, match="10 lines could not be read.*wrong preset"):
        stand.wait_for_data(0.2)


# --------------------------------------------------------------------------- keep-alive


def test_keepalive_is_sent_at_its_interval_and_feeds_the_watchdog() -> None:
    stand, peer, clock, _ = sim_stand()
    out = LineStandEscOutput(stand)
    out.set_throttle({0: 1300.0})
    for _ in range(80):  # 2 s, read every 25 ms
        clock.advance_s(0.025)
        stand.read_samples()
    pings = [t for t, data in peer.written if data == b"PING\n"]
    assert 7 <= len(pings) <= 9
    gaps = [b - a for a, b in zip(pings, pings[1:], strict=False)]
    assert all(0.25 - 1e-9 <= g <= 0.275 + 1e-9 for g in gaps)
    assert peer.inner.watchdog_trips == 0
    assert peer.inner.throttle_pct == pytest.approx(30.0)


def test_without_reads_the_stands_watchdog_trips_and_is_reported() -> None:
    stand, peer, clock, _ = sim_stand()
    out = LineStandEscOutput(stand)
    out.set_throttle({0: 1300.0})
    clock.advance_s(1.5)  # the host hangs: no PING
    stand.read_samples()
    assert peer.inner.watchdog_trips == 1
    assert stand.watchdog_trips == 1
    assert peer.inner.throttle_pct == 0.0


def test_no_keepalive_for_specs_without_one() -> None:
    clock = SimClock()
    peer = ScriptPeer([])
    stand = LineStand(SimSerial(peer, clock), clock, STM32_HX711)
    for _ in range(10):
        clock.advance_s(0.3)
        stand.read_samples()
    assert peer.written == []


# --------------------------------------------------------------------------- ESC output


def test_esc_output_stop_is_verified_from_the_throttle_column() -> None:
    stand, peer, clock, _ = sim_stand()
    with LineStandEscOutput(stand) as out:
        out.set_throttle({0: 1400.0})
        clock.advance_s(0.3)
        stand.read_samples()
        assert peer.inner.throttle_pct == pytest.approx(40.0)
    assert peer.inner.throttle_pct == 0.0
    assert b"STOP" in b"".join(d for _, d in peer.written)
    assert out.last_verification == "throttle column"


def test_esc_output_stop_not_verified_when_the_stand_ignores_it() -> None:
    clock = SimClock()
    spinning = b"".join(f"{i * 10000},1500,2500,0,16000,1000,9000\n".encode() for i in range(200))
    script = [(i * 0.01, spinning[i * 30 : (i + 1) * 30]) for i in range(len(spinning) // 30 + 1)]
    peer = ScriptPeer([(0.0, HEADER), *script])
    stand = LineStand(SimSerial(peer, clock), clock, REFERENCE)
    out = LineStandEscOutput(stand, verify_timeout_s=0.2)
    assert out.stop_and_verify(attempts=2) is False
    assert out.last_verification == "timeout"
    assert peer.lines_written().count(b"STOP") == 2


def test_esc_output_stop_refused_with_err() -> None:
    clock = SimClock()

    class Refuser(ScriptPeer):
        def write(self, data: bytes, now_s: float) -> None:
            super().write(data, now_s)
            if data == b"STOP\n":
                self.script.append((now_s, b"#ERR STOP\n"))

    peer = Refuser([(0.0, HEADER)])
    stand = LineStand(SimSerial(peer, clock), clock, REFERENCE)
    out = LineStandEscOutput(stand)
    out.stop()
    assert out.verify_stopped() is False
    assert out.last_verification == "refused"


def test_esc_output_without_throttle_column_confirms_by_the_link() -> None:
    spec = LineStandSpec(
        "thrust-only",
        {"thrust_n": Column(index=0)},
        header_prefix=None,
        throttle_command="T{pct:.0f}\n",
        stop_command="T0\n",
    )
    clock = SimClock()
    peer = ScriptPeer([(0.05 * i, b"0.5\n") for i in range(1, 40)])
    stand = LineStand(SimSerial(peer, clock), clock, spec)
    out = LineStandEscOutput(stand)
    assert out.throttle_scale.name == "pwm"
    out.set_throttle({0: 1250.0})
    assert out.stop_and_verify() is True
    assert out.last_verification == "link only"
    assert peer.lines_written() == [b"T25", b"T0"]


def test_esc_output_refuses_other_motors_and_clamps() -> None:
    stand, peer, clock, _ = sim_stand()
    out = LineStandEscOutput(stand)
    with pytest.raises(SafetyError, match="drives one motor"):
        out.set_throttle({1: 1200.0})
    with pytest.raises(SafetyError, match="finite"):
        out.set_throttle({0: float("nan")})
    out.set_throttle({0: 2600.0})
    assert peer.written[-1][1] == b"THR 2000\n"
    out.set_throttle({0: 900.0})
    assert peer.written[-1][1] == b"THR 1000\n"


def test_esc_output_needs_a_throttle_command() -> None:
    spec = LineStandSpec("sense-only", {"thrust_n": Column(index=0)}, header_prefix=None)
    clock = SimClock()
    stand = LineStand(SimSerial(ScriptPeer([]), clock), clock, spec)
    with pytest.raises(ConfigError, match="no throttle command"):
        LineStandEscOutput(stand)


def test_esc_output_telemetry_from_the_last_line() -> None:
    stand, _, clock, _ = sim_stand()
    out = LineStandEscOutput(stand)
    out.set_throttle({0: 1500.0})
    clock.advance_s(0.1)
    tel = out.read_telemetry()
    assert tel.rpm == (15000.0,)
    assert tel.voltage_v == pytest.approx(16.0 - 0.0375, abs=1e-3)


def test_close_sends_stop_once_and_closes_the_port() -> None:
    stand, peer, clock, _ = sim_stand()
    stand.close()
    stand.close()
    assert [d for _, d in peer.written].count(b"STOP\n") == 1
    assert not stand.port.is_open


def test_generic_hold_preset_commands_in_percent() -> None:
    spec = preset("generic-hold-csv")
    clock = SimClock()
    peer = ScriptPeer([])
    stand = LineStand(SimSerial(peer, clock), clock, spec)
    out = LineStandEscOutput(stand)
    assert out.throttle_scale.name == "percent"
    out.set_throttle({0: 12.5})
    assert peer.lines_written() == [b"HOLD,12.5,0,0"]


def test_rp2040_whoop_now_means_the_einsz_firmware_and_never_asks_for_more() -> None:
    """einsz/whoop_thrust_stand takes a bare whole percent (``setThrottle(atoi(cmd))``): 12.5 %
    is sent as 12, never rounded up to 13."""
    spec = preset("rp2040-whoop")
    assert spec.name == "einsz-whoop"
    clock = SimClock()
    peer = ScriptPeer([])
    stand = LineStand(SimSerial(peer, clock), clock, spec)
    out = LineStandEscOutput(stand)
    out.set_throttle({0: 12.5})
    out.set_throttle({0: 12.999})
    out.stop()
    assert peer.lines_written() == [b"12", b"12", b"STOP"]


# --------------------------------------------------------------------------- JSON specs


def test_spec_json_round_trips(tmp_path: Path) -> None:
    for spec in (REFERENCE, STM32_HX711, preset("rp2040-whoop"), preset("avenhaus-thrust-stand")):
        path = tmp_path / f"{spec.name}.json"
        path.write_text(json.dumps(line_spec_to_dict(spec)), encoding="utf-8")
        assert load_line_spec(path) == spec


def test_spec_extends_a_preset_with_a_load_cell(tmp_path: Path) -> None:
    path = tmp_path / "mine.json"
    path.write_text(
        json.dumps(
            {
                "extends": "stm32-hx711",
                "name": "bench-2",
                "columns": {"rpm": {"index": 3}},
                "load_cell": {"field": "thrust_n", "tare": 8000, "si_per_count": 0.0005},
            }
        ),
        encoding="utf-8",
    )
    spec = load_line_spec(path)
    assert spec.name == "bench-2"
    assert spec.throttle_command == STM32_HX711.throttle_command
    assert spec.columns["rpm"] == Column(index=3)
    assert spec.columns["thrust_n"].to_si(10000) == pytest.approx(1.0)
    clock = SimClock()
    peer = ScriptPeer([(0.0, b"5,1200,12000,4321\n")])
    (sample,) = LineStand(SimSerial(peer, clock), clock, spec).read_samples()
    assert (sample.thrust_n, sample.rpm) == (pytest.approx(2.0), 4321.0)


@pytest.mark.parametrize(
    ("text", "match", "line"),
    [
        ('{"name": "x",\n "columns": {\n}\n', "not valid JSON", 4),
        ('{"name": "x",\n "columns": {"thrust_n": {"index": 0}},\n "baud": 9600}', "'baud'", 3),
        ('{"name": "x",\n "columns": {"thrust": {"index": 0}}}', "columns.thrust", 2),
        (
            '{"name": "x",\n "columns": {"thrust_n": {"index": 0, "name": "f"}}}',
            "exactly one of",
            2,
        ),
        (
            '{"name": "x",\n "columns": {"thrust_n":\n {"index": 0, "scale": "1e-3"}}}',
            "columns.thrust_n.scale.*expected a number",
            3,
        ),
        ('{"name": "x", "columns": {"rpm": {"index": 0}}}', "thrust_n column is required", None),
        ('{"extends": "tyto"}', "unknown line stand preset", 1),
        ('{"name": "x"}', "key 'columns': required", None),
        (
            '{"extends": "thrustmap-line",\n "throttle_command": "THR {speed}\\n"}',
            "bad command template",
            None,
        ),
        ('{"extends": "thrustmap-line",\n "watchdog_s": -1}', "watchdog_s.*positive", 2),
        ('{"extends": "thrustmap-line",\n "throttle_scale": "volts"}', "unknown throttle", 2),
    ],
)
def test_spec_errors_name_file_key_and_line(
    tmp_path: Path, text: str, match: str, line: int | None
) -> None:
    path = tmp_path / "bad.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=match) as info:
        load_line_spec(path)
    assert info.value.file == str(path)
    assert str(path) in str(info.value)
    if line is not None:
        assert info.value.line == line


def test_spec_missing_file() -> None:
    with pytest.raises(ConfigError, match="cannot read line stand spec"):
        load_line_spec("/nonexistent/stand.json")


def test_spec_from_dict_needs_an_object() -> None:
    with pytest.raises(ConfigError, match="JSON object"):
        line_spec_from_dict([1, 2])


def test_spec_json_is_read_strictly(tmp_path: Path) -> None:
    """Through thrustmap.core.jsonfile: NaN/Infinity are not JSON, and the error names file and line."""
    path = tmp_path / "nan.json"
    path.write_text('{"extends": "thrustmap-line",\n "watchdog_s": NaN}', encoding="utf-8")
    with pytest.raises(ConfigError, match="not valid JSON") as info:
        load_line_spec(path)
    assert info.value.file == str(path)
