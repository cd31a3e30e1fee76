"""The Tyto Flight Stand through its official Python API (issue 32), against the simulated core.

The core (``thrustmap.rig.sim.flightstand_core``, served by ``flightstand_service``) serves the
official package's gRPC service on loopback; thrustmap's sweeps run as the user runs them
(``python -m thrustmap``, real time), and what the ESC output does is read back through the
official package's own client stub. The official examples ``example.py`` and
``data_recording.py`` run unmodified against it.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from support.plant_truth import fit_error_vs_truth

fs = pytest.importorskip("FlightStand.flight_stand_api_v1_pb2")
fs_grpc = pytest.importorskip("FlightStand.flight_stand_api_v1_pb2_grpc")
grpc = pytest.importorskip("grpc")

from thrustmap.rig.sim.flightstand_core import FlightStandCore  # noqa: E402
from thrustmap.rig.sim.flightstand_service import FlightStandServer  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
PLANT = "xnova-2207-6s"


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.fixture
def core() -> Iterator[FlightStandServer]:
    server = FlightStandServer(FlightStandCore(plant=PLANT, seed=3), port=0).start()
    try:
        yield server
    finally:
        server.stop()


def official(address: str) -> Any:
    """The official package's client stub (what a Tyto user's script talks through)."""
    return fs_grpc.FlightStandStub(grpc.insecure_channel(address))


def esc_state(stub: Any) -> tuple[bool, float]:
    """The ESC output signal's latest sample, read through the official client: (active, µs)."""
    esc = stub.ListOutputs(fs.ListOutputsRequest(), timeout=2).outputs[0]
    for sample in stub.ListSamples(fs.ListSamplesRequest(), timeout=2).sample_group.samples:
        if sample.signal_name == esc.signal_name:
            return sample.active, sample.value
    raise AssertionError("no sample of the ESC output signal")


def cutoff_of(stub: Any) -> str | None:
    core = stub.GetCore(fs.GetCoreRequest(), timeout=2)
    if not core.HasField("cutoff_active"):
        return None
    return str(fs.CutoffConditionType.Name(core.cutoff_active.type))


def thrustmap(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "thrustmap", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=_env(),
        cwd=ROOT,
    )


def start_sweep(url: str, out: Path, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "thrustmap",
            "sweep",
            *extra,
            "--stand",
            url,
            "--motor",
            "1",
            "-o",
            str(out),
            "-y",
            "-q",
        ],  # fmt: skip
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
        cwd=ROOT,
    )


def wait_spinning(stub: Any, proc: subprocess.Popen[str], above_us: float = 1200.0) -> None:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        active, value = esc_state(stub)
        if active and value > above_us:
            return
        time.sleep(0.05)
    proc.kill()
    raise AssertionError(f"the sweep never drove the ESC above {above_us} µs")


# --------------------------------------------------------------------------- probe, sweep, fit


def test_probe_names_the_board_its_sensors_and_how_it_was_checked(core: FlightStandServer) -> None:
    r = thrustmap("probe", f"flightstand://{core.address}")
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "board: Flight Stand 50 (simulated 1)" in out
    for sensor in ("FORCE_FZ", "TORQUE_MZ", "VOLTAGE_HV_INPUT", "CURRENT_HALL_CURRENT"):
        assert sensor in out
    assert "protocol_checked: against Tyto's official client" in out
    # the stand was read: thrust at rest near zero, the battery's voltage
    assert "samples in" in out and "mean voltage: 2" in out


def test_probe_of_the_1585_says_it_was_written_from_documentation() -> None:
    r = thrustmap("probe", "sim://tyto-1585")
    assert r.returncode == 0, r.stderr
    assert "protocol_checked: written from documentation only" in r.stdout


@pytest.mark.parametrize("kind", ["steps", "adaptive"])
def test_sweep_without_throttle_fits_within_1pct_of_the_truth(
    core: FlightStandServer, tmp_path: Path, kind: str
) -> None:
    out = tmp_path / "run.csv"
    extra = ["--to", "60", "--dwell", "2"] + (["--step", "10"] if kind == "steps" else [])
    proc = start_sweep(f"flightstand://{core.address}", out, kind, *extra)
    stdout, stderr = proc.communicate(timeout=180)
    assert proc.returncode == 0, stderr + stdout
    assert "completed" in stdout and "stop verified" in stdout
    mean, worst, n = fit_error_vs_truth(out, PLANT)
    assert n >= 5
    assert mean < 1.0 and worst < 2.0, (mean, worst)
    # the CLI's own fit reads the file too
    r = thrustmap("fit", str(out), "-o", str(tmp_path / "map.json"))
    assert r.returncode == 0, r.stderr
    # left behind: the output off and no cutoff
    stub = official(core.address)
    assert esc_state(stub)[0] is False
    assert cutoff_of(stub) is None


