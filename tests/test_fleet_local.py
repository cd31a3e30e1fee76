"""Local workers forked from the command (thrustmap.fleet.local): the serial loop's table, the
memory limit, a worker that dies, a command that is killed, and nothing listening."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from support.fleet_gen import Fleet, make_fleet
from test_fleet_dask import (
    alive,
    args,
    comparable,
    env,
    sigint_for_children,
    stop_as_asked,
    timeless_bytes,
)

import thrustmap.fleet.task as fleet_task
from thrustmap.cli import main
from thrustmap.fleet import local, run
from thrustmap.fleet.task import LogTask, Outcome

pytest.importorskip("pyarrow")
psutil = pytest.importorskip("psutil")
pytestmark = pytest.mark.skipif(not local.available(), reason="forked workers: Linux only")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Fleet:
    return make_fleet(tmp_path_factory.mktemp("fleet"), 3)


def config_for(fleet: Fleet, out: Path) -> run.FleetConfig:
    return run.FleetConfig(
        out_dir=out,
        df_options={"rotors": None},
        masses=run.read_masses(fleet.masses_csv),
        map_path=fleet.stand_map,
    )


def run_pool(
    fleet: Fleet, out: Path, spec: local.LocalSpec, poll_s: float = 0.25
) -> tuple[run.FleetResult, local.ForkPool]:
    pool = local.ForkPool(spec, poll_s=poll_s)
    try:
        result = run.fleet_extract([fleet.folder], config_for(fleet, out), local=pool.run)
    finally:
        stopped = pool.close()
    assert not any(psutil.pid_exists(p) and alive(psutil.Process(p)) for p in stopped)
    return result, pool


def patch_one_log(
    monkeypatch: pytest.MonkeyPatch, victim: Path, action: Callable[[], None]
) -> None:
    """Run ``action`` in the worker that takes ``victim`` (the forked workers inherit the patch)."""
    real = fleet_task.process_log

    def process_log(task: LogTask) -> dict[str, Any]:
        if task.path == str(victim):
            action()
        return real(task)

    monkeypatch.setattr(local, "process_log", process_log)


def test_two_local_workers_give_the_serial_loops_table(fleet: Fleet, tmp_path: Path) -> None:
    main(args(fleet, tmp_path / "serial", "--workers", "0", "--quiet"))
    main(args(fleet, tmp_path / "two", "--workers", "2", "--quiet"))
    serial = comparable(tmp_path / "serial" / "fleet.parquet")
    assert comparable(tmp_path / "two" / "fleet.parquet") == serial
    assert len(serial) == len(fleet.good) + len(fleet.corrupt) + len(fleet.no_mass)
    # byte for byte, but for each log's run time
    two = timeless_bytes(tmp_path / "two" / "fleet.parquet")
    assert two == timeless_bytes(tmp_path / "serial" / "fleet.parquet")


def test_a_log_that_kills_its_worker_is_refused_and_the_fleet_goes_on(
    fleet: Fleet, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    victim = sorted(fleet.good)[4]
    patch_one_log(monkeypatch, victim, lambda: os.kill(os.getpid(), signal.SIGKILL))
    result, pool = run_pool(fleet, tmp_path / "out", local.LocalSpec(2, 1 << 30))
    rows = {Path(o.path): o for o in result.outcomes}
    assert len(rows) == len(result.outcomes) == result.total  # every log once
    died = rows.pop(victim)
    assert died.status == "refused"
    assert died.reason == (
        f"{victim}: the worker holding this log died (killed by signal 9); the log was not retried"
    )
    assert all(rows[p].status == "ok" for p in fleet.good if p != victim)
    assert pool.started == 3  # the two workers and the one forked in place of the dead one


def test_a_log_over_the_memory_limit_fails_to_allocate_and_is_refused(
    fleet: Fleet, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """RLIMIT_AS: the worker's address space grows by at most --memory-per-worker."""
    limit = 256 << 20
    victim = sorted(fleet.good)[2]

    import thrustmap.fleet.task as task

    real = task._extract

    def greedy(t: LogTask, out: Outcome) -> None:
        if t.path == str(victim):
            bytearray(2 * limit)  # more than the limit at once
        real(t, out)

    monkeypatch.setattr(task, "_extract", greedy)
    result, pool = run_pool(fleet, tmp_path / "out", local.LocalSpec(1, limit))
    rows = {Path(o.path): o for o in result.outcomes}
    assert rows.pop(victim).reason == f"{victim}: out of memory while reading the log"
    assert all(rows[p].status == "ok" for p in fleet.good if p != victim)
    assert pool.started == 1  # the worker survived its failed allocation


