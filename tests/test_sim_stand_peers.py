"""Simulated stands: the Tyto-like binary stand and the line stand, read back through the codecs."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.generic_stand import GENERIC_3COL as STM32_HX711

from thrustmap.core.clock import SimClock
from thrustmap.core.errors import ConfigError
from thrustmap.protocols.peer import BytePeer
from thrustmap.protocols.stands.line import (
    REFERENCE,
    RP2040_WHOOP,
    LineComment,
    LineSample,
    LineStandDecoder,
)
from thrustmap.protocols.stands.tyto import (
    TytoDecoder,
    TytoFrame,
    TytoPoll,
    TytoReading,
    TytoReady,
)
from thrustmap.protocols.transport import open_transport
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.sim.plant import ConstantPlant
from thrustmap.rig.sim.stand_peers import (
    SIM_TYTO_CALIBRATION,
    LineStandPeer,
    TytoStandPeer,
    line_peer_from_options,
    tyto_peer_from_options,
)
from thrustmap.rig.stand.tyto import save_calibration

# --------------------------------------------------------------------------- Tyto


def test_tyto_is_a_byte_peer() -> None:
    assert isinstance(TytoStandPeer(ConstantPlant(1)), BytePeer)
    assert isinstance(LineStandPeer(ConstantPlant(1)), BytePeer)


def test_tyto_boot_banner_and_poll() -> None:
    plant = ConstantPlant(1, voltage_v=16.0, max_thrust_n=10.0)
    peer = TytoStandPeer(plant, boot_s=1.5)
    decoder = TytoDecoder()
    peer.write(TytoPoll(2000).frame(), 0.0)  # before Ready: lost
    assert decoder.feed_events(peer.read(1.0)) == []
    assert decoder.feed_events(peer.read(1.5)) == [TytoReady()]
    peer.write(TytoPoll(1500).frame(), 2.0)
    (frame,) = decoder.feed(peer.read(2.0))
    m = SIM_TYTO_CALIBRATION.to_si(TytoReading.decode(frame.payload))
    assert m.thrust_n == pytest.approx(10.0 * 0.5**2, abs=1e-3)  # float32 counts
    assert m.torque_nm == pytest.approx(0.012 * 2.5, abs=1e-4)
    assert m.rpm_electrical == pytest.approx(15000.0)
    assert m.voltage_v == pytest.approx(16.0 - 0.01 * 30 * 0.125, abs=1e-4)
    raw = TytoReading.decode(frame.payload)
    assert raw.load_thrust < SIM_TYTO_CALIBRATION.thrust.tare  # pulling lowers the raw count
    assert peer.esc_us == 1500 and peer.polls == 1


def test_tyto_throttle_follows_each_poll() -> None:
    plant = ConstantPlant(1)
    peer = TytoStandPeer(plant, boot_s=0.0)
    peer.read(0.0)
    peer.write(TytoPoll(2000).frame() + TytoPoll(1000).frame(), 1.0)
    frames = TytoDecoder().feed(peer.read(1.0))
    thrusts = [SIM_TYTO_CALIBRATION.to_si(TytoReading.decode(f.payload)).thrust_n for f in frames]
    assert thrusts == pytest.approx([10.0, 0.0], abs=1e-3)
    assert plant.state(2.0).rpm[0] == 0.0


def test_tyto_ignores_corrupt_and_unknown_requests() -> None:
    peer = TytoStandPeer(ConstantPlant(1), boot_s=0.0)
    peer.read(0.0)
    bad = bytearray(TytoPoll(1500).frame())
    bad[-1] ^= 1
    peer.write(bytes(bad) + TytoFrame("<", 9, b"").encode() + TytoFrame("<", 3, b"x").encode(), 1)
    assert peer.read(1.0) == b"" and peer.polls == 0


def test_tyto_over_sim_serial_with_custom_calibration(tmp_path: Path) -> None:
    cal_path = tmp_path / "cal.json"
    save_calibration(SIM_TYTO_CALIBRATION, cal_path)
    clock = SimClock()
    peer = tyto_peer_from_options({"calibration": str(cal_path), "boot_s": "0.5"})
    port = SimSerial(peer, clock, timeout=2.0)
    assert port.read(7) == b"Ready\r\n"
    assert 0.5 <= clock.now_s() < 0.6
    port.write(TytoPoll(1800).frame())
    (frame,) = TytoDecoder().feed(port.read(64))
    assert SIM_TYTO_CALIBRATION.to_si(TytoReading.decode(frame.payload)).thrust_n == (
        pytest.approx(6.4, abs=1e-3)
    )
    with pytest.raises(ConfigError):
        tyto_peer_from_options({"baud": "250000"})


def test_tyto_noise_is_seeded() -> None:
    import random

    def first_thrust(seed: int) -> float:
        peer = TytoStandPeer(ConstantPlant(1), boot_s=0, noise_counts=5.0, rng=random.Random(seed))
        peer.read(0.0)
        peer.write(TytoPoll(1000).frame(), 0.1)
        (f,) = TytoDecoder().feed(peer.read(0.1))
        return TytoReading.decode(f.payload).load_thrust

    assert first_thrust(1) == first_thrust(1) != first_thrust(2)


# --------------------------------------------------------------------------- line stand


_decoders: dict[int, LineStandDecoder] = {}


def run(peer: LineStandPeer, until_s: float) -> list[LineSample]:
    """Samples the peer has streamed by ``until_s`` (one decoder per peer, header included)."""
    decoder = _decoders.setdefault(id(peer), LineStandDecoder(peer.spec))
    return decoder.feed(peer.read(until_s))


def test_line_stand_streams_at_rate_with_banner_and_header() -> None:
    peer = LineStandPeer(ConstantPlant(1), REFERENCE, rate_hz=50.0)
    decoder = LineStandDecoder(REFERENCE)
    events = decoder.feed_events(peer.read(0.0))
    assert isinstance(events[0], LineComment) and "simulated" in events[0].text
    samples = decoder.feed(peer.read(1.0))
    assert len(samples) == 50  # t = 0.02 .. 1.00 (t = 0 came with the banner)
    assert samples[-1].time_s == pytest.approx(1.0)
    assert all(s.thrust_n == 0.0 for s in samples)


def test_line_stand_obeys_commands() -> None:
    plant = ConstantPlant(1, max_thrust_n=8.0)
    peer = LineStandPeer(plant, REFERENCE, rate_hz=100.0)
    run(peer, 0.0)
    peer.write(REFERENCE.command_for(1500), 0.1)
    samples = run(peer, 0.5)
    assert samples[-1].throttle == 1500.0
    assert samples[-1].thrust_n == pytest.approx(2.0, abs=1e-3)
    assert samples[-1].rpm == pytest.approx(15000.0)
    peer.write(REFERENCE.stop_bytes(), 0.6)
    assert run(peer, 0.7)[-1].thrust_n == 0.0


def test_watchdog_stops_the_motor_without_keepalives() -> None:
    plant = ConstantPlant(1)
    peer = LineStandPeer(plant, REFERENCE, rate_hz=100.0)
    peer.read(0.0)
    peer.write(b"THR 2000\n", 0.0)
    for k in range(1, 9):  # PING every 0.25 s keeps it alive
        peer.write(b"PING\n", 0.25 * k)
    assert peer.throttle_pct == 100.0
    decoder = LineStandDecoder(REFERENCE)
    events = decoder.feed_events(peer.read(4.0))  # pings stop at 2.0 s
    assert peer.watchdog_trips == 1 and peer.throttle_pct == 0.0
    trip = [e for e in events if isinstance(e, LineComment) and e.text == "WATCHDOG"]
    assert len(trip) == 1
    samples = [e for e in events if isinstance(e, LineSample)]
    assert all(s.thrust_n > 0 for s in samples if s.time_s is not None and s.time_s < 3.0)
    assert all(s.thrust_n == 0 for s in samples if s.time_s is not None and s.time_s > 3.0)


def test_stand_without_watchdog_keeps_running() -> None:
    peer = LineStandPeer(ConstantPlant(1), STM32_HX711, rate_hz=10.0)
    peer.write(b"1700\n", 0.0)
    samples = run(peer, 30.0)
    assert samples[-1].throttle == 1700.0 and samples[-1].thrust_n > 0  # raw counts, uncalibrated
    assert peer.watchdog_trips == 0


def test_unknown_command_gets_err_line() -> None:
    peer = LineStandPeer(ConstantPlant(1), RP2040_WHOOP, rate_hz=10.0)
    peer.write(b"FLY AWAY\r\n", 0.0)
    events = LineStandDecoder(RP2040_WHOOP).feed_events(peer.read(0.0))
    assert any(isinstance(e, LineComment) and e.text == "ERR FLY AWAY" for e in events)
    peer.write(RP2040_WHOOP.command_for(40.0), 0.05)
    assert peer.throttle_pct == 40.0


def test_long_silence_is_bounded() -> None:
    peer = LineStandPeer(ConstantPlant(1), REFERENCE, rate_hz=1000.0, max_backlog_s=2.0)
    peer.write(b"THR 1600\n", 0.0)
    samples = run(peer, 3600.0)
    assert len(samples) <= 1 + 2001  # t = 0, then the last 2 s only
    assert peer.watchdog_trips == 1 and samples[-1].thrust_n == 0.0


def test_line_peer_options() -> None:
    peer = line_peer_from_options({"preset": "stm32-hx711", "rate_hz": "20"})
    assert peer.spec.name == "victorhook-thruststand" and peer.period_s == pytest.approx(0.05)
    with pytest.raises(ConfigError):
        line_peer_from_options({"preset": "nope"})
    with pytest.raises(ConfigError):
        line_peer_from_options({"rate_hz": "fast"})


@settings(max_examples=40)
@given(st.lists(st.tuples(st.binary(max_size=20), st.floats(0, 0.5)), max_size=10))
def test_line_peer_survives_random_input(chunks: list[tuple[bytes, float]]) -> None:
    peer = LineStandPeer(ConstantPlant(1), REFERENCE, rate_hz=100.0)
    t = 0.0
    decoder = LineStandDecoder(REFERENCE)
    for data, dt in chunks:
        t += dt
        peer.write(data, t)
        decoder.feed(peer.read(t))
    assert decoder.error_count == 0


def test_sim_urls_build_the_registered_stands() -> None:
    from thrustmap.rig.devices.urls import load_sim_peers

    load_sim_peers()  # the rig binds tyto-1585 and line-stand (rig.sim.peers)
    clock = SimClock()
    port = open_transport("sim://tyto-1585?boot_s=0.2", timeout=1.0, clock=clock)
    assert port.read(7) == b"Ready\r\n"
    line = open_transport("sim://line-stand?rate_hz=10", timeout=0.5, clock=clock)
    decoder = LineStandDecoder(REFERENCE)
    events = decoder.feed_events(line.read(10_000))
    assert any(isinstance(e, LineSample) for e in events) and decoder.error_count == 0
