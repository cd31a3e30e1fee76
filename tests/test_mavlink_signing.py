"""MAVLink 2 signing (issue 36, item 3): ``--signing-key FILE|HEX`` (or
``THRUSTMAP_MAVLINK_SIGNING_KEY``) on every MAVLink command; outgoing messages signed, unsigned
or wrongly signed incoming ones refused; one clear line and exit 2 when thrustmap and the
vehicle disagree; the key in no output, log, recording or file thrustmap writes.

The vehicles are the simulated ones, which sign like ArduPilot (GCS_Signing.cpp: every port
signs once a key is set; the first port also takes unsigned messages, the others ignore them).
"""

from __future__ import annotations

import logging
import pickle
import socket
import time
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from thrustmap.cli import cli, main
from thrustmap.core.clock import MonotonicClock, SimClock
from thrustmap.core.errors import ConfigError
from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink import encode as enc
from thrustmap.protocols.mavlink.link import MavlinkSerialLink, open_mavlink
from thrustmap.protocols.mavlink.signing import (
    ENV_VAR,
    SigningKey,
    enable_signing,
    is_signed,
    parse_signing_key,
    sign_mavlink,
    signing_key_from,
)
from thrustmap.protocols.transcript import read_transcript
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.fc.mavlink import open_mavlink_output
from thrustmap.rig.fc.mavlink_session import SigningRequired
from thrustmap.rig.sim.mavlink_peers import ArduPilotVehicle, PX4Vehicle
from thrustmap.rig.sim.plant import ConstantPlant

KEY = bytes(range(1, 33))
OTHER_KEY = bytes(range(101, 133))


def write_key(folder: Path, key: bytes = KEY, *, raw: bool = False) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / ("key.bin" if raw else "key.hex")
    path.write_bytes(key if raw else (key.hex() + "\n").encode())
    return path


def sim_link(vehicle: Any, clock: SimClock, key: bytes | None = None) -> MavlinkSerialLink:
    link = MavlinkSerialLink(SimSerial(vehicle, clock), clock)
    if key is not None:
        enable_signing(link, SigningKey(key))
    return link


# ------------------------------------------------------------------------------------------
# the key
# ------------------------------------------------------------------------------------------
def test_a_key_from_hex_a_hex_file_a_raw_file_or_the_environment(tmp_path: Path) -> None:
    assert parse_signing_key(KEY.hex()).secret == KEY
    assert parse_signing_key(str(write_key(tmp_path / "h"))).secret == KEY
    assert parse_signing_key(str(write_key(tmp_path / "r", raw=True))).secret == KEY
    assert signing_key_from(None, {ENV_VAR: KEY.hex()}) == SigningKey(KEY)
    assert signing_key_from(OTHER_KEY.hex(), {ENV_VAR: KEY.hex()}) == SigningKey(OTHER_KEY)
    assert signing_key_from(None, {}) is None


def test_a_bad_key_is_one_line_that_never_repeats_it(tmp_path: Path) -> None:
    short = KEY.hex()[:-2]
    with pytest.raises(ConfigError) as exc:
        parse_signing_key(short)
    assert short not in str(exc.value) and "64 hex digits" in str(exc.value)
    bad = tmp_path / "bad.key"
    bad.write_text("not a key\n")
    with pytest.raises(ConfigError, match="bad.key: expected a MAVLink signing key"):
        parse_signing_key(str(bad))
    with pytest.raises(ConfigError, match="cannot read key file"):
        parse_signing_key(str(tmp_path / "missing.key"))
    with pytest.raises(ConfigError, match="all-zero"):
        parse_signing_key("00" * 32)


def test_the_key_never_shows_itself() -> None:
    key = SigningKey(KEY)
    for text in (repr(key), str(key), f"{key}", repr([key]), repr({"k": key})):
        assert KEY.hex() not in text and "hidden" in text
    with pytest.raises(TypeError):
        pickle.dumps(key)


# ------------------------------------------------------------------------------------------
# the wire
# ------------------------------------------------------------------------------------------
def test_outgoing_messages_are_signed_and_the_vehicle_accepts_them() -> None:
    clock = SimClock()
    vehicle = ArduPilotVehicle(ConstantPlant(), signing_key=SigningKey(KEY))
    out = open_mavlink_output(sim_link(vehicle, clock), clock, signing_key=SigningKey(KEY))
    with out:
        ident = out.identify()
    assert ident.kind == "ardupilot" and vehicle.refused_messages == 0
    assert vehicle.commands_received  # every command reached it, signed
    assert out.session.signed_messages > 0 and out.session.unsigned_messages == 0


