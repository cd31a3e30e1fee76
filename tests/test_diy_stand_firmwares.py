"""Three DIY stand firmwares: einsz/whoop_thrust_stand (checked against its authors' emulator),
the MQTB TestStandv2 and avenhaus/thrust_stand (checked against their print statements only).

For each: its recording replays through the real preset and the decoded thrust, voltage,
current, rpm and throttle are what was printed; ``thrustmap probe`` identifies it from the
recording alone; its simulator prints what the recording holds; a sweep on the simulator fits
within 1 % of the simulator's truth; every way out stops the motor through the stand's own stop
(and einsz's PING watchdog stops it when thrustmap goes silent)."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from support.diy_stand_recordings import mqtb_us, truth
from support.plant_truth import ToPct, einsz_label, fit_error_vs_truth, percent_of_scale

from thrustmap.cli import cli
from thrustmap.core.clock import SimClock
from thrustmap.core.physical import G0
from thrustmap.protocols.stands.line import LineSample, LineStandDecoder, LineStandSpec
from thrustmap.protocols.stands.line_presets import identify, preset
from thrustmap.protocols.transcript import read_transcript
from thrustmap.protocols.transport import open_transport
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.devices.detect import detect_from_url
from thrustmap.rig.sim.diy_stand_peers import (
    FIRMWARE_PEERS,
    EinszWhoopPeer,
    einsz_dshot,
)
from thrustmap.rig.sim.plant import ConstantPlant
from thrustmap.rig.stand.line import STOP_TOLERANCE_PCT, LineStand, LineStandEscOutput

ROOT = Path(__file__).resolve().parent.parent
STANDS = ROOT / "fixtures" / "stands"
EINSZ_SWEEP = STANDS / "einsz-whoop" / "sweep.recorded.jsonl"
EINSZ_PROBE = STANDS / "einsz-whoop" / "probe.recorded.jsonl"
MQTB = STANDS / "mqtb-teststand" / "program_s.jsonl"
AVENHAUS = STANDS / "avenhaus-thrust-stand" / "session.jsonl"
RECORDINGS = {
    "einsz-whoop": [EINSZ_SWEEP, EINSZ_PROBE],
    "mqtb-teststand": [MQTB],
    "avenhaus-thrust-stand": [AVENHAUS],
}


def decoded(path: Path, name: str) -> list[tuple[float, LineSample]]:
    """Every row the stand sent, with the recording's time of the read that carried it."""
    spec = preset(name)
    decoder = LineStandDecoder(spec)
    if spec.header_line() is not None:  # as LineStand does: the documented column order
        decoder.feed(f"{spec.header_line()}\n".encode())
    rows: list[tuple[float, LineSample]] = []
    for event in read_transcript(path).events:
        if event.direction == "r":
            rows += [(event.time_s, s) for s in decoder.feed(event.data)]
    assert decoder.error_count == 0, list(decoder.errors)[:3]
    return rows


def writes(path: Path) -> list[tuple[float, bytes]]:
    return [(e.time_s, e.data) for e in read_transcript(path).events if e.direction == "w"]


# --------------------------------------------------------------------------- the presets


@pytest.mark.parametrize(
    ("name", "repo", "commit", "how"),
    [
        ("einsz-whoop", "einsz/whoop_thrust_stand", "f06ef557a466", "authors' emulator"),
        ("mqtb-teststand", "VirtualEnder/TestStandv2", "8521231b3d2d", "source only"),
        ("avenhaus-thrust-stand", "avenhaus/thrust_stand", "a1eb40a2b013", "source only"),
    ],
)
def test_each_preset_cites_its_firmware_and_how_it_was_checked(
    name: str, repo: str, commit: str, how: str
) -> None:
    spec = preset(name)
    assert spec.source.startswith(f"{repo}@{commit} ")
    assert how in spec.verified
    # the README beside each recording names the firmware, its commit and the file's sha256
    for path in RECORDINGS[name]:
        readme = (path.parent / "README.md").read_text(encoding="utf-8")
        assert repo in readme and commit in readme
        assert hashlib.sha256(path.read_bytes()).hexdigest() in readme, path.name


def test_the_old_notes_preset_is_renamed_generic() -> None:
    assert preset("rp2040-whoop").name == "einsz-whoop"
    generic = preset("generic-hold-csv")
    assert "generic" in generic.description and "rp2040-whoop" in generic.description
    # the real firmware's header is not the old notes' header
    assert len(preset("einsz-whoop").header_names) == 23 != len(generic.header_names)


