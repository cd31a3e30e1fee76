"""Local workers without Dask: processes forked from the command after its imports (Linux).

Why not a local Dask cluster: it starts a scheduler, a nanny per worker and workers that each
spawn a fresh interpreter and import Dask and the readers, ~1 s of CPU per worker before the
first log (benchmarks/bench_fleet.py). A worker forked here starts in milliseconds with numpy
and the extraction rules already imported, so the whole command with 2 workers takes little
more than half the time of 1 worker even on a fleet of small logs. Dask stays for what needs it:
``--scheduler`` (workers on other machines) and ``--dashboard``.

The guarantees of the Dask path, kept:

- One log at a time per worker: a worker runs :func:`thrustmap.fleet.task.process_log`, the
  same call as the serial loop and a Dask worker, on one log, sends its outcome, takes the next.
  The parent keeps ``DEPTH`` logs queued per worker (the worker never waits for a round trip)
  and only discovers, plans, collects and writes the table.
- ``--memory-per-worker``: each worker's address space may grow by at most the limit after it
  is forked (``RLIMIT_AS``: an allocation beyond it fails, and the log is refused as out of
  memory), and the parent reads each worker's own resident memory (private pages, not those
  it still shares with the command) every ``poll_s`` and kills a
  worker over the limit (what Dask's nanny does); the log it held is refused with that reason.
- A log that kills its worker (a crash, the memory limit, the OOM killer) is that log's
  refusal; the logs queued behind it go to a new worker, forked in its place, and the run goes
  on.
- No child left behind: :meth:`ForkPool.close` (called on every way out: the end, an
  exception, Ctrl-C, SIGTERM) terminates, then kills, every worker and waits for each. A
  worker dies with the command even when the command is killed outright (``PR_SET_PDEATHSIG``)
  and exits when its pipe closes. Workers ignore SIGINT and SIGHUP (a Ctrl-C at the terminal
  reaches the whole process group: only the command acts on it, by stopping them).
- Nothing listens: a worker talks to the command over a pipe, no socket at all.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from thrustmap.fleet.task import LogTask, Outcome, process_log

log = logging.getLogger(__name__)

#: logs queued per worker: the next one is already there when a log is done
DEPTH = 2
#: signals the command stops on; a worker is forked with them blocked, then ignores SIGINT and
#: SIGHUP and takes SIGTERM's default (the command's stop)
_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}


def available() -> bool:
    """Forked workers are used where fork is safe with the libraries loaded: Linux. (macOS
    system frameworks are not fork-safe; Windows has no fork.) Elsewhere local workers are a
    Dask LocalCluster."""
    return sys.platform.startswith("linux")


@dataclass
class LocalSpec:
    workers: int
    memory_limit_bytes: int


@dataclass(eq=False)  # compared and hashed as itself
class _Worker:
    proc: Any  # multiprocessing.Process
    conn: Any  # multiprocessing.connection.Connection (the command's end)
    queued: deque[LogTask] = field(default_factory=deque)
    killed_for: str = ""  # why the command killed it (over its memory limit)
    rss_at_fork: int = 0  # its resident size just after the fork (the fallback of _own_bytes)


def _own_bytes(pid: int, rss_at_fork: int) -> int:
    """Memory a forked worker holds of its own: its private resident pages (Linux
    /proc/PID/smaps_rollup, Private_Clean + Private_Dirty; 0 when it is gone).

    Not its RSS: a forked worker's RSS counts the pages it still shares with the command
    (copy-on-write), so a command holding 0.5 GB would see every worker "over" a 0.25 GB limit
    the moment it is forked. Where smaps_rollup is missing (kernels before 4.14) the resident
    size minus what was resident at the fork is used."""
    try:
        with open(f"/proc/{pid}/smaps_rollup", "rb") as f:
            total_kb = 0
            for line in f:
                if line.startswith((b"Private_Clean:", b"Private_Dirty:")):
                    total_kb += int(line.split()[1])
            return total_kb * 1024
    except FileNotFoundError:
        return max(0, _rss_bytes(pid) - rss_at_fork)
    except (OSError, ValueError, IndexError):
        return 0


def _rss_bytes(pid: int) -> int:
    """Resident memory of a process (Linux /proc; 0 when it is gone)."""
    try:
        with open(f"/proc/{pid}/statm", "rb") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def _address_space_bytes() -> int:
    with open("/proc/self/statm", "rb") as f:
        return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


#: log records a worker sends back with one log's outcome, at most (the rest are counted)
MAX_RECORDS_PER_LOG = 50


class _Records(logging.Handler):
    """A worker's log records for the log at hand, handed to the command with its outcome (which
    logs them as the serial loop would have): the command's own handlers, inherited by the
    fork, would write over its progress bar or hold the lines in the worker forever."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[tuple[str, int, str]] = []
        self.dropped = 0

    def emit(self, record: logging.LogRecord) -> None:
        if len(self.records) < MAX_RECORDS_PER_LOG:
            self.records.append((record.name, record.levelno, record.getMessage()))
        else:
            self.dropped += 1

    def take(self) -> list[tuple[str, int, str]]:
        out = self.records
        if self.dropped:
            out.append((log.name, logging.WARNING, f"{self.dropped} more log lines not shown"))
        self.records, self.dropped = [], 0
        return out


