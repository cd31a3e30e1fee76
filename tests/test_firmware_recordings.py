"""Real ArduCopter and PX4 SITL, recorded once (fixtures/firmware/), replayed in CI (issue 42).

Each recording is the REAL firmware's side of a claim, made with tests/support/record_firmware.py
(motor-test ways out, the locked link, signing) and tests/support/sitl_flight.py (γ live), with
the firmware, version and commit, the command and the sha256 in fixtures/firmware/<fw>/MANIFEST.json.

- Spins: the real CLI (`thrustmap spin udpin:...`, a process) talks over real UDP to
  ``support.firmware_replay.ReplayPeer``, which answers each of its messages with what the firmware
  answered when recorded (thrustmap's message-level replay, on the real clock). Signals, the
  locked link and exit codes are the real ones; the firmware's answers are recorded ones.
- What the firmware did on its own (ending a test after thrustmap was killed or cut off) is read
  from the ``.monitor.tlog`` the recording took on another of the vehicle's ports.
- Signing: the firmware's signatures checked with thrustmap's signing setup; the unsigned probe
  replayed through the CLI.
- γ live: `gamma live replay://` on the flight's telemetry against `gamma fit` on the Df that
  `flightlog extract` takes from the firmware's own log of the same flight.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.firmware_replay import Intruder, ReplayPeer, is_stop

from thrustmap.protocols.mavlink import codec as mav
from thrustmap.protocols.mavlink.signing import SigningKey, sign_mavlink
from thrustmap.protocols.transcript import Transcript, read_transcript

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures" / "firmware"
FIRMWARES = ("ardupilot", "px4")
MAX_BYTES = 1_000_000
KEY = bytes(range(7, 39))  # the test key the ArduPilot signing recordings were made with
OTHER_KEY = bytes(range(101, 133))
SPIN = ["--motor", "1", "--throttle", "10", "--seconds", "6", "--ramp", "0", "--yes"]


def manifest(fw: str) -> dict[str, Any]:
    result: dict[str, Any] = json.loads((FIXTURES / fw / "MANIFEST.json").read_text())
    return result


def recording(fw: str, name: str) -> Path:
    """The fixture's path, after checking its size and sha256 against the manifest."""
    entry = {r["file"]: r for r in manifest(fw)["recording"]}[name]
    path = FIXTURES / fw / name
    data = path.read_bytes()
    assert len(data) == entry["bytes"] <= MAX_BYTES, (name, len(data))
    assert hashlib.sha256(data).hexdigest() == entry["sha256"], f"{path} changed"
    return path


