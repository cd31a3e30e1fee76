"""`fleet extract` on Dask: a local cluster interrupted leaves no process; a separately started
`dask scheduler` + `dask worker` gives the same table as the plain serial loop."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from support.fleet_gen import Fleet, make_fleet

from thrustmap.cli import main
from thrustmap.fleet.table import read_table

pytest.importorskip("distributed")
psutil = pytest.importorskip("psutil")

ROOT = Path(__file__).resolve().parent.parent
#: what differs between two runs of the same fleet (timing, and whether it was reused)
VOLATILE = ("seconds", "reused")


@contextlib.contextmanager
def sigint_for_children() -> Iterator[None]:
    """Children started in this block get SIGINT at its default, as a terminal's foreground
    job has it. A shell starts background jobs (``&``, nohup, CI scripts run that way) with
    SIGINT ignored and children inherit that (the fleet, unlike a motor path, rightly keeps
    ignoring it there). Only "ignored" survives exec, so any handler here is enough; set in the
    parent rather than in a preexec_fn, which is unsafe with threads running."""
    previous = signal.getsignal(signal.SIGINT)
    if previous == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def env() -> dict[str, str]:
    e = dict(os.environ)
    e["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(ROOT / "tests"), e.get("PYTHONPATH", "")])
    return e


def comparable(table: Path) -> list[dict[str, Any]]:
    rows = []
    for o in read_table(table):
        d = o.to_dict()
        for k in VOLATILE:
            d.pop(k)
        rows.append(json.loads(json.dumps(d, default=str).replace("NaN", "null")))
    return rows


def timeless_bytes(table: Path) -> bytes:
    """The Parquet file the table would be with every log's run time zeroed (the only column
    that differs between two runs of the same fleet that reuse nothing)."""
    import dataclasses

    from thrustmap.fleet.table import write_table

    copy = table.with_name("timeless.parquet")
    write_table([dataclasses.replace(o, seconds=0.0) for o in read_table(table)], copy)
    return copy.read_bytes()


def args(fleet: Fleet, out: Path, *extra: str) -> list[str]:
    return ["fleet", "extract", str(fleet.folder), "-o", str(out), "--masses",
            str(fleet.masses_csv), "--map", str(fleet.stand_map), *extra]  # fmt: skip


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Fleet:
    return make_fleet(tmp_path_factory.mktemp("fleet"), 30)


@pytest.fixture(scope="module")
def serial_table(fleet: Fleet, tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, Any]]:
    out = tmp_path_factory.mktemp("serial")
    main(args(fleet, out, "--workers", "0", "--quiet"))
    return comparable(out / "fleet.parquet")


def stop_as_asked(proc: subprocess.Popen[str], how: str, timeout_s: float) -> str:
    """Ctrl-C at a terminal (SIGINT to the whole process group) or SIGTERM to the command
    alone; the command's stderr once it has ended, its stop checked: exit 130, the resume hint,
    no traceback. (The caller kills the command in its ``finally`` if this fails.)"""
    if how == "ctrl-c":
        os.killpg(proc.pid, signal.SIGINT)
    else:
        proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=timeout_s)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "run the same command again to resume" in err
    assert "Traceback" not in err
    return str(err)


def stop_servers(started: list[subprocess.Popen[bytes]]) -> None:
    """Dask's own scheduler and workers, last started first: SIGINT (their clean stop), then
    SIGKILL for any still up after 30 s."""
    for p in reversed(started):
        p.send_signal(signal.SIGINT)
    for p in reversed(started):
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def alive(p: Any) -> bool:
    try:
        return bool(p.is_running() and p.status() != psutil.STATUS_ZOMBIE)
    except psutil.Error:
        return False


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_ctrl_c_on_a_local_cluster_leaves_no_process_and_resumes(
    fleet: Fleet, serial_table: list[dict[str, Any]], tmp_path: Path, how: str
) -> None:
    """Ctrl-C at a terminal (SIGINT to the whole process group), or SIGTERM to the command
    alone (a batch system, systemd, ``kill``): the table of what finished is written, no worker
    outlives the command, and the same command resumes."""
    out = tmp_path / "out"
    # every log on the workers (with a dashboard the command runs none itself while the
    # cluster starts), so the stop lands while they are busy
    cmd = [sys.executable, "-m", "thrustmap",
           *args(fleet, out, "--workers", "2", "--dashboard", "127.0.0.1:0")]  # fmt: skip
    with sigint_for_children():
        proc = subprocess.Popen(cmd, env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, start_new_session=True)  # fmt: skip
    seen: set[Any] = set()
    try:
        assert proc.stderr is not None
        deadline = time.monotonic() + 120
        for line in proc.stderr:  # wait until the workers are busy with logs
            if line.startswith("progress:"):
                break
            assert time.monotonic() < deadline, "no progress in 120 s"
        parent = psutil.Process(proc.pid)
        seen = set(parent.children(recursive=True))
        assert len(seen) >= 2  # the two worker processes (and their nannies)
        err = stop_as_asked(proc, how, 90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert "KeyboardInterrupt" not in err  # the workers kept quiet
    assert "leaked" not in err  # the workers' semaphores were released: they were stopped
    deadline = time.monotonic() + 10
    while any(alive(p) for p in seen) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = [p.pid for p in seen if alive(p)]
    for pid in left:  # never leave them behind, even when the test fails
        os.kill(pid, signal.SIGKILL)
    assert left == []
    partial = read_table(out / "fleet.parquet")
    assert 0 < len(partial) < len(serial_table)
    # the same command again resumes: what was done is reused, the table is whole
    main(args(fleet, out, "--workers", "2", "--quiet"))
    whole = read_table(out / "fleet.parquet")
    assert sum(o.reused for o in whole) >= len(partial)
    assert comparable(out / "fleet.parquet") == serial_table


def test_an_existing_scheduler_gives_the_same_table(
    fleet: Fleet, serial_table: list[dict[str, Any]], tmp_path: Path
) -> None:
    sched_file = tmp_path / "scheduler.json"
    dask = [sys.executable, "-m", "dask"]  # the `dask` command of this environment
    started: list[subprocess.Popen[bytes]] = []

    def spawn(cmd: list[str]) -> subprocess.Popen[bytes]:
        with sigint_for_children():  # stopped with SIGINT below
            return subprocess.Popen(
                cmd, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
            )

    try:
        started.append(
            spawn(
                [
                    *dask,
                    "scheduler",
                    "--scheduler-file",
                    str(sched_file),
                    "--port",
                    "0",
                    "--dashboard-address",
                    ":0",
                    "--host",
                    "127.0.0.1",
                ],  # fmt: skip
            )
        )
        deadline = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        started.append(
            spawn(
                [
                    *dask,
                    "worker",
                    address,
                    "--nworkers",
                    "2",
                    "--nthreads",
                    "1",
                    "--memory-limit",
                    "1GiB",
                    "--no-dashboard",
                ],  # fmt: skip
            )
        )
        from distributed import Client

        with Client(address, timeout="60s") as c:
            c.wait_for_workers(2, timeout=90)
        out = tmp_path / "out"
        main(args(fleet, out, "--scheduler", address, "--quiet"))
        assert comparable(out / "fleet.parquet") == serial_table
        # and byte for byte the table of local (forked) workers, but for the run times
        main(args(fleet, tmp_path / "local", "--workers", "2", "--quiet"))
        local = timeless_bytes(tmp_path / "local" / "fleet.parquet")
        assert timeless_bytes(out / "fleet.parquet") == local
    finally:
        stop_servers(started)


def test_a_worker_that_dies_refuses_its_log_and_the_fleet_goes_on(tmp_path: Path) -> None:
    """What the memory limit does to a worker (its nanny kills it). Small logs travel two to a
    task here (8 logs, one slot): the first death is the batch's, so its logs are sent again one
    per task; the second kills the first of them alone, which is then refused with that reason,
    not retried, and the other logs are extracted on the restarted worker."""
    import threading

    from thrustmap.fleet import run

    small = make_fleet(tmp_path, 2, duration_s=60.0, rate_hz=50.0, corrupt=False, no_mass=0)
    config = run.FleetConfig(
        out_dir=tmp_path / "out",
        df_options={"rotors": None},
        masses=run.read_masses(small.masses_csv),
        map_path=small.stand_map,
    )
    cluster, client = run.start_local_cluster(run.LocalClusterSpec(1, 1 << 30))
    killed: list[str] = []

    def kill_first_busy_worker() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(killed) < 2:
            busy = {w: keys for w, keys in client.processing().items() if keys}
            key = str(busy[next(iter(busy))][0]) if busy else None
            if key is not None and key not in killed:
                pid = client.run(os.getpid, workers=list(busy))[next(iter(busy))]
                killed.append(key)
                os.kill(pid, signal.SIGKILL)
            time.sleep(0.005)

    try:
        client.run(lambda: __import__("thrustmap.fitting.df"))
        killer = threading.Thread(target=kill_first_busy_worker)
        killer.start()
        result = run.fleet_extract([small.folder], config, connect=lambda: (client, 1))
        killer.join()
    finally:
        client.close()
        cluster.close()
    assert len(killed) == 2
    died = [o for o in result.outcomes if o.status == "refused"]
    assert len(died) == 1 and "the worker holding this log died" in died[0].reason
    assert sum(o.status == "ok" for o in result.outcomes) == len(small.good) - 1


def test_small_logs_travel_in_batches_and_large_ones_alone(tmp_path: Path) -> None:
    from thrustmap.fleet import run
    from thrustmap.fleet.task import LogTask

    def task(name: str, size: int) -> LogTask:
        p = tmp_path / name
        p.write_bytes(b"x" * size)
        return LogTask(str(p), str(tmp_path), "k", {})

    small = [task(f"s{k}", 1000) for k in range(40)]
    big = task("big", run.BATCH_BYTES + 1)
    groups = list(run.batches([*small[:20], big, *small[20:]], window=1))
    # the small logs before the big one together, the big one alone, the rest together
    assert [len(g) for g in groups] == [20, 1, 20]
    assert [t.path for g in groups for t in g] == [t.path for t in [*small[:20], big, *small[20:]]]
    assert all(len(g) == 1 for g in run.batches(small[:3], window=4))  # few logs: one each


def test_batches_shrink_to_single_logs_at_the_fleets_tail(tmp_path: Path) -> None:
    """Guided self-scheduling: big batches first (few Dask tasks), then smaller and smaller, and
    a window of single logs last, so no worker idles while another finishes a big batch."""
    from thrustmap.fleet import run
    from thrustmap.fleet.task import LogTask

    tasks = []
    for k in range(165):
        p = tmp_path / f"s{k:03d}"
        p.write_bytes(b"x" * 1000)
        tasks.append(LogTask(str(p), str(tmp_path), "k", {}))
    groups = list(run.batches(tasks, window=4))
    sizes = [len(g) for g in groups]
    assert [t.path for g in groups for t in g] == [t.path for t in tasks]
    assert sizes[0] == 42  # ceil(165 / 4): a window's share
    assert sizes[-4:] == [1, 1, 1, 1]  # a window of single logs at the end
    assert sizes == sorted(sizes, reverse=True)  # never a bigger batch after a smaller one
    assert len(sizes) <= 20  # still batched: not one task per log
    # a batch also stops at BATCH_BYTES of logs (here 4 logs of a quarter of it)
    big = []
    for k in range(12):
        p = tmp_path / f"b{k:02d}"
        p.write_bytes(b"x" * (run.BATCH_BYTES // 4))
        big.append(LogTask(str(p), str(tmp_path), "k", {}))
    assert [len(g) for g in run.batches(big, window=2)] == [4, 4, 2, 1, 1]


def _tls_files(d: Path) -> dict[str, Path]:
    """A throw-away CA and a certificate for 127.0.0.1 signed by it, for the node and the
    client (openssl on the PATH)."""
    import shutil

    if shutil.which("openssl") is None:
        pytest.skip("needs openssl to make test certificates")

    def ssl(*a: str) -> None:
        subprocess.run(["openssl", *a], cwd=d, check=True, capture_output=True)

    ssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem",
        "-days", "2", "-subj", "/CN=thrustmap-test-ca")  # fmt: skip
    for n in ("node", "client"):
        ssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{n}.key", "-out", f"{n}.csr",
            "-subj", "/CN=127.0.0.1")  # fmt: skip
        (d / f"{n}.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
        ssl("x509", "-req", "-in", f"{n}.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
            "-CAcreateserial", "-out", f"{n}.pem", "-days", "2", "-extfile", f"{n}.ext")  # fmt: skip
    return {k: d / k for k in ("ca.pem", "node.pem", "node.key", "client.pem", "client.key")}


def test_a_tls_scheduler_with_dasks_security_configuration(
    fleet: Fleet, serial_table: list[dict[str, Any]], tmp_path: Path
) -> None:
    """`--scheduler tls://...`: the command takes Dask's own TLS configuration (here from the
    environment), gives the local table; without it, one line naming what is missing, exit 2."""
    tls = _tls_files(tmp_path)
    sched_file = tmp_path / "scheduler.json"
    node = ["--tls-ca-file", str(tls["ca.pem"]), "--tls-cert", str(tls["node.pem"]),
            "--tls-key", str(tls["node.key"])]  # fmt: skip
    started: list[subprocess.Popen[bytes]] = []
    try:
        with sigint_for_children():
            started.append(subprocess.Popen(
                [sys.executable, "-m", "dask", "scheduler", "--protocol", "tls", "--host",
                 "127.0.0.1", "--port", "0", "--dashboard-address", "127.0.0.1:0",
                 "--scheduler-file", str(sched_file), *node],
                env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))  # fmt: skip
        deadline = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        assert address.startswith("tls://127.0.0.1:")
        with sigint_for_children():
            started.append(subprocess.Popen(
                [sys.executable, "-m", "dask", "worker", address, "--nworkers", "2",
                 "--nthreads", "1", "--memory-limit", "1GiB", "--no-dashboard", *node],
                env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))  # fmt: skip
        client_env = {
            **env(),
            "DASK_DISTRIBUTED__COMM__TLS__CA_FILE": str(tls["ca.pem"]),
            "DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT": str(tls["client.pem"]),
            "DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY": str(tls["client.key"]),
            "DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION": "True",
        }
        out = tmp_path / "out"
        cmd = [sys.executable, "-m", "thrustmap", *args(fleet, out, "--scheduler", address,
                                                         "--quiet")]  # fmt: skip
        done = subprocess.run(cmd, env=client_env, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        assert comparable(out / "fleet.parquet") == serial_table
        bare_cmd = [sys.executable, "-m", "thrustmap",
                    *args(fleet, tmp_path / "out2", "--scheduler", address, "--quiet")]  # fmt: skip
        bare = subprocess.run(bare_cmd, env=env(), capture_output=True, text=True, timeout=120)
        assert bare.returncode == 2, bare.stderr
        (line,) = bare.stderr.strip().splitlines()
        assert "tls:// needs Dask's TLS configuration" in line and address in line
    finally:
        stop_servers(started)