def _worker_main(conn: Any, parent_pid: int, memory_limit_bytes: int) -> None:
    """A forked worker: one log at a time from ``conn``, its outcome and log records back; ends
    on EOF or None."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
    _die_with_parent(parent_pid)
    _limit_address_space(memory_limit_bytes)
    records = _Records()
    logging.getLogger().handlers = [records]
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):  # the command is gone
            return
        if task is None:
            return
        row = process_log(task)
        conn.send((row, records.take()))


def _die_with_parent(parent_pid: int) -> None:
    """SIGKILL this process when the command that forked it dies, however it dies."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - not Linux
        pass
    if os.getppid() != parent_pid:  # the command died before the line above
        os._exit(1)


def _limit_address_space(limit_bytes: int) -> None:
    """This process's address space may grow by ``limit_bytes`` from now on: a log that needs
    more fails to allocate (MemoryError: the log is refused) instead of taking the machine."""
    import resource

    try:
        _, hard = resource.getrlimit(resource.RLIMIT_AS)
        soft = _address_space_bytes() + limit_bytes
        if hard != resource.RLIM_INFINITY:
            soft = min(soft, hard)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    except (OSError, ValueError) as exc:  # pragma: no cover - the watchdog still holds
        log.debug("fleet worker: address-space limit not set: %s", exc)


def _received(message: tuple[dict[str, Any], list[tuple[str, int, str]]]) -> Outcome:
    """A worker's outcome; its log records are logged here, as the serial loop logs them."""
    row, records = message
    for name, level, text in records:
        logging.getLogger(name).log(level, "%s", text)
    return Outcome.from_dict(row)


