"""Device factories: detection (URL, transcript, safe probe), opening outputs and stands, ports."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

import thrustmap.protocols.peer as protocols_peer
import thrustmap.rig.devices.builtin as builtin
import thrustmap.rig.devices.detect as detect
import thrustmap.rig.devices.opening as opening
import thrustmap.rig.devices.ports as ports
import thrustmap.rig.devices.probe as probe
import thrustmap.rig.devices.registry as registry
import thrustmap.rig.devices.urls as devices_urls
from thrustmap.core.clock import SimClock
from thrustmap.core.errors import ConfigError
from thrustmap.protocols.msp.framing import MspCommand, encode_request
from thrustmap.protocols.msp.messages import ArmingDisable
from thrustmap.protocols.peer import BytePeer
from thrustmap.protocols.stands.line_presets import preset
from thrustmap.protocols.transcript import TranscriptWriter
from thrustmap.protocols.urlhandlers import protocol_sim
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.fc.msp import MspThrottleOutput
from thrustmap.rig.sim.mavlink_peers import ArduPilotVehicle, PX4Vehicle
from thrustmap.rig.sim.msp_peer import MspPeer
from thrustmap.rig.sim.plant import ConstantPlant
from thrustmap.rig.sim.stand_peers import LineStandPeer, TytoStandPeer
from thrustmap.rig.stand.line import LineStand, LineStandEscOutput
from thrustmap.rig.stand.line_spec import line_spec_to_dict
from thrustmap.rig.stand.tyto import TytoEscOutput, TytoStand


class Spy:
    """Wraps a peer and records every write."""

    def __init__(self, inner: BytePeer) -> None:
        self.inner = inner
        self.written = bytearray()

    def write(self, data: bytes, now_s: float) -> None:
        self.written += data
        self.inner.write(data, now_s)

    def read(self, now_s: float) -> bytes:
        return self.inner.read(now_s)


class Silent:
    def __init__(self) -> None:
        self.written = bytearray()

    def write(self, data: bytes, now_s: float) -> None:
        self.written += data

    def read(self, now_s: float) -> bytes:
        return b""


@pytest.fixture
def peers(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[tuple[str, Any]]]:
    """Every peer a sim:// URL creates, with its name."""
    import thrustmap.rig.sim.peers  # noqa: F401 - the bench-plant registrations

    created: list[tuple[str, Any]] = []
    original = protocols_peer.create_peer

    def spy(name: str, options: Any = None) -> BytePeer:
        peer = original(name, options)
        created.append((name, peer))
        return peer

    monkeypatch.setattr(protocol_sim, "create_peer", spy)
    yield created


# --------------------------------------------------------------------------- detection


@pytest.mark.parametrize(
    ("url", "kind", "firmware", "line"),
    [
        ("sim://betaflight?protocol=PWM", "msp", "betaflight", None),
        ("sim://inav", "msp", "inav", None),
        ("sim://betaflight?firmware=inav", "msp", "inav", None),
        ("sim://px4?motors=4", "mavlink", "px4", None),
        ("sim://ardupilot", "mavlink", "ardupilot", None),
        ("sim://tyto-1585?drive_esc=0", "tyto-1585", None, None),
        ("sim://line-stand", "line-stand", None, "thrustmap-line"),
        ("sim://line-stand?line_preset=stm32-hx711", "line-stand", None, "victorhook-thruststand"),
        ("record://sim://px4?motors=4&file=x.jsonl", "mavlink", "px4", None),
    ],
)
def test_detect_from_sim_urls(url: str, kind: str, firmware: str | None, line: str | None) -> None:
    found = detect.detect_from_url(url)
    assert found is not None
    assert (found.kind, found.firmware, found.line_preset) == (kind, firmware, line)


def test_real_urls_are_not_detected_without_io() -> None:
    assert detect.detect_from_url("/dev/ttyACM0") is None
    assert detect.detect_from_url("socket://192.168.4.1:23") is None
    assert detect.detect_from_url("sim://unknown-thing") is None


def test_is_simulated() -> None:
    assert devices_urls.is_simulated("sim://px4")
    assert devices_urls.is_simulated("replay://fixtures/a.jsonl")
    assert devices_urls.is_simulated("record://sim://px4?file=a.jsonl")
    assert not devices_urls.is_simulated("record:///dev/ttyACM0?file=a.jsonl")
    assert not devices_urls.is_simulated("COM3")
    assert not devices_urls.is_simulated("/dev/ttyUSB0")


