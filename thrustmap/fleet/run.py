"""Running a fleet: plan (what is already done), then the logs serially, on local workers
(:mod:`thrustmap.fleet.local`) or on a Dask cluster.

Bounded by construction: a worker holds one log at a time (a Dask worker runs one thread); the
driver keeps at most two logs per worker queued (on Dask ``window`` tasks submitted, small logs
several to a task, one after the other), so neither it nor a scheduler holds the whole fleet; a
log larger than ``max_log_bytes`` is refused unread; and each local worker gets a memory limit
(a worker that exceeds it is stopped and the log it held is recorded as refused, not retried).

Resumable: a log whose path, size, modification time and options key match the previous table
is not touched; any other log is hashed by its worker, and when ``OUT_DIR/df`` already holds the
outcome for that content and these options it is reused without reading the log.
"""

from __future__ import annotations

import contextlib
import csv
import fnmatch
import hashlib
import json
import logging
import os
import signal
import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from thrustmap.core.errors import ConfigError, DataFormatError
from thrustmap.fleet.discover import LOG_SUFFIXES, discover
from thrustmap.fleet.table import TABLE_NAME, read_table, write_table
from thrustmap.fleet.task import LogTask, Outcome, file_sha256, one_line, process_log

log = logging.getLogger(__name__)

Progress = Callable[[int, int, Outcome], None]


@dataclass
class FleetConfig:
    out_dir: Path
    df_options: dict[str, Any] = field(default_factory=dict)  # DfOptions fields (mass: default)
    masses: list[tuple[str, float]] = field(default_factory=list)  # (glob on path or name, kg)
    map_path: Path | None = None
    fmt: str | None = None
    max_log_bytes: int = 512 << 20
    force: bool = False  # extract a flight on another pack than the map's (recorded)


@dataclass
class FleetResult:
    outcomes: list[Outcome]
    total: int  # logs discovered
    reused: int  # outcomes taken from the previous table or the stored outcome files
    interrupted: bool = False
    table_path: Path | None = None