class ForkPool:
    """``spec.workers`` processes forked from this one, fed over pipes.

    Fork only where no other thread of this process can hold a lock (the command's main
    thread, before any thread is started: a local Dask cluster is never started alongside).
    """

    def __init__(self, spec: LocalSpec, *, poll_s: float = 0.25) -> None:
        import multiprocessing

        if spec.workers < 1:
            raise ValueError("a pool needs at least one worker")
        self.spec = spec
        self.poll_s = poll_s
        self._ctx = multiprocessing.get_context("fork")
        self._workers: list[_Worker] = []
        self.started = 0  # workers forked, replacements included

    def start(self) -> None:
        # imported once here, inherited by every worker (fleet_extract has imported the Df
        # rules already); each reader is imported by a worker when it meets its format
        import thrustmap.fitting.mapfile  # noqa: F401
        import thrustmap.flightlogs.detect  # noqa: F401

        while len(self._workers) < self.spec.workers:
            self._workers.append(self._fork())

    def pids(self) -> list[int]:
        return [w.proc.pid for w in self._workers]

    def _fork(self) -> _Worker:
        mine, theirs = self._ctx.Pipe(duplex=True)
        proc = self._ctx.Process(
            target=_worker_main,
            args=(theirs, os.getpid(), self.spec.memory_limit_bytes),
            name=f"thrustmap-fleet-worker-{self.started}",
            daemon=True,
        )
        # blocked across the fork: a stop signal arriving before the worker has set its own
        # dispositions must not run this process's handlers in the worker; here it is delivered
        # when the mask is restored
        old = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        try:
            proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        theirs.close()
        self.started += 1
        return _Worker(proc, mine, rss_at_fork=_rss_bytes(proc.pid or 0))

    def run(self, tasks: list[LogTask]) -> Iterator[Outcome]:
        """Every task's outcome, in completion order."""
        from multiprocessing.connection import wait

        self.start()
        todo = deque(tasks)
        for w in self._workers:
            self._fill(w, todo)
        next_poll = time.monotonic() + self.poll_s
        while any(w.queued for w in self._workers):
            by_conn = {w.conn: w for w in self._workers if w.queued}
            by_sentinel = {w.proc.sentinel: w for w in by_conn.values()}
            ready = wait([*by_conn, *by_sentinel], timeout=self.poll_s)
            dead: list[_Worker] = []
            for obj in ready:
                if obj in by_conn:
                    w = by_conn[obj]
                    try:
                        message = w.conn.recv()
                    except (EOFError, OSError):
                        dead.append(w)
                        continue
                    w.queued.popleft()
                    self._fill(w, todo)
                    yield _received(message)
                else:
                    dead.append(by_sentinel[obj])
            for w in dict.fromkeys(dead):
                yield from self._replace(w, todo)
            if time.monotonic() >= next_poll:
                next_poll = time.monotonic() + self.poll_s
                self._check_memory()

    def _fill(self, w: _Worker, todo: deque[LogTask]) -> None:
        while todo and len(w.queued) < DEPTH:
            t = todo.popleft()
            w.queued.append(t)
            w.conn.send(t)

    def _check_memory(self) -> None:
        """Kill a worker over its memory limit (its log is refused when its death is seen)."""
        limit = self.spec.memory_limit_bytes
        for w in self._workers:
            rss = _own_bytes(w.proc.pid, w.rss_at_fork)
            if rss > limit and not w.killed_for:
                w.killed_for = (
                    f"stopped at {rss / 2**30:.2f} GiB, over its memory limit of "
                    f"{limit / 2**30:.2f} GiB (--memory-per-worker)"
                )
                log.warning("fleet worker %d %s", w.proc.pid, w.killed_for)
                with contextlib.suppress(OSError):
                    os.kill(w.proc.pid, signal.SIGKILL)

    def _replace(self, w: _Worker, todo: deque[LogTask]) -> Iterator[Outcome]:
        """A worker died: the outcomes it sent first, then its log refused, the logs queued
        behind it back to the front of the queue, and a new worker in its place (while logs are
        left: each death refuses one log, so even workers that all die end the run)."""
        while True:
            try:
                if not w.conn.poll():
                    break
                message = w.conn.recv()
            except (EOFError, OSError):
                break
            w.queued.popleft()
            yield _received(message)
        w.proc.join(5)
        if w.proc.is_alive():  # its pipe broke but it runs on: it is not left behind
            w.proc.kill()
            w.proc.join(5)
        code = w.proc.exitcode
        w.conn.close()
        self._workers.remove(w)
        if w.queued:
            t = w.queued.popleft()
            how = w.killed_for or (
                f"killed by signal {-code}" if code is not None and code < 0 else f"exit {code}"
            )
            todo.extendleft(reversed(w.queued))
            yield Outcome(
                path=t.path,
                options_key=t.options_key,
                reason=f"{t.path}: the worker holding this log died ({how}); the log was not "
                "retried",
            )
        if todo:  # a new worker only for logs still to do
            nw = self._fork()
            self._workers.append(nw)
            self._fill(nw, todo)

    def close(self, timeout_s: float = 5.0) -> list[int]:
        """Stop every worker and confirm it is gone: its pipe closed, SIGTERM, and SIGKILL if
        it is still alive after ``timeout_s``; each is waited for. Returns the pids stopped."""
        workers, self._workers = self._workers, []
        for w in workers:
            with contextlib.suppress(OSError, ValueError):
                w.conn.close()
            if w.proc.is_alive():
                with contextlib.suppress(OSError):
                    w.proc.terminate()
        deadline = time.monotonic() + timeout_s
        for w in workers:
            w.proc.join(max(0.0, deadline - time.monotonic()))
            if w.proc.is_alive():
                w.proc.kill()
                w.proc.join(timeout_s)
        return [w.proc.pid for w in workers]
