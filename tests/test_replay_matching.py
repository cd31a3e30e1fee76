"""Message-level replay: recordings outlive the driver that made them.

The shared real-firmware recordings (ArduPilot, PX4, Betaflight), made by an earlier driver,
replay through today's ``thrustmap probe`` and ``spin``; a recording made now replays after the
driver's request order changes; a real divergence is named in message terms."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from click.testing import CliRunner, Result

from thrustmap.cli import cli
from thrustmap.core.clock import SimClock
from thrustmap.protocols.msp.framing import MspCommand, encode_reply, encode_request
from thrustmap.protocols.transcript import TranscriptWriter, read_transcript
from thrustmap.protocols.urlhandlers.protocol_replay import (
    ReplayDivergenceError,
    ReplayMismatchError,
    ReplaySerial,
)


def run(*args: str) -> Result:
    return CliRunner().invoke(cli, list(args))


def said(result: Result) -> str:
    """What the user sees: the output, or the one-line error the CLI's entry point prints."""
    return result.output + ("" if result.exception is None else f"\n{result.exception}")


def transcripts(shared_data: Path) -> Path:
    folder = shared_data / "firmware-transcripts"
    if not folder.is_dir():
        pytest.skip(f"no firmware transcripts in {shared_data}")
    return folder


# -- the shared real-firmware recordings, through the CLI ------------------------------------
@pytest.mark.parametrize(
    ("name", "expect"),
    [
        ("ardupilot/probe", ["firmware: 4.7.0-dev", "MOT_PWM_MAX: 2000", "MOT_SPIN_ARM: 0.1"]),
        ("px4/probe", ["firmware: 1.17.0-alpha", "CA_ROTOR_COUNT: 4", "param_encoding: bytewise"]),
        ("betaflight/probe", ["firmware: 2026.12.0-alpha", "msp_api: 1.49", "board: SITL"]),
        ("betaflight/probe_after_ctrlc", ["firmware: 2026.12.0-alpha", "motors: 4"]),
    ],
)
def test_shared_probe_recordings_replay_through_the_cli(
    shared_data: Path, name: str, expect: list[str]
) -> None:
    path = transcripts(shared_data) / f"{name}.jsonl"
    result = run("probe", f"replay://{path}")
    assert result.exit_code == 0, result.output
    for text in expect:
        assert text in result.output, (text, result.output)
    assert "driver sent" not in result.output and "write-stream byte" not in result.output


def test_shared_ardupilot_spin_replays_and_verifies_the_stop(shared_data: Path) -> None:
    path = transcripts(shared_data) / "ardupilot" / "spin.jsonl"
    result = run("spin", f"replay://{path}", "--motor", "1", "--throttle", "10", "--yes")
    assert result.exit_code == 0, result.output
    assert "10.0 % (1100 us)" in result.output
    assert "stopped (verified)" in result.output
    assert "driver sent" not in result.output


def test_shared_px4_spin_replays_and_verifies_the_stop(shared_data: Path) -> None:
    # recorded as a 1 % ACTUATOR_TEST (value 0.01) on output 1 of PX4 1.17 SIH
    path = transcripts(shared_data) / "px4" / "spin_workaround.jsonl"
    result = run("spin", f"replay://{path}", "--motor", "1", "--throttle", "1", "--yes")
    assert result.exit_code == 0, result.output
    assert "stopped (verified)" in result.output
    assert "driver sent" not in result.output


def test_shared_betaflight_spin_replays(shared_data: Path) -> None:
    """This Betaflight SITL answers MSP_MOTOR with 0 for every motor, so the stop is sent and
    acknowledged but cannot be verified: the replay must say exactly that (exit 3), having
    spun at the recorded 10 % without any divergence."""
    path = transcripts(shared_data) / "betaflight" / "spin.jsonl"
    result = run("spin", f"replay://{path}", "--motor", "1", "--throttle", "10", "--yes")
    assert "10.0 % (1100 us)" in result.output, result.output
    assert "driver sent" not in result.output
    assert result.exit_code == 3 and "MSP_MOTOR reads 0" in result.output


def test_shared_recording_still_fails_byte_for_byte(shared_data: Path) -> None:
    """What changed: byte-level matching (the old replay) cannot replay them."""
    path = transcripts(shared_data) / "px4" / "probe.jsonl"
    result = run("probe", f"replay://{path}?match=bytes")
    assert "driver wrote 0x13 at write-stream byte 340, transcript has 0x10" in said(result)


def test_a_divergence_is_named_in_message_terms(shared_data: Path) -> None:
    """The recording spun motor 1; spinning motor 2 from it is a real divergence: refused in
    message terms, the run stops (the stop is in the recording) and exits 1."""
    path = transcripts(shared_data) / "ardupilot" / "spin.jsonl"
    result = run("spin", f"replay://{path}", "--motor", "2", "--throttle", "10", "--yes")
    assert "expected COMMAND_LONG 209 DO_MOTOR_TEST (1, 1, 1010, 2" in result.output
    assert "driver sent COMMAND_LONG 209 DO_MOTOR_TEST (2, 1, " in result.output
    assert result.exit_code == 1, result.output