def rules_fingerprint() -> str:
    """A hash of the extraction rules' source (Df filters and their defaults, every reader, the
    per-log task and its physical checks against the map): a change to them changes every
    log's options key, so a re-run re-extracts instead of reusing (a log extracted before the
    pack check came in is checked on the next run). Found without importing them (a re-run
    with nothing new stays fast)."""
    import importlib.util

    h = hashlib.sha256()
    files: list[Path] = []
    for name in (
        "thrustmap.fitting.df",
        "thrustmap.fitting.df_options",
        "thrustmap.flightlogs",
        "thrustmap.fleet.task",
        "thrustmap.core.physical",
    ):
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:  # pragma: no cover - a broken installation
            raise ConfigError(f"cannot find {name}")
        origin = Path(spec.origin)
        files += sorted(origin.parent.glob("*.py")) if origin.name == "__init__.py" else [origin]
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def read_masses(path: Path) -> list[tuple[str, float]]:
    """A CSV of ``pattern,mass_kg`` rows (header optional): the first pattern matching a log's
    path or file name gives its mass."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise ConfigError(f"cannot read the mass table: {exc.strerror}", file=str(path)) from None
    out: list[tuple[str, float]] = []
    for n, row in enumerate(csv.reader(text.splitlines()), start=1):
        if not row or not "".join(row).strip() or row[0].strip().startswith("#"):
            continue
        if len(row) != 2:
            raise DataFormatError("expected two columns: pattern,mass_kg", file=str(path), line=n)
        pattern, value = row[0].strip(), row[1].strip()
        try:
            mass = float(value)
        except ValueError:
            if n == 1:
                continue  # a header
            raise DataFormatError(
                f"expected a mass in kg, got {value!r}", file=str(path), line=n, column="mass_kg"
            ) from None
        if not 0 < mass < 1000:
            raise DataFormatError(
                f"mass {mass:g} kg is not a multirotor's (expected 0..1000 kg)",
                file=str(path),
                line=n,
                column="mass_kg",
            )
        out.append((pattern, mass))
    return out


def mass_for(path: Path, config: FleetConfig) -> float | None:
    for pattern, mass in config.masses:
        if fnmatch.fnmatch(path.name, pattern) or fnmatch.fnmatch(str(path), pattern):
            return mass
    given = config.df_options.get("mass_kg")
    return None if given is None else float(given)


def options_key(
    df_options: dict[str, Any],
    map_sha: str | None,
    fmt: str | None,
    rules: str,
    force: bool = False,
) -> str:
    given: dict[str, Any] = {"df": df_options, "map": map_sha, "format": fmt, "rules": rules}
    if force:  # only when given: the keys of earlier runs stay valid
        given["force"] = True
    text = json.dumps(given, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def plan(
    paths: Iterable[Path], config: FleetConfig, previous: dict[str, Outcome]
) -> tuple[list[LogTask], list[Outcome]]:
    """The tasks still to run, and the outcomes reused from the previous table.

    The options key hashes the options as given (the rules' defaults are in the fingerprint of
    their source), so planning imports no numerical library."""
    rules = rules_fingerprint()
    map_sha = file_sha256(config.map_path) if config.map_path else None
    keys: dict[float | None, tuple[dict[str, Any], str]] = {}
    tasks: list[LogTask] = []
    reused: list[Outcome] = []
    for p in paths:
        mass = mass_for(p, config)
        if mass not in keys:
            opts = {**config.df_options, "mass_kg": mass}
            keys[mass] = (opts, options_key(opts, map_sha, config.fmt, rules, config.force))
        opts, key = keys[mass]
        prev = previous.get(str(p))
        if prev is not None and prev.options_key == key:
            try:
                st = p.stat()
            except OSError:
                st = None
            if (
                st is not None
                and st.st_size == prev.size_bytes
                and st.st_mtime_ns == prev.mtime_ns
                and (not prev.df_path or (config.out_dir / prev.df_path).is_file())
            ):
                reused.append(replace(prev, seconds=0.0, reused=True))
                continue
        tasks.append(
            LogTask(
                path=str(p),
                out_dir=str(config.out_dir),
                options_key=key,
                df_options=opts,
                map_path=None if config.map_path is None else str(config.map_path.absolute()),
                fmt=config.fmt,
                max_log_bytes=config.max_log_bytes,
                force=config.force,
            )
        )
    return tasks, reused


def run_serial(tasks: list[LogTask]) -> Iterator[Outcome]:
    """The plain loop: one log after the other in this process."""
    for t in tasks:
        yield Outcome.from_dict(process_log(t))


#: logs smaller than this together go to a worker as one Dask task (about 0.4 s of work): a task
#: costs ~10 ms of CPU in the scheduler, the client and the worker together on top of its logs
#: (bench_fleet.py: 165 one-log tasks against 19 batches), so 4 MB batches (~0.1 s) lost ~8 %
BATCH_BYTES = 16 << 20
#: at most this many logs in one task
BATCH_LOGS = 64


def batches(tasks: list[LogTask], window: int) -> Iterator[list[LogTask]]:
    """The tasks in submission order, grouped: small logs together up to ``BATCH_BYTES`` (or
    ``BATCH_LOGS``), one after the other in one Dask task.

    Guided self-scheduling: a batch takes at most what is left divided by the window (the
    tasks kept submitted, two per worker: a worker already holds its next task when it gets a
    new one), so batches shrink as the fleet runs out, down to one log a task, and no worker
    idles at the end while another finishes a big batch (fixed batches of 10 logs left one of 2
    workers idle for up to a batch, ~0.13 s of a 1.4 s run, bench_fleet.py)."""
    slots = max(1, window)
    i, n = 0, len(tasks)
    carried: int | None = None  # the size of the log that did not fit the previous batch
    while i < n:
        limit = max(1, min(BATCH_LOGS, -(-(n - i) // slots)))
        batch: list[LogTask] = []
        size = 0
        while i < n and len(batch) < limit:
            s = _size(tasks[i]) if carried is None else carried
            carried = None
            if batch and size + s > BATCH_BYTES:
                carried = s
                break
            batch.append(tasks[i])
            size += s
            i += 1
        yield batch


def _size(task: LogTask) -> int:
    try:
        return os.stat(task.path).st_size
    except OSError:
        return 0  # the worker reports why


#: the signals a fleet run is stopped by (held inside Dask client calls)
STOP_SIGNALS = tuple(
    s for s in (getattr(signal, n, None) for n in ("SIGINT", "SIGTERM", "SIGHUP")) if s is not None
)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Ctrl-C or SIGTERM arriving inside a Dask client call (a future half built, a cancel half
    sent) left objects that failed when collected and printed tracebacks after "interrupted"
    (tests/test_fleet_dask.py, 2 runs in 25). Inside this block such a signal is held and
    delivered as soon as the call returns; a signal the process ignores stays ignored, and only
    Python-level handlers are held (a default SIGTERM still ends the process at once)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    previous: dict[int, Any] = {}
    for sig in STOP_SIGNALS:
        if callable(signal.getsignal(sig)):
            previous[sig] = signal.signal(sig, lambda signum, frame: held.append(signum))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(held):
            signal.raise_signal(sig)


def run_on_client(client: Any, tasks: list[LogTask], window: int) -> Iterator[Outcome]:
    """The logs on a Dask cluster, at most ``window`` tasks submitted at a time, in completion
    order. Small logs travel in batches (``batches``); a batch whose worker died (over its
    memory limit, or crashed) is sent again one log per task, so only the log that killed it is
    refused (the others' outcomes were stored as they finished and are reused).

    Leaving the iterator early (an exception, Ctrl-C, ``close()``) cancels what is in flight.
    Stop signals land only while it waits for the next result (``signals_held``).
    """
    from distributed import as_completed

    from thrustmap.fleet.task import process_batch

    pending = batches(tasks, window)
    retry: list[list[LogTask]] = []
    inflight: dict[str, tuple[Any, list[LogTask]]] = {}
    ac = as_completed()  # type: ignore[no-untyped-call]

    def submit(batch: list[LogTask]) -> None:
        fut = client.submit(process_batch, batch, pure=False, retries=0)
        inflight[fut.key] = (fut, batch)
        ac.add(fut)  # type: ignore[no-untyped-call]

    def submit_next() -> None:
        nxt = retry.pop() if retry else next(pending, None)
        if nxt is not None:
            submit(nxt)

    def collect(fut: Any) -> list[dict[str, Any]]:
        """The finished batch's outcomes; a batch whose worker died goes again, a log at a
        time (nothing to report yet), and a single log that killed its worker is refused."""
        _, batch = inflight.pop(fut.key)
        try:
            rows: list[dict[str, Any]] = fut.result()
        except Exception as exc:  # KilledWorker: over its memory limit, or crashed
            fut.release()
            if len(batch) > 1:
                retry.extend([t] for t in reversed(batch))
                for _ in range(min(window - len(inflight), len(retry))):
                    submit_next()
                return []
            (t,) = batch
            rows = [
                Outcome(
                    path=t.path,
                    options_key=t.options_key,
                    reason=f"{t.path}: the worker holding this log died "
                    f"({type(exc).__name__}: {one_line(exc)}); over its memory limit?",
                ).to_dict()
            ]
        else:
            fut.release()
        submit_next()
        return rows

    try:
        with signals_held():
            while len(inflight) < window:
                before = len(inflight)
                submit_next()
                if len(inflight) == before:
                    break
        for fut in ac:  # a stop signal lands here, while waiting
            with signals_held():
                rows = collect(fut)
            del fut  # no future outlives the client in a traceback's frame
            for d in rows:
                yield Outcome.from_dict(d)
    finally:
        with signals_held():
            if inflight:
                client.cancel([f for f, _ in inflight.values()], force=True)
                inflight.clear()
            ac.clear()  # type: ignore[no-untyped-call]


def fleet_extract(
    sources: Iterable[str | os.PathLike[str]],
    config: FleetConfig,
    *,
    connect: Callable[[], tuple[Any, int]] | None = None,
    local: Callable[[list[LogTask]], Iterator[Outcome]] | None = None,
    progress: Progress | None = None,
) -> FleetResult:
    """Extract every log of the fleet.

    ``connect`` returns a Dask client and the number of logs to keep submitted; ``local`` runs
    the tasks on local worker processes (``thrustmap.fleet.local.ForkPool.run``). Either is
    called only when some log is left to do (a re-run with nothing new starts no worker), after
    the extraction rules are imported here (forked workers inherit them). Without either the
    logs run in the plain serial loop.

    The table (``OUT_DIR/fleet.parquet``) is written at the end, and also when the run is
    interrupted (KeyboardInterrupt is re-raised after the table of what finished is written).
    """
    out_dir = config.out_dir
    sources = list(sources)
    paths = discover(sources, exclude=out_dir)
    if not paths:  # refused before anything is written: never an empty table
        raise ConfigError(
            "no flight log found in "
            + ", ".join(os.fspath(s) for s in sources)
            + f" (a folder is searched for {', '.join(sorted(LOG_SUFFIXES))}); nothing written"
        )
    if config.df_options.get("mass_kg") is None and not config.masses:  # not once per log
        raise ConfigError(
            "give the vehicles' take-off mass: --mass-kg KG (every vehicle) or --masses CSV "
            f"(pattern,mass_kg per log); F_m = m·a_up needs it: none of the {len(paths)} logs "
            "was read"
        )
    (out_dir / "df").mkdir(parents=True, exist_ok=True)
    table_path = out_dir / TABLE_NAME
    previous: dict[str, Outcome] = {}
    if table_path.exists():
        try:
            previous = {o.path: o for o in read_table(table_path)}
        except DataFormatError as exc:
            log.warning("the previous fleet table is unreadable, every log is redone: %s", exc)
    tasks, reused = plan(paths, config, previous)
    if tasks:  # the options are checked once here, not once per log on the workers
        from thrustmap.fitting.df_options import DfOptions

        for opts in {json.dumps(t.df_options, sort_keys=True) for t in tasks}:
            DfOptions(**json.loads(opts))
    total = len(paths)
    result = FleetResult(outcomes=list(reused), total=total, reused=len(reused))
    done = len(reused)
    if progress is not None:
        for k, o in enumerate(reused, start=1):
            progress(k, total, o)
    if tasks and local is not None:
        stream = local(tasks)
    elif tasks and connect is not None:
        client, window = connect()
        stream = run_on_client(client, tasks, window)
    else:
        stream = run_serial(tasks)
    try:
        for o in stream:
            result.outcomes.append(o)
            result.reused += int(o.reused)
            done += 1
            if progress is not None:
                progress(done, total, o)
    except KeyboardInterrupt:
        result.interrupted = True
        close = getattr(stream, "close", None)
        if close is not None:
            close()
        write_table(result.outcomes, table_path)
        result.table_path = table_path
        raise
    write_table(result.outcomes, table_path)
    result.table_path = table_path
    return result


@dataclass
class LocalClusterSpec:
    workers: int
    memory_limit_bytes: int
    #: where the scheduler's dashboard listens (``host:port``); None: no dashboard, and the
    #: scheduler's HTTP server (health checks) on a free loopback port
    dashboard_address: str | None = None


#: every server of a local cluster (scheduler, nannies, workers, their HTTP servers) binds here
LOOPBACK = "127.0.0.1"


#: Local workers per CPU core: a worker mostly decodes (CPU-bound), a few more than the cores
#: hide its file reads; beyond this they only contend for the cores and the memory.
WORKERS_PER_CORE = 4
#: Local workers on any machine: each is a forked process with its own memory limit.
MAX_WORKERS = 256
#: The least memory a local worker is given (as ``--memory-per-worker`` accepts).
MIN_WORKER_MEMORY_BYTES = 256 << 20


def local_cluster_spec(
    workers: int | None, memory_per_worker: int | None, dashboard_address: str | None = None
) -> LocalClusterSpec:
    """How many local workers and how much memory each may use (stated to the user)."""
    cpus = os.cpu_count() or 1
    n = workers if workers is not None else cpus
    if n < 1:
        raise ConfigError(f"--workers must be at least 1 (0 runs the plain serial loop), got {n}")
    top = min(WORKERS_PER_CORE * cpus, MAX_WORKERS)
    if n > top:
        raise ConfigError(
            f"--workers {n}: at most {top} ({WORKERS_PER_CORE} per CPU core, {cpus} here, and "
            f"never over {MAX_WORKERS}): each worker is a process holding a log in memory"
        )
    total = _total_memory_bytes()
    mem = memory_per_worker if memory_per_worker is not None else min(4 << 30, total // n)
    if memory_per_worker is None and mem < MIN_WORKER_MEMORY_BYTES:
        raise ConfigError(
            f"--workers {n}: {mem / 2**20:.0f} MiB of this machine's "
            f"{total / 2**30:.1f} GiB each, under the {MIN_WORKER_MEMORY_BYTES >> 20} MiB a "
            "worker needs; give fewer workers"
        )
    return LocalClusterSpec(n, int(mem), dashboard_address)


def _total_memory_bytes() -> int:
    """The machine's RAM: from the C library where it says (no psutil import on a local run's
    path, ~10 ms), else psutil."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):  # pragma: no cover - not POSIX
        import psutil

        return int(psutil.virtual_memory().total)