def test_a_worker_whose_memory_creeps_over_the_limit_is_stopped(
    fleet: Fleet, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The watchdog: resident memory over --memory-per-worker (what Dask's nanny does)."""
    limit = 256 << 20
    victim = sorted(fleet.good)[1]
    held: list[bytearray] = []

    def creep() -> None:
        for _ in range(64):  # up to 2 x the limit, 32 MiB at a time, written (resident)
            held.append(bytearray(b"\x01" * (8 << 20)))
            time.sleep(0.02)

    # the address-space backstop is lifted here so the watchdog is what stops the worker
    monkeypatch.setattr(local, "_limit_address_space", lambda limit_bytes: None)
    patch_one_log(monkeypatch, victim, creep)
    result, pool = run_pool(fleet, tmp_path / "out", local.LocalSpec(1, limit), poll_s=0.05)
    rows = {Path(o.path): o for o in result.outcomes}
    reason = rows.pop(victim).reason
    assert reason.startswith(f"{victim}: the worker holding this log died (stopped at ")
    assert "over its memory limit of 0.25 GiB (--memory-per-worker)" in reason
    assert all(rows[p].status == "ok" for p in fleet.good if p != victim)
    assert pool.started == 2


def test_memory_the_worker_shares_with_the_command_is_not_its_own(
    fleet: Fleet, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A command holding more than --memory-per-worker (here 320 MiB written before the fork,
    as a test runner or a big map can) forks workers whose RSS starts over the limit: the
    watchdog counts a worker's private pages, so none is stopped (it stopped every worker, and
    each replacement, when it read the RSS)."""
    limit = 256 << 20
    ballast = bytearray(b"\x01" * (320 << 20))
    monkeypatch.setattr(local, "_limit_address_space", lambda limit_bytes: None)
    result, pool = run_pool(fleet, tmp_path / "out", local.LocalSpec(2, limit), poll_s=0.05)
    rows = {Path(o.path): o for o in result.outcomes}
    assert all(rows[p].status == "ok" for p in fleet.good), [rows[p].reason for p in fleet.good]
    assert pool.started == 2
    assert len(ballast) == 320 << 20


def slow_command(argv: list[str], delay_s: float = 0.3) -> list[str]:
    """``thrustmap ARGV`` with every log taking ``delay_s`` longer in the workers, so a signal
    lands while they are busy (the patch is the test's, inherited by the forked workers)."""
    code = (
        "import time\n"
        "from thrustmap.fleet import local\n"
        "real = local.process_log\n"
        f"local.process_log = lambda t: (time.sleep({delay_s}), real(t))[1]\n"
        "from thrustmap.cli import main\n"
        f"main({argv!r})\n"
    )
    return [sys.executable, "-c", code]


def workers_once_busy(proc: subprocess.Popen[str], n: int) -> list[Any]:
    """The command's worker processes once it has reported progress (they are on logs)."""
    assert proc.stderr is not None
    for line in proc.stderr:
        if line.startswith("progress:"):
            break
    kids = psutil.Process(proc.pid).children()
    assert len(kids) == n
    return kids


def test_a_killed_command_takes_its_workers_with_it(fleet: Fleet, tmp_path: Path) -> None:
    """SIGKILL cannot be caught: the workers die with the command anyway (PR_SET_PDEATHSIG)."""
    cmd = slow_command(args(fleet, tmp_path / "out", "--workers", "2"))
    proc = subprocess.Popen(cmd, env=env(), stderr=subprocess.PIPE, text=True)
    kids: list[Any] = []
    try:
        kids = workers_once_busy(proc, 2)
        proc.kill()
        proc.wait(30)
        deadline = time.monotonic() + 10
        while any(alive(k) for k in kids) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(alive(k) for k in kids)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for k in kids:
            if alive(k):
                k.kill()


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_local_workers_listen_nowhere_and_a_stop_keeps_the_table_and_resumes(
    fleet: Fleet, tmp_path: Path, how: str
) -> None:
    """Pipes, no sockets. A Ctrl-C reaches the whole process group and only the command acts
    on it; SIGTERM reaches the command alone. Either way it writes the table so far, stops its
    workers, exits 130, and the same command resumes to the serial loop's table."""
    out = tmp_path / "out"
    cmd = slow_command(args(fleet, out, "--workers", "2"))
    with sigint_for_children():
        proc = subprocess.Popen(cmd, env=env(), stderr=subprocess.PIPE, text=True,
                                start_new_session=True)  # fmt: skip
    kids: list[Any] = []
    try:
        kids = workers_once_busy(proc, 2)
        sockets = [c for p in [psutil.Process(proc.pid), *kids] for c in p.net_connections()]
        assert sockets == []
        stop_as_asked(proc, how, 60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert not any(alive(k) for k in kids)
    from thrustmap.fleet.table import read_table

    partial = read_table(out / "fleet.parquet")
    assert 0 < len(partial) < len(fleet.good)
    main(args(fleet, out, "--workers", "2", "--quiet"))
    assert sum(o.reused for o in read_table(out / "fleet.parquet")) >= len(partial)
    main(args(fleet, tmp_path / "serial", "--workers", "0", "--quiet"))
    assert comparable(out / "fleet.parquet") == comparable(tmp_path / "serial" / "fleet.parquet")


def test_a_workers_log_records_reach_the_command_bounded(
    fleet: Fleet, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """What a reader logs in a worker is logged by the command, as in the serial loop (the
    command's handlers, copied by the fork, would write over its bar or hold the lines in the
    worker); at most MAX_RECORDS_PER_LOG a log."""
    victim = sorted(fleet.good)[3]
    noisy = logging.getLogger("thrustmap.flightlogs.dataflash")
    n = local.MAX_RECORDS_PER_LOG + 7
    patch_one_log(
        monkeypatch, victim, lambda: [noisy.warning("odd record %d", k) for k in range(n)]
    )
    with caplog.at_level(logging.WARNING):
        run_pool(fleet, tmp_path / "out", local.LocalSpec(2, 1 << 30))
    lines = [r.getMessage() for r in caplog.records if r.name == noisy.name]
    assert lines == [f"odd record {k}" for k in range(local.MAX_RECORDS_PER_LOG)]
    more = [r.getMessage() for r in caplog.records if r.name == "thrustmap.fleet.local"]
    assert more == ["7 more log lines not shown"]


def test_workers_that_all_die_still_end_the_run_each_log_refused_once(
    fleet: Fleet, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A broken worker environment: every log kills its worker. Each death refuses one log and
    forks one replacement while logs are left, so the run ends, nothing retried forever."""
    monkeypatch.setattr(local, "process_log", lambda t: os.kill(os.getpid(), signal.SIGKILL))
    result, pool = run_pool(fleet, tmp_path / "out", local.LocalSpec(2, 1 << 30))
    assert len(result.outcomes) == result.total == len({o.path for o in result.outcomes})
    assert all("the worker holding this log died" in o.reason for o in result.outcomes)
    assert pool.started <= result.total + 1