def _transcript(path: Path, inner: str, events: list[tuple[str, bytes]]) -> str:
    with TranscriptWriter(path, inner=inner, origin_s=0.0) as writer:
        for i, (direction, data) in enumerate(events):
            writer.event(direction, data, 0.01 * i)  # type: ignore[arg-type]
    return f"replay://{path}"


def test_detect_from_a_transcript_of_a_real_port(tmp_path: Path) -> None:
    msp = _transcript(
        tmp_path / "a.jsonl", "/dev/ttyACM0", [("w", encode_request(1)), ("r", b"$M>\x03\x01")]
    )
    assert detect.detect_kind(msp, SimClock()).kind == "msp"
    line = _transcript(tmp_path / "b.jsonl", "COM7", [("r", b"# hello\n#COLS t_us,thrust_mN\n")])
    found = detect.detect_kind(line, SimClock())
    assert (found.kind, found.line_preset) == ("line-stand", None)
    tyto = _transcript(tmp_path / "c.jsonl", "COM8", [("r", b"Ready\r\n")])
    assert detect.detect_kind(tyto, SimClock()).kind == "tyto-1585"
    blank = _transcript(tmp_path / "d.jsonl", "COM9", [("r", b"??")])
    with pytest.raises(ConfigError, match="pass --kind"):
        detect.detect_kind(blank, SimClock())


def test_detect_from_a_transcript_of_a_sim(tmp_path: Path) -> None:
    url = _transcript(tmp_path / "e.jsonl", "sim://ardupilot?motors=4", [])
    found = detect.detect_kind(url, SimClock())
    assert (found.kind, found.firmware) == ("mavlink", "ardupilot")


@pytest.mark.parametrize(
    ("peer", "kind", "firmware", "line"),
    [
        (PX4Vehicle(ConstantPlant(4)), "mavlink", "px4", None),
        (ArduPilotVehicle(ConstantPlant(4)), "mavlink", "ardupilot", None),
        (TytoStandPeer(ConstantPlant(1)), "tyto-1585", None, None),
        (LineStandPeer(ConstantPlant(1)), "line-stand", None, "thrustmap-line"),
        (
            LineStandPeer(ConstantPlant(1), preset("generic-hold-csv")),
            "line-stand",
            None,
            "generic-hold-csv",
        ),
        (
            LineStandPeer(ConstantPlant(1), preset("stm32-hx711")),
            "line-stand",
            None,
            "victorhook-thruststand",
        ),
    ],
)
def test_sniff_recognises_talkers_without_writing(
    peer: BytePeer, kind: str, firmware: str | None, line: str | None
) -> None:
    clock = SimClock()
    spy = Spy(peer)
    found = detect.sniff(SimSerial(spy, clock), clock, listen_s=2.0)
    assert found is not None
    assert (found.kind, found.firmware, found.line_preset) == (kind, firmware, line)
    assert bytes(spy.written) == b""  # listening only


@pytest.mark.parametrize("firmware", ["betaflight-4", "inav"])
def test_sniff_asks_msp_with_whole_frames_only(firmware: str) -> None:
    clock = SimClock()
    peer = MspPeer(ConstantPlant(4), firmware)
    spy = Spy(peer)
    found = detect.sniff(SimSerial(spy, clock), clock, listen_s=1.0)
    assert found is not None
    assert found.kind == "msp"
    assert found.firmware == ("inav" if firmware == "inav" else "betaflight")
    assert found.evidence.startswith("MSP API ")
    assert bytes(spy.written) == encode_request(MspCommand.API_VERSION) + encode_request(
        MspCommand.FC_VARIANT
    )
    assert not peer.in_cli and not peer.in_bootloader
    assert clock.now_s() == pytest.approx(1.0, abs=0.1)


def test_sniff_of_a_silent_port_gives_up() -> None:
    clock = SimClock()
    peer = Silent()
    assert detect.sniff(SimSerial(peer, clock), clock, listen_s=1.0, msp_timeout_s=0.3) is None
    assert bytes(peer.written) == encode_request(MspCommand.API_VERSION)
    assert clock.now_s() == pytest.approx(1.3, abs=0.05)


def test_classify_bytes_is_strict_about_text() -> None:
    assert detect.classify_bytes(b"hello world\nthis is text\nmore\nlines\n") is None
    assert detect.classify_bytes(b"1,2,3\n4,5\n6,7,8\n9,1,2\n") is None  # ragged
    found = detect.classify_bytes(b"1 2.5 -3e2 4\n" * 4)
    assert found is not None and found.kind == "line-stand" and found.line_preset is None
    assert detect.classify_bytes(b"Read") is None  # an unfinished line


# --------------------------------------------------------------------------- opening