# --------------------------------------------------------------------------- every way out


def test_sigkill_the_cores_heartbeat_cutoff_stops_the_esc_within_3s(
    core: FlightStandServer, tmp_path: Path
) -> None:
    stub = official(core.address)
    proc = start_sweep(f"flightstand://{core.address}", tmp_path / "k.csv", "explicit",
                       "--levels", "40", "--dwell", "60")  # fmt: skip
    wait_spinning(stub, proc)
    proc.kill()
    killed = time.monotonic()
    proc.communicate(timeout=10)
    while True:
        active, value = esc_state(stub)
        if value <= 1000.0:
            break
        assert time.monotonic() - killed < 3.0, "the ESC output was still driven 3 s after SIGKILL"
        time.sleep(0.02)
    took = time.monotonic() - killed
    assert cutoff_of(stub) == "NO_CLIENT"
    # the recording is kept up to the kill
    assert (tmp_path / "k.csv").stat().st_size > 100
    print(f"ESC at {value:g} µs {took:.2f} s after SIGKILL")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_and_sigterm_stop_within_1s_verified(
    core: FlightStandServer, tmp_path: Path, signum: int
) -> None:
    stub = official(core.address)
    proc = start_sweep(f"flightstand://{core.address}", tmp_path / "s.csv", "explicit",
                       "--levels", "40", "--dwell", "60")  # fmt: skip
    wait_spinning(stub, proc)
    proc.send_signal(signum)
    sent = time.monotonic()
    stopped_at = None
    while proc.poll() is None or stopped_at is None:
        if stopped_at is None and esc_state(stub)[1] <= 1000.0:
            stopped_at = time.monotonic() - sent
        assert time.monotonic() - sent < 10
        time.sleep(0.01)
    exited = time.monotonic() - sent
    stdout, stderr = proc.communicate()
    print(
        f"{signal.Signals(signum).name}: ESC at the stop {stopped_at} s after the signal, "
        f"the process ended {exited:.2f} s after it"
    )
    assert stopped_at is not None and stopped_at < 1.0, stopped_at
    assert proc.returncode == 130, stderr + stdout
    assert "stop verified" in stdout, stdout
    assert cutoff_of(stub) is None  # a clean stop, not the core's cutoff
    assert esc_state(stub)[0] is False  # and the signal switched off after it


def test_a_cutoff_tripped_in_the_core_aborts_the_sweep_naming_it(
    core: FlightStandServer, tmp_path: Path
) -> None:
    stub = official(core.address)
    thrust = next(i for i in stub.ListInputs(fs.ListInputsRequest()).inputs
                  if i.input_type == fs.FORCE_FZ)  # fmt: skip
    # the stand's own limit, set as a Tyto user would: 2 N, below thrustmap's --max-thrust
    from google.protobuf.field_mask_pb2 import FieldMask

    stub.UpdateInput(fs.UpdateInputRequest(
        input=fs.Input(name=thrust.name, max_user_cutoff=2.0, has_max_user_cutoff=True),
        mask=FieldMask(paths=["max_user_cutoff", "has_max_user_cutoff"])))  # fmt: skip
    proc = start_sweep(f"flightstand://{core.address}", tmp_path / "c.csv", "stairs-up",
                       "--from", "10", "--to", "60", "--step", "10", "--dwell", "1.5")  # fmt: skip
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 1, stderr + stdout
    assert "aborted" in stdout and "stop verified" in stdout
    assert "OUT_OF_RANGE_SIGNAL: Thrust" in stdout and "above its cutoff 2" in stdout, stdout
    # thrustmap never clears the core's cutoff; the ESC is at the cutoff target
    assert cutoff_of(stub) == "OUT_OF_RANGE_SIGNAL"
    assert esc_state(stub)[1] <= 1000.0
    # the stand's own (lower) limit is left as the user set it
    again = stub.GetInput(fs.GetInputRequest(name=thrust.name))
    assert again.has_max_user_cutoff and again.max_user_cutoff == pytest.approx(2.0)