def test_incoming_unsigned_messages_from_a_signing_vehicle_are_refused() -> None:
    """A spoofed unsigned ARMED heartbeat and COMMAND_ACK between the vehicle's signed ones:
    the parser refuses them; only the signed ones reach the session."""
    link = open_mavlink("loop://", clock=MonotonicClock())
    enable_signing(link, SigningKey(KEY))
    signer = mav.MavlinkCodec(1, 1)
    sign_mavlink(signer.mav, SigningKey(KEY), timestamp=link.mav.signing.timestamp)
    spoof = mav.MavlinkCodec(1, 1)
    link.port.write(spoof.encode(enc.heartbeat_message(mav.Autopilot.ARDUPILOT, armed=True)))
    link.port.write(signer.encode(enc.heartbeat_message(mav.Autopilot.ARDUPILOT, armed=False)))
    got = []
    while (msg := link.recv_match(blocking=True, timeout=0.3)) is not None:
        if msg.get_type() != "BAD_DATA":
            got.append(msg)
    assert [m.get_type() for m in got] == ["HEARTBEAT"]
    assert is_signed(got[0]) and mav.decode_heartbeat(got[0]).armed is False
    assert link.mav.signing.reject_count == 1
    link.close()


def test_a_vehicle_requiring_signing_says_so_in_one_line() -> None:
    clock = SimClock()
    vehicle = ArduPilotVehicle(ConstantPlant(), signing_key=SigningKey(KEY))
    out = open_mavlink_output(sim_link(vehicle, clock), clock)
    with pytest.raises(SigningRequired, match="the vehicle requires signed MAVLink: pass --sign"):
        out.identify()
    out.close()
    assert vehicle.refused_messages > 0  # it ignored our unsigned commands
    assert vehicle.commands_received == []


def test_the_first_port_of_ardupilot_takes_unsigned_commands_and_setup_signing() -> None:
    """ArduPilot's channel 0 accepts unsigned messages (and SETUP_SIGNING on it sets the key);
    the simulated vehicle's ``accept_unsigned`` is that port."""
    clock = SimClock()
    vehicle = ArduPilotVehicle(ConstantPlant(), accept_unsigned=True)
    link = sim_link(vehicle, clock)
    link.mav.setup_signing_send(1, 1, list(KEY), 1)
    vehicle.write(b"", clock.now_s())
    assert vehicle.signing_key == SigningKey(KEY)
    out = open_mavlink_output(link, clock)  # unsigned, on the first port: still answered
    with out:
        assert out.identify().kind == "ardupilot"
    assert out.session.signed_messages > 0 and vehicle.refused_messages == 0


def test_a_wrong_key_or_an_unsigned_vehicle_is_one_line() -> None:
    clock = SimClock()
    signing = ArduPilotVehicle(ConstantPlant(), signing_key=SigningKey(KEY))
    with pytest.raises(SigningRequired, match="another key"):
        open_mavlink_output(sim_link(signing, clock, OTHER_KEY), clock)
    clock = SimClock()
    plain = PX4Vehicle(ConstantPlant())
    with pytest.raises(SigningRequired, match="the vehicle does not sign"):
        open_mavlink_output(sim_link(plain, clock, KEY), clock)


def test_a_spoofed_unsigned_heartbeat_does_not_lock_a_signed_udp_link() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    link = open_mavlink(f"udpin:127.0.0.1:{port}", clock=MonotonicClock())
    enable_signing(link, SigningKey(KEY))
    spoofer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    try:
        hb = enc.heartbeat_message(mav.Autopilot.PX4, armed=False)
        spoofer.sendto(mav.MavlinkCodec(1, 1).encode(hb), ("127.0.0.1", port))
        other = mav.MavlinkCodec(1, 1)
        sign_mavlink(other.mav, SigningKey(OTHER_KEY), timestamp=link.mav.signing.timestamp)
        spoofer.sendto(other.encode(hb), ("127.0.0.1", port))
        time.sleep(0.05)
        signer = mav.MavlinkCodec(1, 1)
        sign_mavlink(signer.mav, SigningKey(KEY), timestamp=link.mav.signing.timestamp)
        vehicle.sendto(signer.encode(hb), ("127.0.0.1", port))
        msg = link.recv_match(type="HEARTBEAT", blocking=True, timeout=2.0)
        assert msg is not None and is_signed(msg)
        assert link.port.remote == vehicle.getsockname()
        assert link.heartbeats_refused_unsigned == 1
        assert link.heartbeats_refused_bad_signature == 1
    finally:
        link.close()
        spoofer.close()
        vehicle.close()