def dashboard_address(text: str) -> str:
    """``--dashboard [ADDR]``: ``host:port``, ``:port`` (loopback) or a bare port."""
    t = text.strip()
    host, sep, port = t.rpartition(":")
    if not sep:
        host, port = "", t
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ConfigError(f"--dashboard '{text}': expected host:port, :port or a port number")
    return f"{host or LOOPBACK}:{int(port)}"


def start_local_cluster(spec: LocalClusterSpec) -> tuple[Any, Any]:
    """A LocalCluster of ``spec.workers`` processes, one thread each (one log at a time), every
    server of it on 127.0.0.1, the dashboard only when ``spec.dashboard_address`` asks for it.

    The worker processes start with SIGINT blocked: a Ctrl-C at the terminal reaches the whole
    process group, and only this process must act on it, cancelling the logs and closing the
    cluster in order. A blocked signal mask is inherited by the threads the cluster starts and
    by the processes they spawn (across exec; checked in tests/test_fleet_ways_out.py), so it
    is blocked in the calling thread for the start-up; unlike an ignored SIGINT (what this did before), a blocked one is not lost: when
    the start-up is over, a Ctrl-C that came during it is delivered (the cluster is closed
    first). ``LocalClusterStart`` runs this in a background thread, where the main thread
    answers Ctrl-C at once."""
    from multiprocessing import resource_tracker

    main_thread = threading.current_thread() is threading.main_thread()
    # multiprocessing starts its resource tracker with the first worker and then UNBLOCKS
    # SIGINT in the starting thread (resource_tracker.ensure_running): started here first, the
    # mask set below stays as it is for the workers
    resource_tracker.ensure_running()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    started: tuple[Any, Any] | None = None
    try:
        started = _new_local_cluster(spec)
    finally:
        held = (
            main_thread
            and started is not None
            and signal.SIGINT not in old
            and signal.SIGINT in signal.sigpending()
            and callable(signal.getsignal(signal.SIGINT))
        )
        if held and started is not None:  # a Ctrl-C came during the start-up: stop
            close_cluster(*started)
            started = None
        signal.pthread_sigmask(signal.SIG_SETMASK, old)  # a held Ctrl-C is delivered here
    if started is None:  # pragma: no cover - the handler raised at the line above
        raise KeyboardInterrupt
    return started