def test_open_msp_output_by_url(peers: list[tuple[str, Any]]) -> None:
    clock = SimClock()
    out = opening.open_throttle_output("sim://betaflight?protocol=PWM", clock)
    assert isinstance(out, MspThrottleOutput)
    with out:
        ident = out.identify()
        assert (ident.kind, ident.motor_protocol, ident.motor_count) == ("betaflight", "PWM", 4)
        assert out.throttle_scale.name == "pwm"
        out.set_throttle({2: 1300.0})
        ((_, peer),) = peers
        assert peer.motor_values == [1000, 1000, 1300, 1000]
        assert peer.arming_disable_flags & ArmingDisable.MSP
    assert peer.motor_values == [1000] * 4
    assert not peer.arming_disable_flags & ArmingDisable.MSP  # re-enabled after the stop


def test_open_output_with_kind_alias(peers: list[tuple[str, Any]]) -> None:
    out = opening.open_throttle_output("sim://inav", SimClock(), kind="INAV")
    with out:
        assert out.identify().kind == "inav"


def test_kind_for_a_stand_refuses_an_unknown_kind() -> None:
    with pytest.raises(ConfigError, match="unknown device kind 'esc'"):
        opening.open_throttle_output("sim://betaflight", SimClock(), kind="esc")


def test_open_mavlink_outputs(peers: list[tuple[str, Any]]) -> None:
    clock = SimClock()
    for url, firmware in (("sim://px4?bench=p", "px4"), ("sim://ardupilot?bench=a", "ardupilot")):
        out = opening.open_throttle_output(url, clock)
        with out:
            assert out.identify().kind == firmware
    assert [name for name, _ in peers] == ["px4", "ardupilot"]


def test_mavlink_kind_hint_must_match(peers: list[tuple[str, Any]]) -> None:
    with pytest.raises(ConfigError, match="expected a px4 vehicle"):
        opening.open_throttle_output("sim://ardupilot", SimClock(), kind="px4")
    ((_, peer),) = peers


def test_line_stand_esc_output_owns_its_stand(peers: list[tuple[str, Any]]) -> None:
    clock = SimClock()
    out = opening.open_throttle_output("sim://line-stand", clock)
    assert isinstance(out, opening.StandEscOutput)
    assert isinstance(out.inner, LineStandEscOutput)
    ((_, peer),) = peers
    with out:
        out.set_throttle({0: 1250.0})
        clock.advance_s(0.1)
        assert peer.throttle_pct == pytest.approx(25.0)
        assert out.stand.read_samples()[-1].throttle_native == pytest.approx(1250.0)
    assert peer.throttle_pct == 0.0
    assert not out.stand.port.is_open  # type: ignore[attr-defined]


def test_tyto_esc_output(peers: list[tuple[str, Any]]) -> None:
    clock = SimClock()
    out = opening.open_throttle_output("sim://tyto-1585", clock)
    assert isinstance(out, opening.StandEscOutput) and isinstance(out.inner, TytoEscOutput)
    ((_, peer),) = peers
    with out:
        out.set_throttle({0: 1400.0})
        out.stand.read_samples()
        assert peer.esc_us == 1400
    assert peer.esc_us == 1000


def test_stand_esc_output_shares_an_open_stand(peers: list[tuple[str, Any]]) -> None:
    clock = SimClock()
    with opening.open_stand("sim://line-stand", clock) as stand:
        out = opening.stand_esc_output(stand)
        with out:
            out.set_throttle({0: 1100.0})
        assert stand.port.is_open  # type: ignore[attr-defined]  # the output did not close it
    assert len(peers) == 1


def test_open_stand_kinds(peers: list[tuple[str, Any]]) -> None:
    clock = SimClock()
    with opening.open_stand("sim://tyto-1585", clock) as stand:
        assert isinstance(stand, TytoStand)
        assert stand.calibration.serial == "SIM-1585"
    with opening.open_stand("sim://line-stand?rate_hz=50", clock) as stand:
        assert isinstance(stand, LineStand)
        assert stand.spec.name == "thrustmap-line"
        assert stand.read_samples()  # data arrived (open waited for it)


def test_open_stand_from_a_spec_file(tmp_path: Path, peers: list[tuple[str, Any]]) -> None:
    spec = dict(line_spec_to_dict(preset("thrustmap-line")), name="my-stand")
    path = tmp_path / "stand.json"
    path.write_text(json.dumps(spec), encoding="utf-8")
    clock = SimClock()
    with opening.open_stand("sim://line-stand", clock, line_spec_file=str(path)) as stand:
        assert isinstance(stand, LineStand)
        assert stand.spec.name == "my-stand"
        clock.advance_s(0.1)
        assert len(stand.read_samples()) >= 10