# --------------------------------------------------------------------------- einsz (emulator)


def einsz_model(pct: float) -> dict[str, float]:
    """The authors' emulator at a steady percent (fake_stand.py Model: rpm 500 per percent,
    thrust 20 g at 50000 rpm squared, volts 4 - 0.25 n^2, amps 2.2 n^3)."""
    rpm = 500.0 * pct
    n = rpm / 50000.0
    return {"rpm": rpm, "thrust_n": 20.0 * n * n * G0 / 1000.0, "voltage_v": 4.0 - 0.25 * n * n,
            "current_a": 2.2 * n**3}  # fmt: skip


def test_einsz_emulator_recording_decodes_to_the_emulators_model() -> None:
    rows = [s for _, s in decoded(EINSZ_SWEEP, "einsz-whoop")]
    assert len(rows) >= 100
    steady = 0
    for i in range(6, len(rows)):
        window = rows[i - 6 : i + 1]
        if len({s.throttle for s in window}) != 1 or not rows[i].throttle:
            continue  # 0.6 s at one throttle: the emulator's rotor (tau 45 ms) has settled
        s, want = rows[i], einsz_model(float(rows[i].throttle or 0))
        assert s.rpm == pytest.approx(want["rpm"], rel=0.005)  # the DShot period encoding
        assert s.thrust_n == pytest.approx(want["thrust_n"], abs=0.03 * G0 / 1000)  # ±0.02 g
        assert s.voltage_v == pytest.approx(want["voltage_v"], abs=0.002)
        assert s.current_a == pytest.approx(want["current_a"], abs=2e-5)
        steady += 1
    assert steady >= 20
    levels = {s.throttle for s in rows}
    assert {10.0, 20.0, 30.0, 40.0} <= levels
    times = [s.time_s for s in rows if s.time_s is not None]
    assert np.median(np.diff(times)) == pytest.approx(0.1, abs=0.01)  # PRINT_IDLE_US


def test_einsz_emulator_took_the_commands_and_stopped_on_stop() -> None:
    spec = preset("einsz-whoop")
    sent = writes(EINSZ_SWEEP)
    lines = [(t, d.decode().strip()) for t, d in sent]
    assert lines[-1][1] == "STOP"
    pings = [t for t, text in lines if text == "PING"]
    gaps = np.diff([0.0, *(t for t, _ in lines)])  # any line feeds the firmware's watchdog
    assert len(pings) >= 20 and gaps.max() < 0.5  # the 1 s watchdog was always fed
    asked = [spec.parse_command(text) for _, text in lines if text not in ("PING", "STOP")]
    assert max(a for a in asked if a is not None) == 40.0
    last_throttle = max(i for i, (_, text) in enumerate(lines) if text not in ("PING", "STOP"))
    stop_t = next(t for t, text in lines[last_throttle:] if text == "STOP")
    assert all(text in ("PING", "STOP") for t, text in lines if t >= stop_t)
    after = [(t, s) for t, s in decoded(EINSZ_SWEEP, "einsz-whoop") if t > stop_t]
    assert after and after[0][1].throttle == 0.0 and after[0][0] - stop_t < 0.25


def test_einsz_probe_recording_replays_through_the_cli() -> None:
    result = CliRunner().invoke(cli, ["probe", f"replay://{EINSZ_PROBE}", "--seconds", "1"])
    assert result.exit_code == 0, result.output
    assert "einsz-whoop prints them" in result.output
    assert "spec: einsz-whoop" in result.output
    assert "mean voltage: 4 V" in result.output
    assert "authors' emulator" in result.output


# --------------------------------------------------------------------------- MQTB, avenhaus


def test_mqtb_rows_are_what_its_print_statements_printed() -> None:
    rows = [s for _, s in decoded(MQTB, "mqtb-teststand")]
    assert len(rows) == 751  # 3 s of 4 ms rows
    for s in rows:
        assert s.time_s is not None and s.throttle == mqtb_us(int(round(s.time_s * 1e6)))
        v = truth((s.throttle - 1000) / 1000)
        assert s.thrust_n == pytest.approx(int(v["thrust_g"]) * G0 / 1000, abs=1e-12)
        assert s.rpm == int(v["rpm"])
        assert s.voltage_v == pytest.approx(v["voltage_v"], abs=0.0051)
        assert s.current_a == pytest.approx(v["current_a"], abs=0.0051)
    assert rows[-1].throttle == 1175  # 1 s into the 12 s ramp to 2000 µs