def _new_local_cluster(spec: LocalClusterSpec) -> tuple[Any, Any]:
    import dask
    from distributed import Client, LocalCluster

    quiet_dask()
    settings: dict[str, Any] = {
        "distributed.scheduler.allowed-failures": 0,
        # the workers' statistical profiler samples every thread's stack every 10 ms: on
        # pure-Python log readers that costs ~20 % of each log's time (bench_fleet.py)
        "distributed.worker.profile.enabled": False,
        # Background ticks of an idle 2-worker cluster (benchmarks/bench_fleet.py measures them:
        # CPU of this process and of each worker while nothing runs) took 40-55 ms/s in this
        # process and ~20 ms/s in each worker, ~4.5 % of a 2-core machine taken from the logs.
        # These three bring it to ~10 ms/s and ~4 ms/s:
        # - the event-loop health check (only a "loop was unresponsive" warning) every 20 ms
        "distributed.admin.tick.interval": "1s",
        # - CPU/memory/network samples for the dashboard (which a local cluster does not run)
        "distributed.admin.system-monitor.interval": "5s",
        # - the nanny's and the worker's memory poll (100 ms): 250 ms still stops a worker over
        #   --memory-per-worker within a quarter second, and --max-log-mb bounds what one log
        #   can take (one log at a time per worker)
        "distributed.worker.memory.monitor-interval": "250ms",
        # Dask starts workers with MALLOC_TRIM_THRESHOLD_=65536, which also turns off glibc's
        # adaptive mmap threshold: every numpy array over 128 kB is then mmap'ed and unmapped
        # again, and a log took ~1.3x as long in a worker as in the serial loop (bench_fleet).
        # A worker holds one log at a time and the nanny still enforces memory_limit, so the
        # default allocator is kept; the BLAS/OpenMP pools stay at one thread per worker.
        "distributed.nanny.pre-spawn-environ": {
            "OMP_NUM_THREADS": 1,
            "MKL_NUM_THREADS": 1,
            "OPENBLAS_NUM_THREADS": 1,
        },
    }
    dashboard = spec.dashboard_address is not None
    if not dashboard:
        # the HTTP servers then answer health checks only: Dask's info pages, JSON and event
        # stream (worker logs, call stacks, the paths they hold) are the dashboard's part
        settings["distributed.scheduler.http.routes"] = ["distributed.http.health"]
        settings["distributed.worker.http.routes"] = ["distributed.http.health"]
    with dask.config.set(settings):
        cluster = LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=spec.workers,
            threads_per_worker=1,
            processes=True,
            memory_limit=spec.memory_limit_bytes,
            # scheduler, nannies and workers on loopback (issue 36: Dask's default dashboard
            # address ':8787' and ':0' listen on every interface)
            host=LOOPBACK,
            # no dashboard unless asked for (start-up is ~0.5 s shorter without bokeh); the
            # scheduler's HTTP server (health checks) stays, on a free loopback port
            dashboard_address=spec.dashboard_address or f"{LOOPBACK}:0",
            worker_dashboard_address=None,
            scheduler_kwargs={"dashboard": dashboard},
            # Dask's own errors too: every log's fate, a worker's death included, is in the
            # table and the summary; what is left are races of its shutdown (a worker's
            # heartbeat to a scheduler already closing), printed as tracebacks after
            # "interrupted" in 2 of 60 stopped runs (tests/test_fleet_dask.py)
            silence_logs=logging.CRITICAL,
        )
    try:
        client = Client(cluster)  # type: ignore[no-untyped-call]
    except BaseException:
        with contextlib.suppress(Exception):
            cluster.close()
        raise
    return cluster, client