def test_open_stand_refuses_an_fc() -> None:
    with pytest.raises(ConfigError, match="flight controller"):
        opening.open_stand("sim://betaflight", SimClock())


def test_real_tyto_needs_a_calibration() -> None:
    with pytest.raises(ConfigError, match="--calibration"):
        opening.open_stand("/dev/nonexistent-tyto", SimClock(), kind="tyto-1585")


def test_real_line_stand_needs_a_preset() -> None:
    with pytest.raises(ConfigError, match="--line-preset"):
        builtin.line_spec_for("/dev/ttyACM0")
    with pytest.raises(ConfigError, match="not both"):
        builtin.line_spec_for("/dev/ttyACM0", line_preset="x", line_spec_file="y")


def test_silent_line_stand_fails_to_open(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = SimClock()
    silent = Silent()
    from thrustmap.core.errors import ThrustmapError
    from thrustmap.rig.devices import urls

    monkeypatch.setattr(urls, "open_transport", lambda url, **kwargs: SimSerial(silent, clock))
    with pytest.raises(ThrustmapError, match="no data from line stand"):
        opening.open_stand("/dev/fake", clock, line_preset="stm32-hx711", wait_s=0.5)
    assert b"1000\n" in bytes(silent.written)  # closing sent the stop command


def test_record_then_strict_replay_through_the_factory(tmp_path: Path) -> None:
    path = tmp_path / "bf.jsonl"
    clock = SimClock()
    out = opening.open_throttle_output(f"record://sim://betaflight?file={path}", clock)
    with out:
        ident = out.identify()
        out.set_throttle({0: 300.0})
    replay_clock = SimClock()
    again = opening.open_throttle_output(f"replay://{path}", replay_clock)
    assert isinstance(again, MspThrottleOutput)
    with again:
        assert again.identify() == ident
        again.set_throttle({0: 300.0})
    report = again.port.report()  # type: ignore[attr-defined]
    assert (report.write_bytes_remaining, report.mismatches) == (0, 0)
    assert report.write_bytes_matched > 50


# --------------------------------------------------------------------------- probe


def test_probe_fc_reports_identity_motors_and_battery(peers: list[tuple[str, Any]]) -> None:
    report = probe.probe_device("sim://betaflight", SimClock())
    assert report.identity is not None
    assert (report.identity.kind, report.identity.motor_protocol) == ("betaflight", "DSHOT600")
    assert report.throttle_scale == "dshot"
    assert report.motor_values == (1000, 1000, 1000, 1000, 0, 0, 0, 0)
    assert report.telemetry is not None and report.telemetry.voltage_v == pytest.approx(
        24.87, abs=0.1
    )
    ((_, peer),) = peers
    assert peer.motors_at_rest and not peer.arming_disable_flags & ArmingDisable.MSP
    data = report.to_dict()
    assert data["kind"] == "msp" and data["motor_values"][:4] == [1000] * 4  # type: ignore[index]


def test_probe_armed_fc_warns(
    peers: list[tuple[str, Any]], monkeypatch: pytest.MonkeyPatch
) -> None:
    from thrustmap.rig.sim import msp_peer

    original = msp_peer.MspPeer.__init__

    def armed_init(self: MspPeer, *args: Any, **kwargs: Any) -> None:
        original(self, *args, **kwargs)
        self.armed = True

    monkeypatch.setattr(msp_peer.MspPeer, "__init__", armed_init)
    report = probe.probe_device("sim://betaflight", SimClock())
    assert any("ARMED" in w for w in report.warnings)


def test_probe_stand_summarises_a_second(peers: list[tuple[str, Any]]) -> None:
    report = probe.probe_device("sim://line-stand?rate_hz=100", SimClock(), seconds=1.0)
    assert report.stand is not None
    assert 95 <= report.stand.samples <= 110
    assert report.stand.rate_hz == pytest.approx(100.0, rel=0.02)
    assert report.stand.means["voltage_v"] == pytest.approx(24.87, abs=0.1)
    assert abs(report.stand.means["thrust_n"]) < 0.05
    assert report.stand.bad_lines == 0


# --------------------------------------------------------------------------- ports


@dataclass
class FakePort:
    device: str
    vid: int | None = None
    pid: int | None = None
    description: str = "n/a"
    manufacturer: str | None = None
    product: str | None = None
    serial_number: str | None = None
    hwid: str = "n/a"


@pytest.mark.parametrize(
    ("port", "guess", "kinds", "safe"),
    [
        (
            FakePort("/dev/ttyACM0", 0x0483, 0x5740, "STM32 Virtual ComPort"),
            "STM32",
            ("msp", "mavlink"),
            True,
        ),
        (
            FakePort("/dev/ttyACM1", 0x0483, 0x5740, product="Betaflight STM32F7x2"),
            "Betaflight",
            ("msp",),
            True,
        ),
        (FakePort("/dev/ttyACM2", 0x0483, 0xDF11, "STM32 BOOTLOADER"), "DFU", (), False),
        (
            FakePort("/dev/ttyACM3", 0x1209, 0x5740, product="CubeOrange"),
            "Cube",
            ("mavlink",),
            True,
        ),
        (FakePort("/dev/ttyACM4", 0x26AC, 0x0011, "PX4 FMU v2.x"), "PX4", ("mavlink",), True),
        (
            FakePort("/dev/ttyUSB0", 0x10C4, 0xEA60, "CP2102 USB to UART"),
            "CP210x",
            ("line-stand", "mavlink", "msp"),
            True,
        ),
        (
            FakePort("/dev/ttyUSB1", 0x1A86, 0x7523, "USB Serial"),
            "CH340",
            ("line-stand", "tyto-1585"),
            True,
        ),
        (
            FakePort("/dev/ttyUSB2", 0x0403, 0x6015, "FT231X USB UART"),
            "FTDI",
            ("mavlink", "line-stand"),
            True,
        ),
        (FakePort("/dev/ttyACM5", 0x2E8A, 0x000A, "Pico"), "RP2040", ("line-stand",), True),
        (FakePort("/dev/ttyACM6", 0x16C0, 0x0483, "USB Serial"), "Teensy", ("line-stand",), True),
        (FakePort("/dev/ttyACM7", 0xABCD, 0x1234, "Widget"), "unknown", registry.kinds(), True),
        (FakePort("/dev/ttyS0"), "no USB IDs", (), True),
    ],
)
def test_describe_port(port: FakePort, guess: str, kinds: tuple[str, ...], safe: bool) -> None:
    desc = ports.describe_port(port)
    assert guess in desc.guess
    assert desc.kinds == kinds
    assert desc.probe_safe is safe
    if port.vid is not None:
        assert desc.usb_id == f"{port.vid:04X}:{port.pid:04X}"
    assert desc.to_dict()["device"] == port.device


def test_pymavlink_connection_strings_reach_the_mavlink_driver(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``udpin:``/``tcp:`` open through thrustmap's own transports (so ``record://`` works on
    them); here the transport is a simulated vehicle on the SimClock (real UDP is tested in
    test_rig_fc_firmware), and ``tcpin:`` too (locked to its first connection: test_link_lock).
    ``udpbcast:`` still goes to stock ``mavutil``, switched to MAVLink 2."""
    from pymavlink import mavutil

    from thrustmap.protocols.mavlink import link as mavlink_link
    from thrustmap.protocols.mavlink.link import MavlinkSerialLink

    found = detect.detect_from_url("udpin:0.0.0.0:14550")
    assert found is not None and found.kind == "mavlink"
    assert not devices_urls.is_simulated("tcp:127.0.0.1:5760")

    clock = SimClock()
    vehicle = PX4Vehicle(ConstantPlant(4))
    asked: list[str] = []

    def transport(url: str, **kwargs: Any) -> Any:
        asked.append(url)
        return SimSerial(vehicle, clock)

    monkeypatch.setattr(mavlink_link, "open_transport", transport)
    out = opening.open_throttle_output("udpin:127.0.0.1:14550", clock)
    with out:
        assert out.identify().kind == "px4"
        out.set_throttle({0: 0.3})
        assert vehicle.running_motors() == {0: pytest.approx(0.3)}
    assert vehicle.running_motors() == {}
    assert asked == ["udpin://127.0.0.1:14550"]
    with opening.open_throttle_output("tcpin:127.0.0.1:5760", clock) as out1:
        assert out1.identify().kind == "px4"
    assert asked[1:] == ["tcpin://127.0.0.1:5760"]

    stock: list[tuple[str, dict[str, Any]]] = []

    def connection(url: str, **kwargs: Any) -> Any:
        stock.append((url, kwargs))
        return MavlinkSerialLink(SimSerial(PX4Vehicle(ConstantPlant(4)), clock), clock)

    monkeypatch.setattr(mavutil, "mavlink_connection", connection)
    with opening.open_throttle_output("udpbcast:127.0.0.1:5760", clock) as out2:
        assert out2.identify().kind == "px4"
    assert stock == [
        ("udpbcast:127.0.0.1:5760", {"source_system": 255, "source_component": 190, "retries": 0})
    ]