def test_avenhaus_rows_are_what_its_print_statements_printed() -> None:
    rows = [s for _, s in decoded(AVENHAUS, "avenhaus-thrust-stand")]
    assert len(rows) == 139  # one live row per 100 ms; the summaries and the block are text
    for s in rows:
        assert s.throttle is not None and s.time_s is None
        v = truth(s.throttle / 100.0)
        assert s.thrust_n == pytest.approx(v["thrust_g"] * G0 / 1000, abs=0.0051 * G0 / 1000)
        assert s.torque_nm == pytest.approx(v["torque_g_cm"] * G0 / 1e5, abs=0.0051 * G0 / 1e5)
        assert s.voltage_v == pytest.approx(v["voltage_v"], abs=0.0051)
        assert s.current_a == pytest.approx(v["current_a"], abs=0.00051)
        assert s.rpm == pytest.approx(v["rpm"], abs=0.0051)
    assert max(s.throttle or 0 for s in rows) == 30.0


# --------------------------------------------------------------------------- probe


@pytest.mark.parametrize(
    ("name", "path"), [(n, p) for n, paths in RECORDINGS.items() for p in paths]
)
def test_probe_identifies_each_stand_from_its_recording_alone(name: str, path: Path) -> None:
    found = detect_from_url(f"replay://{path}")
    assert found is not None and found.kind == "line-stand"
    assert found.line_preset == name
    text = read_transcript(path).read().decode("latin-1")
    lines = [ln.strip() for ln in re.split(r"[\r\n]+", text)][1:-1]
    assert [s.name for s in identify([ln for ln in lines if ln])] == [name]


# --------------------------------------------------------------------------- simulators


def sim_lines(name: str, script: list[tuple[float, bytes]], until_s: float) -> list[str]:
    peer = FIRMWARE_PEERS[name](ConstantPlant(1), preset(name))
    out = b""
    for t, data in script:
        out += peer.read(t)
        peer.write(data, t)
    out += peer.read(until_s)
    return [ln.strip() for ln in re.split(r"[\r\n]+", out.decode("utf-8")) if ln.strip()]


@pytest.mark.parametrize(
    ("name", "path", "script", "until_s"),
    [
        ("einsz-whoop", EINSZ_SWEEP, [(0.5, b"PING\n"), (0.6, b"30\n"), (1.5, b"STOP\n")], 2.0),
        ("mqtb-teststand", MQTB, [(0.5, b"s"), (3.5, b"e")], 4.0),
        ("avenhaus-thrust-stand", AVENHAUS, [(0.5, b"3"), (2.0, b" "), (3.0, b"s")], 9.0),
    ],
)
def test_each_simulator_prints_what_its_recording_holds(
    name: str, path: Path, script: list[tuple[float, bytes]], until_s: float
) -> None:
    spec = preset(name)
    printed = sim_lines(name, script, until_s)
    # every line the simulator prints is a line the preset knows the firmware prints ...
    assert identify(printed) == [spec]
    # ... its rows decode to the same fields as the recording's, with no bad line
    sim_rows = LineStandDecoder(spec).feed("\n".join(printed).encode() + b"\n")
    rec_rows = [s for _, s in decoded(path, name)]
    assert sim_rows and rec_rows
    fields = ("time_s", "throttle", "thrust_n", "torque_nm", "voltage_v", "current_a", "rpm")
    assert {f for f in fields if getattr(sim_rows[-1], f) is not None} == {
        f for f in fields if getattr(rec_rows[-1], f) is not None
    }
    # ... and a row has the recording's shape cell for cell (the same row pattern matches)
    row_pattern = re.compile(spec.line_patterns[0])
    assert any(row_pattern.fullmatch(ln) for ln in printed)