def outcome(fw: str, name: str) -> dict[str, Any]:
    """What the recording run saw (exit code, output, the intruder's counts)."""
    result: dict[str, Any] = json.loads(recording(fw, name).read_text())
    return result


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def cli(*args: str, timeout_s: float = 120) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("THRUSTMAP_MAVLINK_SIGNING_KEY", None)
    return subprocess.Popen(
        [sys.executable, "-m", "thrustmap", *args], cwd=ROOT, env=env, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip


def finish(proc: subprocess.Popen[str], timeout_s: float = 90) -> tuple[int, str]:
    try:
        out, err = proc.communicate(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, out + err


# ------------------------------------------------------------------------------------------
# the recordings themselves
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("fw", FIRMWARES)
def test_every_recording_is_in_the_manifest_with_its_hash(fw: str) -> None:
    entries = manifest(fw)["recording"]
    names = sorted(p.name for p in (FIXTURES / fw).iterdir() if p.is_file())
    assert sorted([r["file"] for r in entries] + ["MANIFEST.json", "README.md"]) == names
    info = manifest(fw)["firmware"]
    assert info["name"] and info["version"] and len(info["commit"]) == 40
    for entry in entries:
        recording(fw, entry["file"])
        assert entry["command"].startswith("python -m support."), entry


# ------------------------------------------------------------------------------------------
# monitor logs: the vehicle's outputs as it reported them on another port
# ------------------------------------------------------------------------------------------
def monitor_log(fw: str, name: str) -> list[tuple[float, Any]]:
    """(time s, message) of a .monitor.tlog, decoded by thrustmap's codec."""
    data = recording(fw, name).read_bytes()
    codec = mav.MavlinkCodec()
    out: list[tuple[float, Any]] = []
    pos = 0
    while pos + 8 < len(data):
        stamp = int.from_bytes(data[pos : pos + 8], "big") / 1e6
        length = (data[pos + 9] + 12) if data[pos + 8] == 0xFD else (data[pos + 9] + 8)
        if data[pos + 8] == 0xFD and data[pos + 10] & 1:
            length += 13
        out += [(stamp, m) for m in codec.feed(data[pos + 8 : pos + 8 + length])]
        pos += 8 + length
    return out


def outputs(log: list[tuple[float, Any]]) -> list[tuple[float, int]]:
    return [
        (t, max(getattr(m, f"servo{i}_raw") for i in range(1, 5)))
        for t, m in log
        if m.get_type() == "SERVO_OUTPUT_RAW" and m.port == 0
    ]


def armed_times(log: list[tuple[float, Any]]) -> list[tuple[float, bool]]:
    return [
        (t, bool(m.base_mode & 128))
        for t, m in log
        if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1
    ]


def firmware_ended_the_test(fw: str, name: str) -> float | None:
    """Asserts the motor turned, came back to the idle output and the vehicle ended disarmed;
    returns the seconds from the recording's signal or cut to the first idle output (None when
    the spin ran to its end)."""
    run = outcome(fw, name.replace(".monitor.tlog", ".json"))
    idle = run["idle_us"]
    log = monitor_log(fw, name)
    outs = outputs(log)
    high = [t for t, us in outs if us > idle + 20]
    assert high, f"{name}: the motor never turned: {outs[:5]}"
    after = [(t, us) for t, us in outs if t > high[-1]]
    assert after and all(us <= idle for _, us in after), f"{name}: not back at idle {after[-5:]}"
    assert armed_times(log)[-1][1] is False, f"{name}: still armed at the end"
    if "acted_unix_s" not in run:
        return None
    return float(after[0][0] - run["acted_unix_s"])


# ------------------------------------------------------------------------------------------
# motor-test ways out, the real CLI against the recorded firmware
# ------------------------------------------------------------------------------------------
def spin_against(fw: str, name: str, act: Any) -> tuple[int, str, ReplayPeer]:
    """`thrustmap spin udpin:` against the recorded firmware; ``act(proc, peer)`` once the
    motor command went out (None: let it end)."""
    port = free_udp_port()
    transcript = read_transcript(str(recording(fw, f"{name}.jsonl")))
    proc = cli("spin", f"udpin:127.0.0.1:{port}", *SPIN)
    peer = ReplayPeer(transcript, port)
    try:
        if act is not None:
            peer.wait_for_run()
            time.sleep(1.0)
            act(proc, peer)
        code, text = finish(proc)
    finally:
        peer.close()
    return code, text, peer


def last_is_stop(peer: ReplayPeer) -> bool:
    cmds = peer.motor_commands()
    return bool(cmds) and is_stop(cmds[-1])


@pytest.mark.parametrize("fw", FIRMWARES)
def test_spin_to_its_end_stops_verified(fw: str) -> None:
    code, text, peer = spin_against(fw, "spin", None)
    assert code == 0, text
    assert "stopped (verified)" in text
    assert last_is_stop(peer)
    assert outcome(fw, "spin.json")["exit"] == 0
    firmware_ended_the_test(fw, "spin.monitor.tlog")


@pytest.mark.parametrize("way", ["sigint", "sigterm"])
@pytest.mark.parametrize("fw", FIRMWARES)
def test_spin_interrupted_stops_verified(fw: str, way: str) -> None:
    sig = signal.SIGINT if way == "sigint" else signal.SIGTERM
    code, text, peer = spin_against(fw, f"spin_{way}", lambda p, _: p.send_signal(sig))
    assert code == 130, text
    assert "stopped (verified)" in text
    assert last_is_stop(peer)
    assert outcome(fw, f"spin_{way}.json")["exit"] == 130
    firmware_ended_the_test(fw, f"spin_{way}.monitor.tlog")


def run_timeouts_s(fw: str, peer: ReplayPeer) -> list[float]:
    """The timeout each motor RUN command asked the firmware for (ArduPilot DO_MOTOR_TEST
    param4, PX4 ACTUATOR_TEST param2): the firmware ends the test by itself after it."""
    index = 3 if fw == "ardupilot" else 1
    return [c.params[index] for c in peer.motor_commands() if not is_stop(c)]


@pytest.mark.parametrize("way", ["sigkill", "lostlink"])
@pytest.mark.parametrize("fw", FIRMWARES)
def test_spin_cut_off_the_firmware_ends_the_test_itself(fw: str, way: str) -> None:
    """thrustmap killed, or its link cut: no stop can reach the vehicle, so each run command
    carries a short timeout; the recorded firmware ended its test within it."""
    if way == "sigkill":
        code, text, peer = spin_against(fw, "spin_sigkill", lambda p, _: p.kill())
        assert code == -signal.SIGKILL
    else:
        code, text, peer = spin_against(fw, "spin_lostlink", lambda _, q: q.go_silent())
        assert code == outcome(fw, "spin_lostlink.json")["exit"] == 3, text
        assert "NOT verified" in text
    timeouts = run_timeouts_s(fw, peer)
    assert timeouts and all(0 < t <= 3.0 for t in timeouts), timeouts
    took_s = firmware_ended_the_test(fw, f"spin_{way}.monitor.tlog")
    assert took_s is not None and took_s <= max(timeouts) + 1.0, (took_s, timeouts)


@pytest.mark.parametrize(
    ("fw", "name"),
    [("ardupilot", "spin_intruder"), ("px4", "spin_intruder")],
)
def test_locked_link_refuses_a_second_sender(fw: str, name: str) -> None:
    """The second sender's bytes answered 0, the spin stopped (verified), exit 1 naming it."""
    intruders: list[Intruder] = []

    def intrude(_: Any, peer: ReplayPeer) -> None:
        intruders.append(Intruder(peer.port))
        intruders[0].start()

    try:
        code, text, peer = spin_against(fw, name, intrude)
    finally:
        for one in intruders:
            one.close()
    intruder = intruders[0]
    assert intruder.sent > 0
    assert code == 1, text
    assert f"{intruder.address} sent to the vehicle link" in text
    assert intruder.received == 0, text
    assert "stopped (verified)" in text and last_is_stop(peer)
    recorded = outcome(fw, f"{name}.json")
    assert recorded["intruder_received"] == 0 and recorded["intruder_sent"] > 0
    assert recorded["exit"] == 1
    assert f"{recorded['intruder']} sent to the vehicle link" in recorded["stderr"]
    firmware_ended_the_test(fw, f"{name}.monitor.tlog")


# ------------------------------------------------------------------------------------------
# signing
# ------------------------------------------------------------------------------------------
def fc_frames(transcript: Transcript, key: bytes | None) -> tuple[list[Any], Any]:
    """The firmware's side parsed by pymavlink with thrustmap's signing setup (``key``)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    if key is not None:
        sign_mavlink(parser, SigningKey(key), timestamp=0)
        parser.signing.sign_outgoing = False
    msgs = parser.parse_buffer(transcript.read()) or []
    return [m for m in msgs if m.get_type() != "BAD_DATA"], parser.signing


def test_ardupilot_signed_probe_accepted() -> None:
    """thrustmap's signed requests were answered; every firmware message verifies with the key
    under thrustmap's signing setup, and none with another key."""
    transcript = read_transcript(str(recording("ardupilot", "probe_signed.jsonl")))
    msgs, signing = fc_frames(transcript, KEY)
    assert signing.goodsig_count == signing.sig_count >= 20 and signing.badsig_count == 0
    kinds = {m.get_type() for m in msgs}
    assert {"AUTOPILOT_VERSION", "PARAM_VALUE", "HEARTBEAT"} <= kinds, kinds
    wrong, other = fc_frames(transcript, OTHER_KEY)
    assert other.goodsig_count == 0 and not [m for m in wrong if m.get_type() == "PARAM_VALUE"]
    sent = _raw_frames(transcript.written())
    assert sent and all(f[2] & 1 for f in sent), "thrustmap sent an unsigned message"
    assert outcome("ardupilot", "probe_signed.json")["exit"] == 0


def _raw_frames(data: bytes) -> list[bytes]:
    from thrustmap.protocols.urlhandlers.transcript_messages import MavlinkProtocol

    frames, _ = MavlinkProtocol().split(data)
    return frames


def test_ardupilot_unsigned_probe_refused_replayed_through_the_cli() -> None:
    path = recording("ardupilot", "probe_unsigned.jsonl")
    transcript = read_transcript(str(path))
    msgs, _ = fc_frames(transcript, None)
    kinds = {m.get_type() for m in msgs}
    assert "HEARTBEAT" in kinds and not {"AUTOPILOT_VERSION", "PARAM_VALUE"} & kinds, kinds
    assert all(f[2] & 1 for f in _raw_frames(transcript.read())), "the firmware sent unsigned"
    code, text = finish(cli("probe", f"replay://{path}"))
    lines = text.strip().splitlines()
    assert code == 2 and len(lines) == 1, text
    assert "the vehicle requires signed MAVLink: pass --signing-key" in lines[0]


def test_px4_probe_replayed_with_and_without_a_key() -> None:
    """PX4 v1.17-alpha has no MAVLink signing: its probe replays; with a key thrustmap refuses
    its unsigned messages in one line (exit 2) and never prints the key."""
    path = recording("px4", "probe.jsonl")
    code, text = finish(cli("probe", f"replay://{path}"))
    assert code == 0 and "px4" in text, text
    code, text = finish(cli("probe", f"replay://{path}", "--signing-key", KEY.hex()))
    lines = [ln for ln in text.strip().splitlines() if not ln.startswith("warning: replay ")]
    assert code == 2 and len(lines) == 1 and "unsigned MAVLink message(s)" in lines[0], text
    assert KEY.hex() not in text


# ------------------------------------------------------------------------------------------
# γ live on a flown hover
# ------------------------------------------------------------------------------------------
def gamma_of(path: Path) -> tuple[list[float], list[float]]:
    corr = json.loads(path.read_text())["correction"]
    return corr["coefficients"], corr["voltage_v"]


@pytest.mark.parametrize("fw", FIRMWARES)
def test_gamma_live_matches_gamma_fit_on_the_firmwares_own_log(fw: str, tmp_path: Path) -> None:
    info = manifest(fw)["flight"]
    tmap = recording(fw, "flight.map.json")
    tlog = recording(fw, "flight.tlog")
    mass = str(info["mass_kg"])
    runs = [
        ("gamma", "live", f"replay://{tlog}", "--map", str(tmap), "--mass-kg", mass,
         "-o", str(tmp_path / "live.json"), "--no-panel"),
    ]  # fmt: skip
    if info["log"]:  # the firmware's own log, trimmed: extract runs here
        log_df = tmp_path / "log.csv"
        runs.append(
            ("flightlog", "extract", str(recording(fw, info["log"])), "--map", str(tmap),
             "--mass-kg", mass, "-o", str(log_df))
        )  # fmt: skip
    else:  # the Df extract took from the whole log (too large to commit, even trimmed)
        log_df = recording(fw, info["log_df"])
        recording(fw, info["log_df"].replace(".csv", ".json"))
    runs.append(
        ("gamma", "fit", str(log_df), "--map", str(tmap), "-o", str(tmp_path / "logfit.json"))
    )
    for args in runs:
        code, text = finish(cli(*args))
        assert code == 0, (args, text)
    (g_live, v_live), (g_log, v_log) = (
        gamma_of(tmp_path / "live.json"),
        gamma_of(tmp_path / "logfit.json"),
    )
    lo, hi = max(v_live[0], v_log[0]), min(v_live[1], v_log[1])
    assert hi - lo >= info["min_voltage_span_v"], (v_live, v_log)
    b = np.linspace(lo, hi, 41)
    live = np.polynomial.polynomial.polyval(b, g_live)
    fit = np.polynomial.polynomial.polyval(b, g_log)
    rel = float(np.max(np.abs(live / fit - 1)))
    print(f"{fw}: gamma live {g_live} vs gamma fit on the firmware's log {g_log}: {rel:.3%}")
    assert math.isfinite(rel) and rel <= info["gamma_tolerance"], (rel, g_live, g_log)
    assert np.all(np.abs(live - 1) > 0.005), "γ corrects nothing: the check would be empty"