def test_a_thrust_input_reading_a_pulling_propeller_negative_is_questioned(
    core: FlightStandServer, tmp_path: Path
) -> None:
    from google.protobuf.field_mask_pb2 import FieldMask

    stub = official(core.address)
    thrust = next(i for i in stub.ListInputs(fs.ListInputsRequest()).inputs
                  if i.input_type == fs.FORCE_FZ)  # fmt: skip
    stub.UpdateInput(fs.UpdateInputRequest(input=fs.Input(name=thrust.name, reversed=True),
                                           mask=FieldMask(paths=["reversed"])))  # fmt: skip
    proc = start_sweep(f"flightstand://{core.address}", tmp_path / "n.csv", "explicit",
                       "--levels", "30,40", "--dwell", "3")  # fmt: skip
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 1, stderr + stdout
    assert "aborted" in stdout and "stop verified" in stdout
    assert "thrust input reads -" in stdout and "reverse the thrust input" in stdout, stdout


def test_thrustmaps_limits_are_the_cores_cutoffs_during_the_run_and_restored_after(
    core: FlightStandServer, tmp_path: Path
) -> None:
    stub = official(core.address)
    proc = start_sweep(f"flightstand://{core.address}", tmp_path / "l.csv", "explicit",
                       "--levels", "20", "--dwell", "2", "--max-thrust", "15",
                       "--max-current", "30")  # fmt: skip
    wait_spinning(stub, proc, above_us=1100.0)
    seen = {
        fs.InputType.Name(i.input_type): i for i in stub.ListInputs(fs.ListInputsRequest()).inputs
    }
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr + stdout
    assert seen["FORCE_FZ"].has_max_user_cutoff and seen["FORCE_FZ"].max_user_cutoff == 15.0
    assert seen["CURRENT_HALL_CURRENT"].max_user_cutoff == 30.0
    assert seen["TEMPERATURE_PROBE"].has_max_user_cutoff
    after = {
        fs.InputType.Name(i.input_type): i for i in stub.ListInputs(fs.ListInputsRequest()).inputs
    }
    assert not after["FORCE_FZ"].has_max_user_cutoff
    assert not after["CURRENT_HALL_CURRENT"].has_max_user_cutoff