def close_cluster(cluster: Any, client: Any, timeout_s: float = 10.0) -> None:
    """Close a client and its cluster; a failure to close hides nothing (callers then stop the
    children that are left, ``stop_children``)."""
    if client is not None:
        with contextlib.suppress(Exception):
            client.close(timeout=timeout_s)
    if cluster is not None:
        with contextlib.suppress(Exception):
            cluster.close(timeout=timeout_s)


class LocalClusterStart:
    """A local cluster starting in a background thread while the caller discovers and plans
    the logs (start-up, ~1 s, overlapped with that work). The main thread keeps answering
    Ctrl-C and SIGTERM at once: ``wait`` is interruptible, and ``close`` (in every way out)
    waits for the start to finish and closes what it started."""

    def __init__(self, spec: LocalClusterSpec) -> None:
        self.spec = spec
        self._done = threading.Event()
        self._cluster: Any = None
        self._client: Any = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(
            target=self._start, name="thrustmap-cluster-start", daemon=True
        )
        self._thread.start()

    def _start(self) -> None:
        try:
            self._cluster, self._client = start_local_cluster(self.spec)
        except BaseException as exc:  # handed to the main thread by wait()
            self._error = exc
        finally:
            self._done.set()

    def ready(self) -> bool:
        """Whether the start is over (started, or failed: ``wait`` then raises)."""
        return self._done.is_set()

    def wait(self) -> tuple[Any, Any]:
        while not self._done.wait(0.05):  # a stop signal lands here
            pass
        if self._error is not None:
            raise self._error
        return self._cluster, self._client

    def close(self, timeout_s: float = 60.0) -> None:
        self._done.wait(timeout_s)
        close_cluster(self._cluster, self._client)
        self._cluster = self._client = None