@pytest.mark.parametrize(
    ("name", "args", "label"),
    [
        ("einsz-whoop", ["--dwell", "2"], einsz_label),
        ("avenhaus-thrust-stand", ["--dwell", "3"], percent_of_scale),
    ],
)
def test_sweep_on_the_simulated_stand_fits_within_1pct_of_the_truth(
    tmp_path: Path, name: str, args: list[str], label: ToPct
) -> None:
    out = tmp_path / "run.csv"
    result = CliRunner().invoke(
        cli,
        ["sweep", "steps", "--stand", f"sim://line-stand?preset={name}", "--from", "10", "--to",
         "60", "--step", "10", *args, "--yes", "-q", "-o", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "stop verified" in result.output
    mean, worst, n = fit_error_vs_truth(out, "xnova-2207-6s", label)
    assert n >= 5
    assert mean < 1.0 and worst < 1.5, (mean, worst)


def test_mqtb_own_program_on_the_simulator_fits_within_1pct_of_the_truth(tmp_path: Path) -> None:
    out = tmp_path / "run.csv"
    result = CliRunner().invoke(
        cli,
        # its program runs the simulated motor to 40,003 rpm: above the 40,000 rpm default
        # limit (a tripped limit stops it), so the rig's own ceiling is given
        ["stand", "run", "sim://line-stand?preset=mqtb-teststand", "--line-preset",
         "mqtb-teststand", "--yes", "--max-rpm", "60000", "-o", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    meta = json.loads(out.with_suffix(".meta.json").read_text())
    assert meta["outcome"]["status"] == "completed" and meta["stop_verified"]
    mean, worst, n = fit_error_vs_truth(out, "xnova-2207-6s")
    assert n >= 100
    assert mean < 1.0 and worst < 1.5, (mean, worst)


# --------------------------------------------------------------------------- ways out


def test_einsz_watchdog_stops_the_motor_when_thrustmap_goes_silent() -> None:
    """serviceWatchdog(): armed by the first PING, 1 s without a line with the throttle up
    stops the motor and prints #WARN,watchdog_timeout, which the driver counts."""
    clock = SimClock()
    peer = EinszWhoopPeer(ConstantPlant(1), preset("einsz-whoop"))
    stand = LineStand(SimSerial(peer, clock), clock, preset("einsz-whoop"))
    out = LineStandEscOutput(stand)
    out.set_throttle({0: 30.0})
    for _ in range(20):  # 2 s of normal service: PING every 0.25 s keeps it fed
        clock.advance_s(0.1)
        stand.read_samples()
    assert peer.armed and peer.pct == 30 and peer.watchdog_trips == 0
    clock.advance_s(1.2)  # thrustmap hangs: nothing is sent
    stand.read_samples()
    assert peer.throttle_pct == 0.0 and peer.watchdog_trips == 1
    assert stand.watchdog_trips == 1
    assert stand.last_sample is not None and stand.last_sample.throttle == 0.0


def test_einsz_watchdog_is_not_armed_without_a_ping() -> None:
    """A person at a serial monitor is not a dead host (the firmware's own rule)."""
    peer = EinszWhoopPeer(ConstantPlant(1), preset("einsz-whoop"))
    peer.write(b"20\n", 0.0)
    peer.read(5.0)
    assert peer.pct == 20 and peer.watchdog_trips == 0
    assert peer.dshot == einsz_dshot(20) == 384


class Spy:
    def __init__(self, inner: object) -> None:
        self.inner = inner
        self.history: list[float] = []

    def write(self, data: bytes, now_s: float) -> None:
        self.inner.write(data, now_s)  # type: ignore[attr-defined]
        self.history.append(self.inner.throttle_pct)  # type: ignore[attr-defined]

    def read(self, now_s: float) -> bytes:
        data: bytes = self.inner.read(now_s)  # type: ignore[attr-defined]
        self.history.append(self.inner.throttle_pct)  # type: ignore[attr-defined]
        return data


@pytest.mark.parametrize("name", ["einsz-whoop", "avenhaus-thrust-stand"])
@pytest.mark.parametrize("action", [None, "ctrl-c", "sigterm", "exception"])
def test_every_way_out_of_a_spin_stops_the_stands_esc(
    monkeypatch: pytest.MonkeyPatch, name: str, action: str | None
) -> None:
    from test_cli_hardware import Trigger

    import thrustmap.protocols.peer as protocols_peer
    from thrustmap.protocols.urlhandlers import protocol_sim

    created: list[Spy] = []
    original = protocols_peer.create_peer

    def spy(peer_name: str, options: object = None) -> object:
        created.append(Spy(original(peer_name, options)))  # type: ignore[arg-type]
        return created[-1]

    monkeypatch.setattr(protocol_sim, "create_peer", spy)
    if action is not None:
        Trigger(monkeypatch, 1.5, action)
    result = CliRunner().invoke(
        cli,
        ["spin", f"sim://line-stand?preset={name}", "--motor", "1", "--throttle", "20",
         "--seconds", "3", "--yes"],
    )  # fmt: skip
    (stand,) = created
    assert max(stand.history) >= 19.0  # it spun ...
    assert stand.inner.throttle_pct == 0.0  # type: ignore[attr-defined]  # ... and is stopped
    assert "motor 1 stopped (verified)" in result.output
    assert result.exit_code == {None: 0, "ctrl-c": 130, "sigterm": 130, "exception": 1}[action]
    if name == "einsz-whoop":
        assert stand.inner.watchdog_trips == 0  # type: ignore[attr-defined]  # PINGs fed it


def test_mqtb_program_is_stopped_by_any_byte_and_confirmed_by_its_menu() -> None:
    """Against the recording: thrustmap starts the program ('s'), reads its rows, and on the way
    out sends 'e' (any byte ends a program); the menu printed again confirms it."""
    clock = SimClock()
    spec = preset("mqtb-teststand")
    stand = LineStand(open_transport(f"replay://{MQTB}", clock=clock, timeout=0), clock, spec)
    stand.start_sequence()
    rows = 0
    for _ in range(60):
        clock.advance_s(0.1)
        rows += len(stand.read_samples())
    assert rows == 751 and stand.sequence_running
    stand.close()  # the way out of `thrustmap stand run`, whatever the reason
    assert stand.stop_confirmation == "stop line"


def test_avenhaus_stop_is_its_space_confirmed_after_its_ramp() -> None:
    """Against the recording: '3' (30 %), a space (the ramp down, confirmed by the throttle
    column reaching 0 within stop_time_s), 's' (its own test), a space on the way out."""
    clock = SimClock()
    spec = preset("avenhaus-thrust-stand")
    port = open_transport(f"replay://{AVENHAUS}", clock=clock, timeout=0)
    stand = LineStand(port, clock, spec)
    out = LineStandEscOutput(stand)
    clock.advance_s(1.0)
    out.set_throttle({0: 35.0})  # sent as '3': never more than asked
    clock.advance_s(3.0)
    stand.read_samples()
    assert (stand.last_sample or LineSample(0, 0.0)).throttle == 30.0
    out.stop()
    assert out.verify_stopped() and out.last_verification == "throttle column"
    clock.advance_s(max(0.0, 5.5 - clock.now_s()))
    stand.start_sequence()
    clock.advance_s(10.7 - clock.now_s())
    stand.read_samples()
    stand.close()
    assert stand.stop_confirmation == "throttle column"
    report = port.report()  # type: ignore[attr-defined]
    assert report.write_bytes_remaining == 0 and report.write_bytes_matched == 4, report


def test_presets_need_their_stop_command_for_levels() -> None:
    from thrustmap.core.errors import ConfigError

    with pytest.raises(ConfigError, match="stop command"):
        LineStandSpec(
            name="x",
            columns=preset("avenhaus-thrust-stand").columns,
            delimiter="|",
            header_prefix=None,
            throttle_levels=((10.0, "1"),),
        )


def test_einsz_own_sweep_on_the_simulator_fits_within_1pct_of_the_truth(tmp_path: Path) -> None:
    """``SWEEP`` runs the firmware's own program (idle hunt, 1 % steps up and back down, 250 Hz
    rows in the last 100 ms of each): read as a recording, the throttle from its rows."""
    out = tmp_path / "run.csv"
    result = CliRunner().invoke(
        cli,
        # a whoop motor spins past the 40,000 rpm default limit (which stops it): its ceiling
        ["stand", "run", "sim://line-stand?preset=einsz-whoop", "--line-preset", "einsz-whoop",
         "--yes", "--max-rpm", "60000", "-o", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "stop verified (its end line)" in result.output
    mean, worst, n = fit_error_vs_truth(out, "xnova-2207-6s", einsz_label)
    assert n >= 100
    assert mean < 1.0 and worst < 1.5, (mean, worst)


@pytest.mark.parametrize("cause", ["stop", "watchdog"])
def test_einsz_stop_and_watchdog_abort_its_own_sweep(cause: str) -> None:
    """endSequence(): an aborted program skips the ramp, says why, and still ends with
    END_SWEEP so the host is never left waiting."""
    peer = EinszWhoopPeer(ConstantPlant(1), preset("einsz-whoop"))
    peer.write(b"PING\nSWEEP\n", 0.0)
    t = 0.0
    while t < 8.0:  # the host keeps pinging into the up leg
        t += 0.25
        peer.write(b"PING\n", t)
    assert peer.in_sequence and peer.pct > 10
    if cause == "stop":
        peer.write(b"STOP\n", 8.1)
    text = peer.read(8.2 if cause == "stop" else 10.0).decode()
    assert peer.throttle_pct == 0.0 and not peer.in_sequence
    aborted = text.index(f"#WARN,sequence_aborted,{cause}")
    assert text.index("END_SWEEP", aborted) > aborted
    ramp_rows = re.findall(r"^D,\d+,8,", text[aborted:], flags=re.M)
    assert not ramp_rows  # no logged ramp down (phase 8): the stop was at once
    if cause == "watchdog":
        assert "#WARN,watchdog_timeout" in text


@pytest.mark.parametrize("name", ["einsz-whoop", "mqtb-teststand", "avenhaus-thrust-stand"])
@pytest.mark.parametrize("action", ["ctrl-c", "sigterm", "exception"])
def test_every_way_out_of_a_stand_run_stops_the_firmwares_program(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, name: str, action: str
) -> None:
    from test_cli_hardware import Trigger

    import thrustmap.protocols.peer as thrustmap_protocols_peer
    from thrustmap.protocols.urlhandlers import protocol_sim

    created: list[Spy] = []
    original = thrustmap_protocols_peer.create_peer

    def spy(peer_name: str, options: object = None) -> object:
        created.append(Spy(original(peer_name, options)))  # type: ignore[arg-type]
        return created[-1]

    monkeypatch.setattr(protocol_sim, "create_peer", spy)
    Trigger(monkeypatch, 12.0, action)  # mid-program, the motor turning
    out = tmp_path / "run.csv"
    result = CliRunner().invoke(
        cli,
        ["stand", "run", f"sim://line-stand?preset={name}", "--line-preset", name, "--yes",
         "-o", str(out)],
    )  # fmt: skip
    (stand,) = created
    peer = stand.inner
    assert max(stand.history) > 10.0  # it was spinning when the way out came
    # stopped (an ESC does not turn within the driver's 0.5 % stop tolerance; avenhaus's own
    # ramp reaches 0 a tick later)
    assert peer.throttle_pct <= STOP_TOLERANCE_PCT  # type: ignore[attr-defined]
    meta = json.loads(out.with_suffix(".meta.json").read_text())
    assert meta["stop_verified"], meta
    assert "its stop command, confirmed" in meta["stop"]
    assert "stop verified" in result.output or action == "exception"
    assert result.exit_code == {"ctrl-c": 130, "sigterm": 130, "exception": 1}[action]


@pytest.mark.parametrize(
    ("vid", "pid", "name"), [(0x2E8A, 0x000A, "einsz-whoop"), (0x1CBE, 0x00FD, "mqtb-teststand")]
)
def test_ports_names_the_boards_these_stands_are_built_on(vid: int, pid: int, name: str) -> None:
    from types import SimpleNamespace

    from thrustmap.rig.devices.ports import describe_port

    info = SimpleNamespace(device="/dev/ttyACM0", description="", hwid="", vid=vid, pid=pid,
                           serial_number=None, manufacturer=None, product=None)  # fmt: skip
    port = describe_port(info)  # type: ignore[arg-type]
    assert name in port.guess and port.kinds == ("line-stand",)


def test_a_sweep_on_a_stand_that_runs_only_its_own_programs_is_refused(tmp_path: Path) -> None:
    """The MQTB firmware takes no throttle from the host: a sweep without an FC is refused
    before anything is sent (its own program is `thrustmap stand run`)."""
    result = CliRunner().invoke(
        cli,
        ["sweep", "steps", "--stand", "sim://line-stand?preset=mqtb-teststand", "--yes",
         "-o", str(tmp_path / "run.csv")],
    )  # fmt: skip
    from thrustmap.core.errors import ConfigError

    assert isinstance(result.exception, ConfigError), result.output  # exit 2 from the CLI
    assert "use thrustmap stand run" in str(result.exception)
    assert not (tmp_path / "run.csv").exists()
