"""`fleet extract` and `fleet gamma`: what listens (issue 36 item 1), Ctrl-C while the local
cluster starts (issue 31 item 10), no group fitted (issue 31 item 15)."""

from __future__ import annotations

import http.client
import ipaddress
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import pytest
from support.fleet_gen import Fleet, make_fleet
from test_fleet_dask import alive, args, env, sigint_for_children

from thrustmap.cli import main

pytest.importorskip("distributed")
psutil = pytest.importorskip("psutil")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Fleet:
    return make_fleet(tmp_path_factory.mktemp("fleet"), 6, duration_s=60.0, rate_hz=25.0)


def start(cmd: list[str]) -> subprocess.Popen[str]:
    with sigint_for_children():  # as a terminal's foreground job has it
        return subprocess.Popen(
            [sys.executable, "-m", "thrustmap", *cmd], env=env(), stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True, start_new_session=True,
        )  # fmt: skip


def listening(pid: int) -> set[tuple[str, int]]:
    """Listening TCP sockets of a process and its children (those that can be read)."""
    found: set[tuple[str, int]] = set()
    try:
        procs = [psutil.Process(pid), *psutil.Process(pid).children(recursive=True)]
    except psutil.Error:
        return found
    for p in procs:
        try:
            conns = p.net_connections(kind="inet")
        except psutil.Error:
            continue
        found |= {(c.laddr.ip, c.laddr.port) for c in conns if c.status == psutil.CONN_LISTEN}
    return found


def http_status(port: int, path: str) -> int | None:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=2) as r:
            return int(r.status)
    except urllib.error.HTTPError as exc:
        return exc.code
    except (OSError, ValueError, http.client.HTTPException):
        return None  # not HTTP (the scheduler's or a worker's own port)


def watch(proc: subprocess.Popen[str]) -> tuple[set[tuple[str, int]], dict[int, int | None]]:
    """Sample the listening sockets until the command ends; ask each port once for Dask's
    JSON identity page (which the dashboard's routes serve)."""
    seen: set[tuple[str, int]] = set()
    answers: dict[int, int | None] = {}
    deadline = time.monotonic() + 180
    while proc.poll() is None and time.monotonic() < deadline:
        for ip, port in listening(proc.pid) - seen:
            seen.add((ip, port))
            answers[port] = http_status(port, "/json/identity.json")
        time.sleep(0.1)
    return seen, answers


def finish(proc: subprocess.Popen[str]) -> tuple[int, str]:
    try:
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err


def test_local_workers_listen_nowhere(fleet: Fleet, tmp_path: Path) -> None:
    """Forked local workers talk to the command over pipes: no socket listens at all."""
    proc = start(args(fleet, tmp_path / "out", "--workers", "2", "--quiet"))
    seen, _ = watch(proc)
    code, err = finish(proc)
    assert code == 0, err
    assert "local workers: 2 processes forked from this command" in err
    assert seen == set()


def test_a_local_dask_cluster_listens_on_loopback_only_and_serves_no_dashboard() -> None:
    """Where local workers are a Dask LocalCluster (not Linux, or --dashboard): every server
    on 127.0.0.1, and without --dashboard no page but health checks."""
    from thrustmap.fleet import run

    cluster, client = run.start_local_cluster(run.LocalClusterSpec(2, 1 << 30))
    try:
        seen = listening(os.getpid())
        assert len(seen) >= 4  # the scheduler, its HTTP server, the nannies and workers
        outside = [(ip, port) for ip, port in seen if not ipaddress.ip_address(ip).is_loopback]
        assert outside == []
        answers = {port: http_status(port, "/json/identity.json") for _, port in seen}
        assert 200 not in answers.values()  # no dashboard page answers, even on loopback
    finally:
        run.close_cluster(cluster, client)


def test_the_dashboard_only_when_asked_for(fleet: Fleet, tmp_path: Path) -> None:
    proc = start(args(fleet, tmp_path / "out", "--workers", "1", "--quiet", "--dashboard", ":0"))
    seen, answers = watch(proc)
    code, err = finish(proc)
    assert code == 0, err
    link = re.search(r"Dask dashboard: http://127\.0\.0\.1:(\d+)/status", err)
    assert link is not None, err
    assert answers.get(int(link.group(1))) == 200
    assert all(ipaddress.ip_address(ip).is_loopback for ip, _ in seen)


@pytest.mark.parametrize("delay_s", [0.0, 0.5])
def test_ctrl_c_while_the_local_cluster_starts_stops_the_run(
    fleet: Fleet, tmp_path: Path, delay_s: float
) -> None:
    """The workers start with SIGINT blocked (a Ctrl-C at the terminal reaches the whole
    process group, only the command acts on it), and the command itself answers it at once:
    exit 130, nothing left running, no traceback. (A local Dask cluster: --dashboard here;
    forked workers, which start in milliseconds: tests/test_fleet_local.py.)"""
    proc = start(args(fleet, tmp_path / "out", "--workers", "2", "--dashboard", "127.0.0.1:0"))
    assert proc.stderr is not None
    deadline = time.monotonic() + 60
    for line in proc.stderr:
        if line.startswith("local Dask cluster"):
            break
        assert time.monotonic() < deadline
    # the cluster is starting once its first process exists (Ctrl-C used to be ignored from
    # then until every worker had started, ~1-2 s)
    while not psutil.Process(proc.pid).children(recursive=True):
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.01)
    time.sleep(delay_s)
    kids: list[Any] = psutil.Process(proc.pid).children(recursive=True)
    os.killpg(proc.pid, signal.SIGINT)
    code, err = finish(proc)
    assert code == 130, err
    assert "interrupted" in err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    deadline = time.monotonic() + 10
    while any(alive(p) for p in kids) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = [p.pid for p in kids if alive(p)]
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert left == []


def test_the_workers_of_a_local_cluster_start_with_sigint_blocked() -> None:
    from thrustmap.fleet import run

    cluster, client = run.start_local_cluster(run.LocalClusterSpec(1, 1 << 30))
    try:
        pids = list(client.run(os.getpid).values())
        assert len(pids) == 1
        status = Path(f"/proc/{pids[0]}/status").read_text()
        blocked = int(re.search(r"SigBlk:\s*([0-9a-f]+)", status).group(1), 16)  # type: ignore[union-attr]
        assert blocked & (1 << (signal.SIGINT - 1))
        assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())
    finally:
        run.close_cluster(cluster, client)


def test_fleet_gamma_with_no_group_fitted_says_so_and_exits_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    small = make_fleet(tmp_path, 2, corrupt=False, no_mass=0)
    out = tmp_path / "out"
    main(args(small, out, "--workers", "0", "--quiet"))
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main(["fleet", "gamma", str(out), "--map", str(small.stand_map)])  # 3 logs a group
    assert exc.value.code == 1
    stdout, err = capsys.readouterr()
    assert "0 of 4 groups fitted" in stdout
    assert "corrected map" not in stdout  # no claim of maps written
    assert "no group fitted, so no γ(B) and no corrected map" in err
    assert "too small: 2 logs" in err
    assert not (out / "gamma").exists()
    html = (out / "fleet-report.html").read_text()
    section = html[html.index("<section id='gamma'>") :]
    assert "No group was fitted" in section and "too small: 2 logs" in section