def quiet_dask() -> None:
    """Dask's own INFO lines (scheduler, nanny, worker life cycle) are not the user's business."""
    for name in ("distributed", "tornado", "bokeh"):
        logging.getLogger(name).setLevel(logging.ERROR)


def connect(address: str) -> Any:
    from distributed import Client

    quiet_dask()
    try:
        return Client(address, timeout="15s")  # type: ignore[no-untyped-call]
    except (OSError, TimeoutError) as exc:
        raise ConfigError(
            f"cannot reach the Dask scheduler at {address}: {one_line(exc)}"
        ) from None
    except (TypeError, ValueError) as exc:  # e.g. tls:// without Dask's TLS configuration
        hint = (
            ": tls:// needs Dask's TLS configuration (distributed.comm.tls.ca-file and "
            "client.cert/key, see docs/fleet.md)"
            if address.startswith("tls://")
            else ""
        )
        raise ConfigError(
            f"cannot connect to the Dask scheduler at {address}: {one_line(exc)}{hint}"
        ) from None


def stop_children(before: set[int], timeout_s: float = 5.0) -> list[int]:
    """Terminate (then kill) any child process started since ``before`` that is still alive:
    after a cluster is closed nothing it spawned may outlive the command."""
    import psutil

    me = psutil.Process()
    left = [
        c for c in me.children(recursive=True) if c.pid not in before and not _resource_tracker(c)
    ]
    for c in left:
        with contextlib.suppress(psutil.Error):
            c.terminate()
    _, alive = psutil.wait_procs(left, timeout=timeout_s)
    for c in alive:
        with contextlib.suppress(psutil.Error):
            c.kill()
    psutil.wait_procs(alive, timeout=timeout_s)
    return [c.pid for c in left]


def _resource_tracker(proc: Any) -> bool:
    """multiprocessing's resource tracker: one per parent, it exits when the parent does."""
    import psutil

    try:
        return any("multiprocessing.resource_tracker" in a for a in proc.cmdline())
    except psutil.Error:
        return False


def child_pids() -> set[int]:
    import psutil

    return {c.pid for c in psutil.Process().children(recursive=True)}