# -- a recording made now survives a change of the driver's request order ----------------------
def test_recording_replays_after_the_driver_changes_its_request_order(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from thrustmap.rig.fc import ardupilot

    probe = tmp_path / "probe.jsonl"
    spin = tmp_path / "spin.jsonl"
    assert run("probe", f"record://sim://ardupilot?file={probe}").exit_code == 0
    recorded = run(
        "spin", f"record://sim://ardupilot?file={spin}", "--motor", "1", "--throttle", "10", "--yes"
    )
    assert recorded.exit_code == 0, recorded.output
    before = run("probe", f"replay://{probe}")
    assert before.exit_code == 0, before.output

    # the deliberate change: the driver asks for its parameters in the opposite order
    monkeypatch.setattr(ardupilot, "ARDUPILOT_PARAMS", tuple(reversed(ardupilot.ARDUPILOT_PARAMS)))
    after = run("probe", f"replay://{probe}")
    assert after.exit_code == 0, after.output
    values = [line for line in before.output.splitlines() if line.startswith("  MOT_")]
    assert values and all(line in after.output.splitlines() for line in values)
    assert "replayed by message" not in after.output  # every request answered, nothing unused
    spun = run("spin", f"replay://{spin}", "--motor", "1", "--throttle", "10", "--yes")
    assert spun.exit_code == 0, spun.output
    assert "stopped (verified)" in spun.output
    # byte for byte, the same change is a mismatch: this is what message replay adds
    strict = run("probe", f"replay://{probe}?match=bytes")
    assert "write-stream byte" in said(strict)


# -- the rules, on a small MSP recording --------------------------------------------------------
def _msp_recording(path: Path) -> None:
    with TranscriptWriter(path, inner="test", origin_s=0.0) as writer:
        t = 0.0
        for cmd, reply in (
            (MspCommand.API_VERSION, b"\x00\x01\x31"),
            (MspCommand.FC_VARIANT, b"BTFL"),
            (MspCommand.BATTERY_STATE, b"\x04" + bytes(10)),
        ):
            writer.event("w", encode_request(cmd), t)
            writer.event("r", encode_reply(cmd, reply), t + 0.01)
            t += 0.02
        motors = struct.pack("<8H", 1100, *([1000] * 7))
        writer.event("w", encode_request(MspCommand.SET_MOTOR, motors), t)
        writer.event("r", encode_reply(MspCommand.SET_MOTOR), t + 0.01)
        stop = struct.pack("<8H", *([1000] * 8))
        writer.event("w", encode_request(MspCommand.SET_MOTOR, stop), t + 0.5)
        writer.event("r", encode_reply(MspCommand.SET_MOTOR), t + 0.51)


def test_msp_requests_in_another_order_get_their_own_replies(tmp_path: Path) -> None:
    path = tmp_path / "msp.jsonl"
    _msp_recording(path)
    clock = SimClock()
    port = ReplaySerial(read_transcript(path), clock=clock, timeout=0.2)
    port.write(encode_request(MspCommand.FC_VARIANT))  # recorded second, asked first
    assert port.read(64) == encode_reply(MspCommand.FC_VARIANT, b"BTFL")
    port.write(encode_request(MspCommand.API_VERSION))
    assert port.read(64) == encode_reply(MspCommand.API_VERSION, b"\x00\x01\x31")
    # a poll the recording never saw goes unanswered (like a lossy link), and is counted
    port.write(encode_request(MspCommand.MOTOR))
    assert port.read(64) == b""
    assert "MOTOR" in port.report().unanswered
    # a motor command unlike the recorded one is a divergence, in message terms
    with pytest.raises(ReplayDivergenceError) as info:
        port.write(encode_request(MspCommand.SET_MOTOR, struct.pack("<8H", 1500, *([1000] * 7))))
    assert str(info.value).endswith(
        "expected SET_MOTOR 1100 1000 1000 1000 1000 1000 1000 1000, "
        "driver sent SET_MOTOR 1500 1000 1000 1000 1000 1000 1000 1000"
    )
    assert isinstance(info.value, ReplayMismatchError) and info.value.line == 8
    # the recorded one (within 5 % of the range), then keep-alives answered from the recording
    port.write(encode_request(MspCommand.SET_MOTOR, struct.pack("<8H", 1120, *([1000] * 7))))
    for _ in range(3):
        port.write(encode_request(MspCommand.SET_MOTOR, struct.pack("<8H", 1100, *([1000] * 7))))
    assert port.read(64) == encode_reply(MspCommand.SET_MOTOR) * 4
    port.write(encode_request(MspCommand.SET_MOTOR, struct.pack("<8H", *([1000] * 8))))
    assert port.read(64) == encode_reply(MspCommand.SET_MOTOR)
    report = port.report()
    assert report.match == "messages" and report.repeats == 3
    assert "BATTERY_STATE" in report.unused  # recorded, never asked


def test_a_stand_recording_still_replays_byte_for_byte(tmp_path: Path) -> None:
    path = tmp_path / "line.jsonl"
    with TranscriptWriter(path, inner="test", origin_s=0.0) as writer:
        writer.event("w", b"PING\n", 0.0)
        writer.event("r", b"PONG\n", 0.01)
    port = ReplaySerial(read_transcript(path), timeout=0.1)
    assert port.report().match == "bytes"
    with pytest.raises(ReplayMismatchError, match="write-stream byte 3"):
        port.write(b"PINX\n")