# ------------------------------------------------------------------------------------------
# the CLI
# ------------------------------------------------------------------------------------------
def run(args: list[str], env: dict[str, str] | None = None) -> Any:
    from thrustmap.rig.sim import peers

    peers.reset_benches()
    return CliRunner().invoke(cli, args, env=env or {ENV_VAR: ""})


def test_cli_probe_with_and_without_the_key(tmp_path: Path) -> None:
    keyfile = write_key(tmp_path / "secret")
    url = f"sim://ardupilot?signing_key_file={keyfile}"
    assert run(["probe", url, "--signing-key", str(keyfile)]).exit_code == 0
    assert run(["probe", url, "--signing-key", KEY.hex()]).exit_code == 0
    assert run(["probe", url], env={ENV_VAR: str(keyfile)}).exit_code == 0
    refused = run(["probe", url])  # main() turns it into one line and exit 2 (below)
    assert isinstance(refused.exception, SigningRequired)
    assert "the vehicle requires signed MAVLink: pass --signing-key" in str(refused.exception)


def test_cli_main_prints_one_line_and_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(ENV_VAR, raising=False)
    keyfile = write_key(tmp_path / "secret")
    with pytest.raises(SystemExit) as exc:
        main(["probe", f"sim://ardupilot?signing_key_file={keyfile}"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "error: the vehicle requires signed MAVLink: pass --signing-key FILE|HEX (or set "
        f"{ENV_VAR}); it signs its messages and ignored our unsigned commands"
    ]
    with pytest.raises(SystemExit) as exc:
        main(["probe", "sim://ardupilot", "--signing-key", KEY.hex()[:40]])
    assert exc.value.code == 2
    assert KEY.hex()[:40] not in capsys.readouterr().err


def test_a_key_for_an_msp_fc_is_refused(tmp_path: Path) -> None:
    done = run(["probe", "sim://betaflight", "--signing-key", KEY.hex()])
    assert isinstance(done.exception, ConfigError)  # main(): one line, exit 2
    assert "for MAVLink vehicles" in str(done.exception)


@pytest.mark.parametrize("firmware", ["ardupilot", "px4"])
def test_the_key_is_in_no_file_thrustmap_writes(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, firmware: str
) -> None:
    """A signed spin and a signed sweep, recorded (record://), logged at DEBUG, and a map fitted
    to the sweep: the key is in no byte of any file written, nor in the output or the log."""
    keyfile = write_key(tmp_path / "secret")
    work = tmp_path / "work"
    work.mkdir()
    fc = f"record://sim://{firmware}?signing_key_file={keyfile}&bench=k&file={work / 'fc.jsonl'}"
    outputs = []
    with caplog.at_level(logging.DEBUG):
        spin = run(
            ["spin", fc, "--motor", "1", "--throttle", "10", "--seconds", "1", "--yes"]
            + ["--signing-key", KEY.hex()]
        )
        assert spin.exit_code == 0, spin.output
        outputs.append(spin.output)
        fc2 = fc.replace("fc.jsonl", "fc2.jsonl")
        sweep = run(
            ["sweep", "stairs-up", "--stand", "sim://tyto-1585?bench=k&drive_esc=0"]
            + ["--throttle", fc2, "--to", "40", "--step", "10", "--dwell", "1"]
            + ["-o", str(work / "run.csv"), "--yes", "--quiet"],
            env={ENV_VAR: str(keyfile)},
        )
        assert sweep.exit_code == 0, sweep.output
        outputs.append(sweep.output)
        fit = run(["fit", str(work / "run.csv"), "-o", str(work / "map.json"), "--model", "linear"])
        assert fit.exit_code == 0, fit.output
    written = [p for p in work.rglob("*") if p.is_file()]
    assert {"fc.jsonl", "fc2.jsonl", "run.csv", "map.json"} <= {p.name for p in written}
    frames = mav.MavlinkCodec().feed(read_transcript(work / "fc.jsonl").written())
    assert frames and all(is_signed(f) for f in frames)  # what went out was signed
    needles = [KEY, KEY.hex().encode(), KEY.hex().upper().encode()]
    for path in written:
        data = path.read_bytes()
        for needle in needles:
            assert needle not in data, f"the key is in {path}"
    text = "\n".join(outputs) + caplog.text
    assert KEY.hex() not in text and KEY.hex().upper() not in text


def test_a_key_from_the_environment_is_ignored_by_an_msp_fc() -> None:
    """The variable may be set for a whole shell: a Betaflight probe is not refused for it."""
    done = run(["probe", "sim://betaflight"], env={ENV_VAR: KEY.hex()})
    assert done.exit_code == 0, done.output
    assert signing_key_from(None, {ENV_VAR: KEY.hex()}).from_environment  # type: ignore[union-attr]
    assert not parse_signing_key(KEY.hex()).from_environment
