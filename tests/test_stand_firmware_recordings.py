"""The DIY stand presets against recordings of their real firmware (compiled for the host with
tests/support/arduino_shim, fed by thrustmap's simulator; fixtures/stands/<stand>/README.md says
how), their byte-level simulators against those recordings, and their sweeps on the simulator.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.plant_truth import fit_error_vs_truth

from thrustmap.core.clock import SimClock
from thrustmap.core.errors import ConfigError
from thrustmap.core.physical import G0
from thrustmap.protocols.stands.line import LineComment, LineSample, LineStandDecoder
from thrustmap.protocols.stands.line_presets import identify, preset
from thrustmap.protocols.transcript import read_transcript
from thrustmap.protocols.urlhandlers.protocol_sim import SimSerial
from thrustmap.rig.devices.detect import detect_from_url
from thrustmap.rig.sim.physics import make_plant, true_thrust_n
from thrustmap.rig.sim.presets import preset as plant_preset
from thrustmap.rig.sim.stand_peers import LineStandPeer
from thrustmap.rig.stand.line import LineStand
from thrustmap.rig.stand.line_calibration import (
    calibration_from_counts,
    load_line_calibration,
    raw_spec,
)

ROOT = Path(__file__).resolve().parents[1]
FIX = ROOT / "fixtures" / "stands"
TINY = FIX / "tiny-thrust-stand"
VICTOR = FIX / "victorhook-thruststand"


def decode(path: Path, spec_name: str, calibration: Path | None = None, raw: bool = False):
    spec = preset(spec_name)
    if raw:
        spec = raw_spec(spec)
    elif calibration is not None:
        spec = load_line_calibration(calibration).apply(spec)
    decoder = LineStandDecoder(spec)
    events = decoder.feed_events(read_transcript(path).read())
    assert decoder.error_count == 0, [e for e in events if not isinstance(e, LineSample)][:3]
    return events


def samples_of(events) -> list[LineSample]:
    return [e for e in events if isinstance(e, LineSample)]


def shape(line: str) -> str:
    """A line with every number replaced by N: its framing."""
    return re.sub(r"-?\d+", "N", line)


def lines_of(data: bytes) -> list[str]:
    return [ln for ln in re.split(r"\r\n|\n|\r", data.decode()) if ln]


# --------------------------------------------------------------------------- tiny-thrust-stand


def test_tiny_run_replays_through_the_preset_with_the_simulators_thrust() -> None:
    assert read_transcript(TINY / "run.jsonl").written() == b"S\n"  # only its start command
    events = decode(TINY / "run.jsonl", "tiny-thrust-stand", TINY / "cal.json")
    rows = samples_of(events)
    assert [e.text for e in events if isinstance(e, LineComment)] == ["Done"]
    assert [r.throttle for r in rows] == [float(d) for d in range(0, 200, 10) for _ in range(10)]
    params = plant_preset("crazyflie-2.1")  # the plant the recording's harness ran
    for duty in range(0, 200, 10):
        level = [r for r in rows if r.throttle == duty]
        volts = np.mean([r.voltage_v for r in level])
        assert 4.0 < volts < 4.2  # a 1S pack through the 10-bit ADC (5 V / 1024)
        thrust = np.mean([r.thrust_n for r in level[5:]])
        truth = float(true_thrust_n(params, 1, duty / 255, volts))
        assert thrust == pytest.approx(truth, rel=0.03, abs=1.5e-3), duty
    currents = [np.mean([r.current_a for r in rows if r.throttle == d]) for d in (0, 100, 190)]
    assert currents[0] == pytest.approx(0.103, abs=0.01) and currents[0] < currents[1]
    assert currents[2] == pytest.approx(0.677, abs=0.02)


def test_tiny_prints_the_wrapped_16_bit_count_the_avr_prints() -> None:
    # 24-bit -83000 >> 4 is 1043388: an AVR's %d prints its low 16 bits, signed: -5188
    rows = samples_of(decode(TINY / "run.jsonl", "tiny-thrust-stand", raw=True))
    assert all(-32768 <= r.thrust_n < 32768 for r in rows)
    assert np.mean([r.thrust_n for r in rows[:10]]) == pytest.approx(-5188, abs=30)


def test_tiny_calibration_recording_finds_the_cell() -> None:
    events = decode(TINY / "calibrate.jsonl", "tiny-thrust-stand", raw=True)
    runs: list[list[float]] = [[]]
    for e in events:
        if isinstance(e, LineComment) and e.text == "Done":
            runs.append([])
        elif isinstance(e, LineSample):
            runs[-1].append(e.thrust_n)
    assert [len(r) for r in runs] == [200, 200, 0]  # two sweeps, the motor unplugged
    cal = calibration_from_counts(preset("tiny-thrust-stand"), runs[0], runs[1], 0.010)
    assert cal.counts_per_n == pytest.approx(-422.0 / G0 * 1000.0, rel=0.005)  # the harness's
    written = load_line_calibration(TINY / "cal.json")
    assert written.counts_per_n == pytest.approx(cal.counts_per_n)


def test_tiny_interrupted_on_the_real_firmware_is_reset_by_dtr_and_falls_silent() -> None:
    tr = read_transcript(TINY / "interrupted.jsonl")
    (start,) = [e for e in tr.events if e.direction == "w"]
    assert start.data == b"S\n" and start.time_s >= 2.0  # after the bootloader's wait
    notes = [(e.time_s, e.note) for e in tr.events if e.note]
    assert [n for _, n in notes] == ["dtr 0", "dtr 1"]  # the reset pulse, on the way out
    reads = [e for e in tr.events if e.direction == "r"]
    assert reads[-1].time_s < notes[0][0]  # nothing at all after the reset
    events = decode(TINY / "interrupted.jsonl", "tiny-thrust-stand", TINY / "cal.json")
    rows = samples_of(events)
    levels = sorted({r.throttle for r in rows})
    assert levels[:5] == [0.0, 10.0, 20.0, 30.0, 40.0]  # it was sweeping when stopped
    assert np.mean([r.thrust_n for r in rows if r.throttle == 40.0]) > 0.005
    assert not any(isinstance(e, LineComment) for e in events)  # no "Done": cut short


# --------------------------------------------------------------------------- victorhook


def test_victorhook_sweep_replays_through_the_preset_at_the_fcs_levels() -> None:
    tr = read_transcript(VICTOR / "sweep.jsonl")
    # a stand that drives no ESC is only ever sent the stop label
    assert set(lines_of(tr.written())) == {"1000"}
    rows = samples_of(decode(VICTOR / "sweep.jsonl", "victorhook-thruststand", VICTOR / "cal.json"))
    assert len(rows) > 3000 and all(r.throttle == 1000.0 for r in rows)  # the label echoed
    gaps = np.diff([r.time_s for r in rows])
    assert np.median(gaps) == pytest.approx(0.010, abs=1e-4)  # every 10 ms (main.cpp line 7)
    thrust = np.array([r.thrust_n for r in rows])
    # plateaus: a level held 4 s; HX711_ADC's 16-conversion average settles in 1.6 s
    params = plant_preset("xnova-2207-6s")
    levels = [float(true_thrust_n(params, 1, f, 24.7)) for f in (0.2, 0.3, 0.4, 0.5)]
    for truth in levels:
        near = thrust[np.abs(thrust - truth) < 0.1 * truth]
        assert near.size > 150, truth  # held for > 1.5 s at that thrust
        assert np.median(near) == pytest.approx(truth, rel=0.03)
    assert abs(np.median(thrust[:100])) < 0.01  # tared at rest


def test_victorhook_calibration_recording_finds_the_cell() -> None:
    rows = samples_of(decode(VICTOR / "calibrate.jsonl", "victorhook-thruststand", raw=True))
    counts = np.array([r.thrust_n for r in rows])
    cal = load_line_calibration(VICTOR / "cal.json")
    assert cal.preset == "victorhook-thruststand"
    assert cal.counts_per_n * G0 / 1000.0 == pytest.approx(-400.0, rel=0.01)  # the harness's
    assert counts.min() < cal.tare_counts + 0.2 * G0 * cal.counts_per_n * 0.9  # the 200 g seen


# --------------------------------------------------------------------------- identification


@pytest.mark.parametrize(
    ("path", "name"),
    [
        (TINY / "run.jsonl", "tiny-thrust-stand"),
        (TINY / "calibrate.jsonl", "tiny-thrust-stand"),
        (TINY / "interrupted.jsonl", "tiny-thrust-stand"),
        (VICTOR / "sweep.jsonl", "victorhook-thruststand"),
        (VICTOR / "calibrate.jsonl", "victorhook-thruststand"),
    ],
)
def test_probe_identifies_each_recording_alone(path: Path, name: str) -> None:
    found = detect_from_url(f"replay://{path}")
    assert found is not None and (found.kind, found.line_preset) == ("line-stand", name)
    lines = lines_of(read_transcript(path).read())[1:40]
    assert [s.name for s in identify(lines)] == [name]  # no other preset claims its lines


def test_probe_says_it_knows_none_and_shows_the_first_lines(tmp_path: Path) -> None:
    from thrustmap.protocols.transcript import TranscriptWriter

    path = tmp_path / "unknown.jsonl"
    writer = TranscriptWriter(path, inner="/dev/ttyUSB0", origin_s=0.0)
    writer.event("r", b"12;34;56;78\n" * 6, 0.1)
    writer.close()
    r = subprocess.run(
        [sys.executable, "-m", "thrustmap", "probe", f"replay://{path}"],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "no line-stand preset knows" in r.stderr and "'12;34;56;78'" in r.stderr
    assert "--line-preset" in r.stderr


def test_a_silent_port_names_the_stands_that_wait_for_a_start_command() -> None:
    from thrustmap.rig.devices.detect import heard_summary

    said = heard_summary({115200: bytearray()})
    assert "printed nothing" in said and "tiny-thrust-stand (waits for 'S'" in said
    assert heard_summary({115200: bytearray(b"hello\r\nworld\r\n")}).startswith(
        "at 115200 baud it printed 'hello' | 'world'"
    )


# --------------------------------------------------------------------------- the simulators


def test_simulated_tiny_prints_what_the_firmware_printed() -> None:
    recorded = lines_of(read_transcript(TINY / "run.jsonl").read())
    peer = LineStandPeer(
        make_plant("crazyflie-2.1", rotors_on_esc=1, seed=1), preset("tiny-thrust-stand")
    )
    assert peer.read(5.0) == b""  # silent until its start command, like the firmware
    peer.write(read_transcript(TINY / "run.jsonl").written(), 5.0)  # the recording's commands
    simulated = lines_of(peer.read(60.0))
    assert (
        {shape(ln) for ln in simulated} == {shape(ln) for ln in recorded} == {"N\tN\tN\tN", "Done"}
    )
    assert [ln.split("\t")[0] for ln in simulated] == [ln.split("\t")[0] for ln in recorded]
    assert peer.throttle_pct == 0.0  # duty 0 after its sweep (line 67)


def test_simulated_victorhook_prints_what_the_firmware_printed() -> None:
    recorded = lines_of(read_transcript(VICTOR / "sweep.jsonl").read())[1:]
    peer = LineStandPeer(
        make_plant("xnova-2207-6s", rotors_on_esc=1, seed=1), preset("victorhook-thruststand")
    )
    peer.write(b"1000\n", 0.0)
    simulated = lines_of(peer.read(2.0))
    assert {shape(ln) for ln in simulated} == {shape(ln) for ln in recorded} == {"N, N, N"}
    assert len(simulated) == pytest.approx(200, abs=2)  # 100 lines a second
    peer.write(b"1600\n", 2.0)  # a label only: the firmware drives no motor
    assert lines_of(peer.read(2.1))[-1].split(", ")[1] == "1600" and peer.throttle_pct == 0.0


# --------------------------------------------------------------------------- ways out


class DtrPort(SimSerial):
    """A simulated port that remembers the DTR levels set on it."""

    def __init__(self, peer: LineStandPeer, clock: SimClock) -> None:
        super().__init__(peer, clock)
        self.dtr_levels: list[bool] = []

    def _update_dtr_state(self) -> None:
        self.dtr_levels.append(bool(self.dtr))
        super()._update_dtr_state()


def test_closing_during_tinys_own_sweep_resets_the_board_and_the_motor_stops() -> None:
    from thrustmap.rig.stand.line_runs import run_sequence

    clock = SimClock()
    peer = LineStandPeer(
        make_plant("crazyflie-2.1", rotors_on_esc=1, seed=1), preset("tiny-thrust-stand")
    )
    port = DtrPort(peer, clock)
    stand = LineStand(port, clock, preset("tiny-thrust-stand"))

    spinning: list[float] = []

    def interrupt(sample: object, throttle: float) -> None:
        if throttle >= 100:
            spinning.append(peer.throttle_pct)
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt), stand:
        run_sequence(stand, 60.0, interrupt)
    assert spinning[0] > 30  # it was spinning when interrupted
    # close() ran on the way out: DTR dropped then asserted (the Pro Mini's reset)
    assert port.dtr_levels[-2:] == [False, True] and stand.resets == 1 and stand.reset_verified
    assert peer.resets == 1 and peer.throttle_pct == 0.0
    assert peer.read(clock.now_s() + 30.0) == b""  # the sweep does not resume


def test_tiny_without_dtr_says_the_sweep_runs_on(caplog: pytest.LogCaptureFixture) -> None:
    class NoDtr(SimSerial):
        def _update_dtr_state(self) -> None:
            raise OSError(25, "Inappropriate ioctl for device")  # a pseudo-terminal

    clock = SimClock()
    peer = LineStandPeer(
        make_plant("crazyflie-2.1", rotors_on_esc=1, seed=1), preset("tiny-thrust-stand")
    )
    stand = LineStand(NoDtr(peer, clock), clock, preset("tiny-thrust-stand"))
    stand.start_sequence()
    stand.close()
    assert "may still be running" in caplog.text and "cut the motor's power" in caplog.text
    assert not stand.reset_verified


def test_victorhook_cannot_be_the_esc_output_the_fc_drives_and_stops_it(tmp_path: Path) -> None:
    from thrustmap.rig.devices.opening import stand_esc_output

    clock = SimClock()
    peer = LineStandPeer(
        make_plant("xnova-2207-6s", rotors_on_esc=1, seed=1), preset("victorhook-thruststand")
    )
    stand = LineStand(SimSerial(peer, clock), clock, preset("victorhook-thruststand"))
    with pytest.raises(ConfigError, match="cannot drive an ESC"):
        stand_esc_output(stand, 0)
    stand.close()
    r = subprocess.run(
        [sys.executable, "-m", "thrustmap", "sweep", "steps", "--yes", "-q",
         "--stand", "sim://line-stand?preset=victorhook-thruststand",
         "-o", str(tmp_path / "x.csv")],
        capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    assert r.returncode == 2 and "cannot drive an ESC" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


# --------------------------------------------------------------------------- sweeps on the simulator


def thrustmap_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "thrustmap", *args], capture_output=True, text=True, cwd=ROOT
    )


def test_tinys_own_sweep_on_its_simulator_fits_within_1pct_of_the_truth(tmp_path: Path) -> None:
    out = tmp_path / "tiny.csv"
    url = "sim://line-stand?preset=tiny-thrust-stand&plant=crazyflie-2.1"
    r = thrustmap_cli(
        "stand", "run", url, "--line-preset", "tiny-thrust-stand", "-o", str(out), "--yes"
    )
    assert r.returncode == 0, r.stderr
    assert "completed: 200 rows, 20 levels; stop verified (its end line)" in r.stdout
    mean, worst, n = fit_error_vs_truth(out, "crazyflie-2.1")
    assert n >= 15 and mean < 1.0 and worst < 2.0, (mean, worst, n)
    meta = (tmp_path / "tiny.meta.json").read_text()
    assert '"status": "completed"' in meta and '"stop_verified": true' in meta


def test_victorhook_sweep_by_the_fc_on_its_simulator_fits_within_1pct(tmp_path: Path) -> None:
    out = tmp_path / "vh.csv"
    r = thrustmap_cli(
        "sweep", "steps", "--stand", "sim://line-stand?preset=victorhook-thruststand",
        "--throttle", "sim://betaflight", "--to", "60", "--step", "10", "--dwell", "2",
        "--yes", "-q", "-o", str(out),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "completed" in r.stdout and "stop verified" in r.stdout  # stopped by the FC
    mean, worst, n = fit_error_vs_truth(out, "xnova-2207-6s")
    assert n >= 5 and mean < 1.0 and worst < 2.0, (mean, worst, n)


def test_sigterm_during_tinys_own_sweep_resets_the_board_exit_130(tmp_path: Path) -> None:
    import signal
    import time

    out = tmp_path / "t.csv"
    proc = subprocess.Popen(
        [sys.executable, "-m", "thrustmap", "stand", "run", "--clock", "real", "--yes",
         "sim://line-stand?preset=tiny-thrust-stand&plant=crazyflie-2.1",
         "--line-preset", "tiny-thrust-stand", "-o", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )  # fmt: skip
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and (not out.exists() or out.read_text().count("\n") < 30):
        time.sleep(0.05)  # rows are written as they come: wait for the motor to be driven
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stdout and "stop verified (a DTR reset, then silence)" in stdout
    meta = (tmp_path / "t.meta.json").read_text()
    assert '"stop": "a DTR reset, then silence"' in meta and '"stop_verified": true' in meta


@pytest.mark.parametrize("stand", ["tiny-thrust-stand", "victorhook-thruststand"])
def test_each_recording_names_its_firmware_commit_and_the_shim_it_ran_on(stand: str) -> None:
    import hashlib
    import json

    prov = json.loads((FIX / stand / "provenance.json").read_text())
    assert (
        prov["firmware"]["commit"] in preset(stand).source
        or prov["firmware"]["commit"][:12] in preset(stand).source
    )
    shim = ROOT / "tests" / "support" / "arduino_shim"
    for name, sha in prov["shim"]["sha256"].items():
        # the shim changed since the recording: re-record (tests/support/arduino_shim/README.md)
        assert hashlib.sha256((shim / name).read_bytes()).hexdigest() == sha, name


def test_probe_of_a_serial_port_printing_the_firmwares_lines_names_its_preset() -> None:
    """A pseudo-terminal plays the real firmware's recorded output back at its own pace: probe
    finds the preset from the lines alone, and opens the stand with it."""
    import os
    import threading
    import time
    import tty

    events = [e for e in read_transcript(VICTOR / "sweep.jsonl").events if e.direction == "r"]
    master, slave = os.openpty()
    tty.setraw(slave)
    stop = threading.Event()

    def play() -> None:
        start = time.monotonic() - events[0].time_s
        for e in events:
            if stop.is_set():
                return
            time.sleep(max(0.0, e.time_s - (time.monotonic() - start)))
            os.write(master, e.data)

    player = threading.Thread(target=play, daemon=True)
    player.start()
    try:
        r = thrustmap_cli("probe", os.ttyname(slave), "--seconds", "0.5")
    finally:
        stop.set()
        player.join(5)
        os.close(master)
        os.close(slave)
    assert r.returncode == 0, r.stderr
    assert "as victorhook-thruststand prints them" in r.stdout
    assert "spec: victorhook-thruststand" in r.stdout
    rate = re.search(r"samples in [\d.]+ s at (\d+) Hz", r.stdout)
    assert rate is not None and 90 <= int(rate.group(1)) <= 110
    assert "motor: driven and stopped by the flight controller" in r.stdout


def test_sigterm_during_a_victorhook_sweep_stops_the_motor_through_the_fc(tmp_path: Path) -> None:
    import signal
    import time

    out = tmp_path / "v.csv"
    proc = subprocess.Popen(
        [sys.executable, "-m", "thrustmap", "sweep", "steps", "--realtime", "--yes", "-q",
         "--stand", "sim://line-stand?preset=victorhook-thruststand",
         "--throttle", "sim://betaflight", "--to", "40", "--dwell", "5", "-o", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (not out.exists() or out.read_text().count("\n") < 100):
        time.sleep(0.05)  # the FC is driving the motor (rows are written as they come)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 130, stderr
    assert "stop verified" in stdout
    meta = (tmp_path / "v.meta.json").read_text()
    assert '"stop_verified": true' in meta and '"status": "aborted"' in meta


def test_a_limit_tripped_in_tinys_own_sweep_resets_the_board(tmp_path: Path) -> None:
    """The firmware sets the levels of its own sweep; thrustmap still holds every row against
    the reading interlocks: a thrust past --max-thrust ends the run (exit 1) with the board
    reset and the stop verified, and the log keeps the rows up to it."""
    out = tmp_path / "tiny.csv"
    url = "sim://line-stand?preset=tiny-thrust-stand&plant=crazyflie-2.1"
    r = thrustmap_cli(
        "stand", "run", url, "--line-preset", "tiny-thrust-stand", "-o", str(out), "--yes",
        "--max-thrust", "0.05",
    )  # fmt: skip
    assert r.returncode == 1, r.stdout + r.stderr
    assert "limit tripped in its own sequence: thrust" in r.stdout + r.stderr
    assert "stop verified (a DTR reset, then silence)" in r.stdout
    meta = json.loads((tmp_path / "tiny.meta.json").read_text())
    assert meta["outcome"]["status"] == "aborted" and meta["stop_verified"]
    rows = out.read_text().splitlines()
    assert 2 < len(rows) < 200  # recorded up to the trip, not the whole sweep


def test_a_stand_silent_in_its_own_sweep_is_a_lost_link(monkeypatch: pytest.MonkeyPatch) -> None:
    """Rows came, then none for SEQUENCE_SILENT_S: the run ends (the caller's way out stops
    the motor) instead of waiting out the whole --timeout with the motor as the firmware left it."""
    from thrustmap.core.clock import SimClock
    from thrustmap.rig.stand import line_runs
    from thrustmap.rig.stand.line import LineStandTimeout

    clock = SimClock()
    rows = iter([[object()], [], [], []])

    class Sample:
        thrust_n, current_a, voltage_v, rpm = 0.1, None, None, None
        temperature_c = vibration_g = None
        throttle_native = 50.0

    class Silent:
        spec = type(
            "Spec", (), {"columns": {"throttle": 1}, "name": "fake", "sequence_end": "Done"}
        )
        sequence_ended = False
        drives_esc = False
        sequence_started = False

        def __init__(self) -> None:
            self.clock = clock

        def start_sequence(self) -> None:
            self.sequence_started = True

        def read_samples(self) -> list[Sample]:
            got = next(rows, [])
            return [Sample() for _ in got]

    monkeypatch.setattr(line_runs, "SEQUENCE_SILENT_S", 1.0)
    with pytest.raises(LineStandTimeout, match="silent for .* the link is taken as lost"):
        line_runs.run_sequence(Silent(), timeout_s=60.0)  # type: ignore[arg-type]
    assert clock.now_s() < 5.0  # ended after ~1 s of silence, not the 60 s timeout