class FreezableProxy:
    """A loopback TCP forwarder between thrustmap and the core; ``freeze()`` stops forwarding
    and keeps the sockets open: a link that goes silent (a cable, a hung network)."""

    def __init__(self, upstream: tuple[str, int]) -> None:
        self.upstream = upstream
        self.frozen = threading.Event()
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.sockets: list[socket.socket] = [self.listener]
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            server = socket.create_connection(self.upstream)
            self.sockets += [client, server]
            for a, b in ((client, server), (server, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        while not self.frozen.is_set():
            try:
                data = src.recv(65536)
                if not data:
                    return
                if self.frozen.is_set():
                    return
                dst.sendall(data)
            except OSError:
                return

    def freeze(self) -> None:
        self.frozen.set()

    def close(self) -> None:
        for sock in self.sockets:
            sock.close()


def test_a_lost_link_aborts_within_the_link_timeout_and_the_core_stops_the_esc(
    core: FlightStandServer, tmp_path: Path
) -> None:
    stub = official(core.address)  # straight to the core, not through the link that is cut
    proxy = FreezableProxy(("127.0.0.1", core.port))
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "thrustmap", "-v", "sweep", "explicit", "--levels", "30",
             "--dwell", "60", "--link-timeout", "1.0", "--stand",
             f"flightstand://127.0.0.1:{proxy.port}", "-o", str(tmp_path / "x.csv"), "-y", "-q"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(), cwd=ROOT,
        )  # fmt: skip
        lines: list[tuple[float, str]] = []

        def read() -> None:
            assert proc.stderr is not None
            for line in proc.stderr:
                lines.append((time.monotonic(), line))

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        wait_spinning(stub, proc)
        proxy.freeze()
        lost = time.monotonic()
        esc_zero_s = None
        while esc_zero_s is None and time.monotonic() - lost < 5:
            if esc_state(stub)[1] <= 1000.0:
                esc_zero_s = time.monotonic() - lost
            time.sleep(0.02)
        stdout = proc.stdout.read() if proc.stdout else ""
        proc.wait(timeout=60)
        reader.join(timeout=5)
    finally:
        proxy.close()
    print(
        f"link frozen: the core's cutoff at {esc_zero_s} s; thrustmap aborting after {[t - lost for t, ln in lines if 'aborting:' in ln][:1]} s"
    )
    # the core cut the ESC off on the missing heartbeat, within its 1 s (+ one sample)
    assert esc_zero_s is not None and esc_zero_s < 3.0, esc_zero_s
    assert cutoff_of(stub) == "NO_CLIENT"
    # thrustmap decided to abort within the link timeout (1 s; stale stand data is 0.5 s)
    aborting = [(t - lost, line) for t, line in lines if "aborting:" in line]
    assert aborting, (stdout, lines)
    took, line = aborting[0]
    assert 0 < took < 1.0 + 0.3, (took, line)
    assert "stale stand data" in line or "lost link" in line, line
    # it could not verify the stop over the dead link: it says so, exit 3
    assert proc.returncode == 3, stdout
    assert "STOP NOT VERIFIED" in stdout


# --------------------------------------------------------------------------- refusals


def test_an_active_cutoff_is_refused_at_start_and_cleared_only_when_asked(
    core: FlightStandServer, tmp_path: Path
) -> None:
    stub = official(core.address)
    stub.TriggerCutoff(fs.TriggerCutoffRequest())
    r = thrustmap("sweep", "explicit", "--levels", "20", "--dwell", "1", "--stand",
                  f"flightstand://{core.address}", "-o", str(tmp_path / "r.csv"), "-y", "-q")  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    assert "holds a cutoff (MANUAL)" in r.stderr and "clear_cutoff=1" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert cutoff_of(stub) == "MANUAL"
    assert not (tmp_path / "r.csv").exists() or (tmp_path / "r.csv").stat().st_size < 200
    r = thrustmap("sweep", "explicit", "--levels", "20", "--dwell", "1", "--stand",
                  f"flightstand://{core.address}?clear_cutoff=1", "-o", str(tmp_path / "r2.csv"),
                  "-y", "-q")  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    assert "clearing the Flight Stand core's cutoff (MANUAL)" in r.stderr


def test_several_boards_are_chosen_by_name_and_ambiguity_refused_in_one_line() -> None:
    with FlightStandServer(FlightStandCore(plant=PLANT, boards=2), port=0) as server:
        r = thrustmap("probe", f"flightstand://{server.address}")
        assert r.returncode == 2
        assert r.stderr.count("\n") == 1, r.stderr
        assert "2 boards" in r.stderr and "/boards/simulated_2" in r.stderr
        assert "?board=NAME" in r.stderr
        r = thrustmap("probe", f"flightstand://{server.address}?board=simulated_2")
        assert r.returncode == 0, r.stderr
        assert "board_name: /boards/simulated_2" in r.stdout
        r = thrustmap("probe", f"flightstand://{server.address}?board=nope")
        assert r.returncode == 2 and "no board 'nope'" in r.stderr


def test_no_core_is_one_line_and_exit_2() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    r = thrustmap("probe", f"flightstand://127.0.0.1:{port}?timeout=0.5")
    assert r.returncode == 2
    assert "cannot reach a Flight Stand core" in r.stderr and len(r.stderr.splitlines()) == 1


@pytest.mark.parametrize(
    ("url", "said"),
    [
        ("flightstand://127.0.0.1:50051?bord=x", "unknown option(s) bord"),
        ("flightstand://127.0.0.1:50051?timeout=soon", "timeout='soon': expected seconds"),
        ("flightstand://127.0.0.1:99999", "the port must be a number"),
        ("flightstand://", "expected flightstand://HOST:PORT"),
    ],
)
def test_a_bad_url_is_one_line_and_exit_2(url: str, said: str) -> None:
    r = thrustmap("probe", url)
    assert r.returncode == 2, r.stdout + r.stderr
    assert said in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_sim_serve_listens_on_loopback_only_by_default() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(
        [sys.executable, "-m", "thrustmap", "sim-serve", "flightstand", "--port", str(port),
         "--duration", "20"],  # fmt: skip
        stderr=subprocess.PIPE, text=True, env=_env(), cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stderr is not None
        assert f"on 127.0.0.1:{port}" in proc.stderr.readline()
        listening = _listening_ports(proc.pid)
        assert listening, "sim-serve listens on nothing"
        assert all(addr in ("127.0.0.1", "::ffff:127.0.0.1") for addr, _ in listening), listening
        assert {p for _, p in listening} == {port}
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=10)


def _listening_ports(pid: int) -> list[tuple[str, int]]:
    """(address, port) of the TCP sockets ``pid`` listens on (Linux /proc)."""
    inodes = set()
    fd_dir = Path(f"/proc/{pid}/fd")
    if not fd_dir.is_dir():
        pytest.skip("no /proc here")
    for fd in fd_dir.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    out = []
    for table, v6 in (("/proc/net/tcp", False), ("/proc/net/tcp6", True)):
        for line in Path(table).read_text().splitlines()[1:]:
            cols = line.split()
            if cols[3] != "0A" or cols[9] not in inodes:  # 0A: LISTEN
                continue
            hex_addr, hex_port = cols[1].split(":")
            raw = bytes.fromhex(hex_addr)
            if v6:
                words = [raw[i : i + 4][::-1] for i in range(0, 16, 4)]
                addr = socket.inet_ntop(socket.AF_INET6, b"".join(words))
            else:
                addr = socket.inet_ntop(socket.AF_INET, raw[::-1])
            out.append((addr, int(hex_port, 16)))
    return out


# --------------------------------------------------------------------------- the official client


def test_every_message_thrustmap_sends_is_one_of_the_packages_generated_classes(
    core: FlightStandServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A whole sweep in-process, every request recorded on the channel: each is an instance of
    a class of the package's generated module, for a method of its service."""
    from thrustmap.core.clock import MonotonicClock
    from thrustmap.rig import plans
    from thrustmap.rig.interlocks import Limits
    from thrustmap.rig.session import BenchSession, Rig

    sent: list[tuple[str, Any]] = []

    class Record(grpc.UnaryUnaryClientInterceptor, grpc.StreamStreamClientInterceptor):  # type: ignore[misc]
        def intercept_unary_unary(self, continuation: Any, details: Any, request: Any) -> Any:
            sent.append((details.method, request))
            return continuation(details, request)

        def intercept_stream_stream(self, continuation: Any, details: Any, requests: Any) -> Any:
            def each() -> Iterator[Any]:
                for r in requests:
                    sent.append((details.method, r))
                    yield r

            return continuation(details, each())

    real = grpc.insecure_channel
    monkeypatch.setattr(grpc, "insecure_channel",
                        lambda *a, **k: grpc.intercept_channel(real(*a, **k), Record()))  # fmt: skip
    plan = plans.explicit([15.0, 25.0], dwell_s=1.0)
    with BenchSession(Rig(stand=f"flightstand://{core.address}"), MonotonicClock()) as bench:
        result = bench.sweep(plan, str(tmp_path / "m.csv"), limits=Limits())
    assert result.status == "completed" and result.stop_verified
    methods = {m.rsplit("/", 1)[-1] for m, _ in sent}
    assert {
        "UpdateOutput",
        "GetServerStatus",
        "WatchSamples",
        "TareInputs",
        "UpdateInput",
    } <= methods
    service = fs.DESCRIPTOR.services_by_name["FlightStand"]
    for method, request in sent:
        rpc = service.methods_by_name[method.rsplit("/", 1)[-1]]
        assert type(request) is getattr(fs, rpc.input_type.name), (method, type(request))
        assert (
            type(request).__module__ == fs.__name__
            or type(request).DESCRIPTOR.file is fs.DESCRIPTOR
        )


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


@pytest.mark.parametrize("script", ["example.py", "data_recording.py"])
def test_the_official_examples_run_unmodified_against_the_simulated_core(
    script: str, tmp_path: Path
) -> None:
    """The package's own scripts, from where pip installed them, on the core's default address
    (localhost:50051, as they hard-code it)."""
    import FlightStand

    path = Path(FlightStand.__file__).parent / "examples" / script
    assert path.is_file(), f"the package no longer ships {path}"
    if not _port_free(50051):
        pytest.skip("localhost:50051 is in use (a Flight Stand core may be running)")
    with FlightStandServer(FlightStandCore(plant=PLANT, seed=5), port=50051):
        r = subprocess.run([sys.executable, str(path)], capture_output=True, text=True,
                           timeout=90, cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    assert "\nDone" in r.stdout, r.stdout
    if script == "example.py":
        # thrust printed at rest, then at 1500 µs: the physics behind the ESC output
        values = [float(line) for line in r.stdout.splitlines() if _is_number(line)]
        assert len(values) == 2 and abs(values[0]) < 0.2 and values[1] > 2.0, r.stdout
    else:
        assert "Manual samples taken: 8" in r.stdout
        assert "Rows of retrieved manual data: 8" in r.stdout
        rows = int(r.stdout.split("Rows of retrieved continuous data:")[1].split()[0])
        assert 4500 <= rows <= 5600, rows  # 5 s resampled at 1 ms


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
